"""The processing pipeline: a list of configured stages run over tiles on OpenCL or NumPy.

The pipeline is data. :func:`build_pipeline` turns a raw image and a few choices into a list of
stages; later work can drop or swap stages per image or per tile without touching the runner.
"""
from __future__ import annotations

import math
import time
from contextlib import closing, nullcontext
from dataclasses import dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Any, Callable

import numpy as np

from .cfa import CFA
from .errors import ClispError, clip
from .io.exif import output_attributes
from .io.rawfile import read_raw
from .io.rawimage import MAX_GAIN, RawImage, check_levels, check_samples
from .engine.profile import host_timer, stage_label
from .engine.runtime import DeviceImage, get_runtime
from .modules.base import Origin, Stage, advance, fuse_stages
from .modules.chroma_denoise.stage import (ChromaDenoise, ChromaDenoiseParams, calibrate_noise, is_noiseless,
                                           space_for)
from .modules.colour.stage import ColourMatrix, ToneCurve, WhiteBalance2
from .modules.demosaic_ari.stage import DemosaicARI
from .modules.demosaic_bilinear.stage import DemosaicBilinear
from .modules.demosaic_dlmmse.stage import DemosaicDLMMSE
from .modules.demosaic_lms.stage import DemosaicLMSHybrid
from .modules.demosaic_lms_guided.stage import DemosaicLMSGuided
from .modules.demosaic_malvar.stage import DemosaicMalvar
from .modules.highlights.stage import DEFAULT_MODE as DEFAULT_HIGHLIGHTS, highlight_stage
from .modules.raw_scale.stage import normalize, white_balance1
from .engine.streaming import (READ_AHEAD, ArraySink, ArrayWindows, BandSink, TileSink, WindowPool, WindowSource,
                        progress_bar, run_tiles, window_source)
from .noise_estimate import NoiseEstimateError, raw_noise
from .white_balance2 import estimate_wb2
from .engine.tiling import DEVICE_SHARE, MIN_TILE, DeviceLimits, Tile, TileNeeds, TilePlan, make_plan

DEMOSAICS: dict[str, type[Stage]] = {
    "bilinear": DemosaicBilinear,
    "malvar": DemosaicMalvar,
    "dlmmse": DemosaicDLMMSE,
    "hybrid": DemosaicLMSHybrid,
    "guided": DemosaicLMSGuided,
    "ari": DemosaicARI,
}
"""Demosaic stages by CLI name, each built by its ``for_raw(raw)`` (Stage: from the raw's CFA;
stages that adapt to the raw's noise override it); ``cfa_kinds`` lists the CFAs it supports."""

PRESETS: dict[str, dict[str, Any]] = {
    "fast": {"demosaic": {"lms": "bilinear", "bayer": "bilinear"}, "denoise_levels": 0, "highlights": "clamp"},
    "balanced": {"demosaic": {"lms": "hybrid", "bayer": "dlmmse"}, "denoise_levels": 2, "highlights": "reconstruct"},
    "quality": {"demosaic": {"lms": "guided", "bayer": "dlmmse"}, "denoise_levels": 3, "highlights": "reconstruct"},
}
"""Named parameter sets (``--preset``); an option is one value or a dict per CFA kind.
``denoise_levels``: pyramid depth of the chroma denoiser, 0 = none. ``highlights``: the highlight
mode (clisp.modules.highlights.stage; fast: the per-pixel clamp, since reconstruct costs 1 s on a 24 MP
raw with clipping spread over a fifth of it). Explicit options override."""

DEFAULT_PRESET = "quality"
OUTPUTS = ("linear", "srgb", "srgb16")


DEFAULT_BUDGET = 2**30
"""Memory budget in bytes. ``clisp process --mem`` / :func:`process_file`: the peak resident set
of the whole process (clisp.engine.memory). :meth:`Pipeline.run` (the in-memory API): the host and device
buffers of the tiles in flight, not the interpreter or the output array."""

TILES_IN_FLIGHT = 3
"""Host copies of a tile's window and result alive at once: one being read or written, one
being computed, one queued (see streaming.run_tiles). For the per-pixel estimate (reference)."""

READ_WINDOWS = READ_AHEAD + 3
"""Raw windows alive on the host at once (Pipeline.tile_cost): two tiles in flight (a device that
shares host memory reads them in place), READ_AHEAD read ahead (streaming.WindowPool), and the
block a file source reads rows into before gathering them."""

SINK_BANDS = 2
"""Output band buffers of a streamed file (streaming.BandSink's rotation)."""

WRITER_ROWS = 2 * 128
"""Rows of float32 the writer converts at once (imageio.WRITE_ROWS), counted twice for the
library's own copy."""


@dataclass
class RunStats:
    """Wall time of the last run, its throughput in megapixels per second and its tiling."""

    seconds: float = 0.0
    megapixels: float = 0.0
    tiles: int = 0
    tile_shape: tuple[int, int] = (0, 0)

    @property
    def mp_per_s(self) -> float:
        return self.megapixels / self.seconds if self.seconds > 0 else float("nan")


@dataclass
class Pipeline:
    """Stages applied in order to a raw mosaic; the first stage reads raw DN, the last writes RGB."""

    cfa: CFA
    stages: list[Stage]
    stats: RunStats = field(default_factory=RunStats)
    skipper: Any = None
    """A clisp.skip.Skipper (build_pipeline ``skip``): per-tile paths from the scene analysis."""
    skip_plan: Any = None
    """The clisp.skip.SkipPlan of the last run (None without a skipper)."""

    @property
    def halo(self) -> int:
        """Total input border one output pixel needs (sum of the stage halos)."""
        return sum(stage.halo for stage in self.stages)

    @property
    def align(self) -> int:
        """Tile-origin multiple: the CFA period and every stage's alignment."""
        return math.lcm(self.cfa.period, *(stage.align for stage in self.stages))

    @property
    def out_channels(self) -> int:
        return self.stages[-1].out_channels

    @property
    def out_dtype(self) -> np.dtype:
        """float32, or uint16 when the pipeline ends in 16-bit codes (output 'srgb16')."""
        return self.stages[-1].out_dtype

    def describe(self) -> str:
        return " -> ".join(stage.name for stage in self.stages)

    def needs(self, raw_dtype: Any) -> TileNeeds:
        """The planner's numbers for raw input of ``raw_dtype`` (B/px of the input window).

        Device: the raw, every stage's declared buffers (all stay pooled; the unfused sum bounds
        the fused schedule) and an interleaved result. Host: TILES_IN_FLIGHT windows and results.
        """
        raw_bytes = float(np.dtype(raw_dtype).itemsize)
        out_bytes = float(self.out_dtype.itemsize * self.out_channels)
        stage_bytes = [float(stage.bytes_per_pixel) for stage in self.stages]
        return TileNeeds(halo=self.halo, align=self.align,
                         device_bytes=raw_bytes + sum(stage_bytes) + out_bytes,
                         host_bytes=TILES_IN_FLIGHT * (raw_bytes + out_bytes),
                         largest_bytes=max(stage_bytes + [raw_bytes, out_bytes]))

    def plan(self, shape: tuple[int, int], raw_dtype: Any, tile: int | None = None,
             budget: int = DEFAULT_BUDGET, backend: str = "opencl", sink_bands: bool = False) -> TilePlan:
        """Tiles for an H x W raw: ``tile`` None = from ``budget`` (bytes for the tiles in flight)
        and the device's limits, 0 = the whole image, N = N x N (see tiling.make_plan).

        On OpenCL the tiles' bytes are counted exactly (:meth:`tile_cost`); ``sink_bands``: also
        count the band buffers and writer rows of a streamed output file (process_file)."""
        limits = device_limits(backend)
        needs = self.needs(raw_dtype)
        if backend == "opencl":
            needs = replace(needs, cost=self.tile_cost(raw_dtype, shape[1], limits, sink_bands))
        return make_plan(shape[0], shape[1], needs, tile, budget, limits)

    def tile_cost(self, raw_dtype: Any, image_width: int, limits: DeviceLimits,
                  sink_bands: bool) -> Callable[[int, int], float]:
        """Bytes one tile of (rows, columns) output pixels takes while it runs, as a function:
        its device buffers, measured by enqueueing the tile's schedule in a metering run (exact,
        whatever the stages allocate), counted as host memory when the device shares it (a CPU
        device: PoCL's buffers are resident pages of this process); READ_WINDOWS raw windows; with
        ``sink_bands`` SINK_BANDS output bands of the image's width and the writer's converted rows.
        inf past DEVICE_SHARE of the device's memory or its largest allocation."""
        rt = get_runtime()
        schedule = self.schedule()
        shared = rt.host_unified or bool(rt.device.type & rt.cl.device_type.CPU)
        raw_item = np.dtype(raw_dtype).itemsize
        out_px = self.out_channels * self.out_dtype.itemsize
        halo = self.halo
        metered: dict[tuple[int, int], tuple[int, int]] = {}

        def cost(rows: int, cols: int) -> float:
            window = (rows + 2 * halo, cols + 2 * halo)
            if window not in metered:
                metered[window] = self.metered_tile(schedule, window, raw_dtype)
            created, largest = metered[window]
            if (limits.global_mem and created > DEVICE_SHARE * limits.global_mem) or \
                    (limits.max_alloc and largest > limits.max_alloc):
                return math.inf
            host = READ_WINDOWS * window[0] * window[1] * raw_item
            if sink_bands:
                host += SINK_BANDS * rows * image_width * out_px + WRITER_ROWS * image_width * self.out_channels * 4
            return host + (created if shared else 0)
        return cost

    def metered_tile(self, schedule: list[Stage], window: tuple[int, int], raw_dtype: Any) -> tuple[int, int]:
        """(bytes of all device buffers, bytes of the largest) that one tile of input ``window``
        (rows, columns) creates, from a metering run of :meth:`_enqueue_tile` (nothing runs).
        Where the device gathers windows from an in-memory mosaic (Runtime.gather_window) each
        tile has one pooled input window, not counted here, but the host then takes none of the
        READ_WINDOWS windows the memory plan counts: the plan errs on the safe side."""
        rt = get_runtime()
        with rt.metering() as meter:
            if rt.host_unified and np.dtype(raw_dtype) in (np.uint16, np.float32):
                src = DeviceImage(None, 1, window[0], window[1], np.dtype(raw_dtype),
                                  host=np.empty(0, raw_dtype))   # read in place (Runtime.host_input)
            else:
                src = rt.acquire(1, window[0], window[1], raw_dtype)
            rt.release(self._enqueue_tile(rt, schedule, src, (0, 0)))
        return meter.created, meter.largest

    def run(self, data: np.ndarray, tile: int | None = None, backend: str = "opencl",
            fuse: bool = True, budget: int = DEFAULT_BUDGET) -> np.ndarray:
        """Process an H x W raw mosaic (DN, uint16 or float32) into H x W x 3 float32 (uint16
        for a pipeline built with output 'srgb16').

        ``tile``: output tile side in pixels; None (default) chooses tiles from ``budget`` (bytes)
        and the device's limits, 0 runs the whole image as one tile.
        ``backend``: 'opencl' (kernels) or 'reference' (NumPy, float64 inside, stage by stage).
        ``fuse``: on OpenCL, merge neighbouring stages that compose (e.g. normalise, WB 1, bilinear
        demosaic and colour matrix become one kernel); False runs one kernel per stage.
        A read-only memory map of a raw file (``read_raw(path, lazy=True)``) is read tile by tile.
        """
        self._check(data.shape, backend)
        out = np.empty((data.shape[0], data.shape[1], self.out_channels), dtype=self.out_dtype)
        plan = self.plan(data.shape, data.dtype, tile, budget, backend)
        with closing(window_source(data)) as source:
            self.stream(source, ArraySink(out), plan, backend, fuse)
        return out

    def stream(self, source: WindowSource, sink: TileSink, plan: TilePlan, backend: str = "opencl",
               fuse: bool = True, progress: Callable[[Tile], None] | None = None) -> RunStats:
        """Run ``plan`` from ``source`` into ``sink`` (see streaming.run_tiles); sets and returns
        :attr:`stats`."""
        self._check(source.shape, backend)
        image = (int(source.shape[0]), int(source.shape[1]))     # the planner's alone; stages get it per window
        halo, (win_h, win_w) = plan.halo, plan.window_shape
        whole = self._device_source(source) if backend == "opencl" else None
        if backend == "opencl":                      # halo passed on: stages recompute it per call
            get_runtime().trim_pool()                # the pool holds what this plan's tiles need
            compute = partial(self._compute_opencl, self.schedule(fuse), halo, whole=whole,
                              window_shape=(win_h, win_w), image=image)
        else:
            compute = partial(self._compute_reference, halo, image=image)

        if self.skipper is not None:                 # per-tile paths (clisp.skip)
            compute = self._path_compute(plan, backend, fuse, whole, compute, image)

        windows = WindowPool()

        def read(t: Tile) -> np.ndarray | None:
            if whole is not None:                    # the device gathers the window itself
                return None
            with host_timer("read tile windows"):
                return source.read(t.y0 - halo, t.x0 - halo, win_h, win_w, self.cfa.period,
                                   windows.take((win_h, win_w), source.window_dtype))

        start = time.perf_counter()
        try:
            run_tiles(plan, read, compute, sink, progress, release=None if whole is not None else windows.give)
        finally:
            if backend == "opencl":
                get_runtime().queue.finish()          # no copy may still target the sink's arrays
        height, width = source.shape
        self.stats = RunStats(time.perf_counter() - start, height * width / 1e6, len(plan.tiles),
                              (plan.tile_h, plan.tile_w))
        return self.stats

    def _path_compute(self, plan: TilePlan, backend: str, fuse: bool, whole: Any,
                      full: Callable[..., Any], image: tuple[int, int]) -> Callable[..., Any]:
        """The compute step of :meth:`stream` choosing each tile's path from the skipper's plan
        (sets :attr:`skip_plan`). A path with a smaller halo runs on the centre of the tile's
        window (its origin moves in by the difference), so every path sees the image's pixels
        at the same coordinates and tiled equals whole per path."""
        skipper = self.skipper
        self.skip_plan = skip_plan = skipper.plan(plan)
        halo, (win_h, win_w) = plan.halo, plan.window_shape
        computes: dict[str, Callable[..., Any]] = {"full": full}
        for name in set(skip_plan.counts) - {"full"}:
            sub = Pipeline(self.cfa, skipper.paths[name])
            d, h = halo - sub.halo, sub.halo
            if backend == "opencl":
                run = partial(sub._compute_opencl, sub.schedule(fuse), h, whole=whole,
                              window_shape=(win_h - 2 * d, win_w - 2 * d), image=image)
            else:
                run = partial(sub._compute_reference, h, image=image)

            def crop(t: Tile, window: np.ndarray | None, target: Any, run: Callable[..., Any] = run,
                     d: int = d) -> Any:
                if window is None:
                    return run(t, window, target)
                inner = np.ascontiguousarray(window[d:window.shape[0] - d, d:window.shape[1] - d])
                # the device may read ``inner`` in place (or copy it asynchronously) until the tile's
                # event: keep it alive with the event, not only for this call
                return KeepAlive(run(t, inner, target), inner)
            computes[name] = crop
        return lambda t, window, target: computes[skip_plan.path_of(t)](t, window, target)

    def _check(self, shape: tuple[int, ...], backend: str) -> None:
        if backend not in ("opencl", "reference"):
            raise ClispError(f"unknown backend {backend!r}; expected opencl or reference")
        if len(shape) != 2:
            raise ClispError(f"raw data must be H x W, got shape {tuple(shape)}")
        if min(shape) < self.cfa.period:
            raise ClispError(f"raw of {shape[1]}x{shape[0]} is smaller than one CFA tile")

    def _compute_reference(self, halo: int, t: Tile, window: np.ndarray,
                           target: tuple[np.ndarray, int, int], image: tuple[int, int] | None = None) -> None:
        """The NumPy stages on the tile's own window (the plan's may reach past the image);
        ``image``: the whole image's (H, W), passed to the stages with each window's Origin."""
        x, origin = window[:t.h + 2 * halo, :t.w + 2 * halo], Origin(t.y0 - halo, t.x0 - halo, image)
        for stage in self.stages:
            x = stage.reference(x, origin)
            origin = advance(origin, stage.halo)
        host, y, x0 = target
        host[y:y + t.h, x0:x0 + t.w] = x
        return None

    def schedule(self, fuse: bool = True) -> list[Stage]:
        """The stages as run on OpenCL: fused where they compose, the last one writing the host's
        interleaved layout when it can."""
        schedule = fuse_stages(self.stages) if fuse else list(self.stages)
        last = schedule[-1].with_interleaved_output()
        if last is not None:
            schedule[-1] = last
        return schedule

    @staticmethod
    def _enqueue_tile(rt: Any, schedule: list[Stage], src: Any, origin: tuple[int, int],
                      into: tuple[np.ndarray, int] | None = None) -> Any:
        """Enqueue every stage of ``schedule`` on the uploaded window ``src`` (released on the
        way); returns the interleaved result. ``into``: (host band array, first row): where the
        last stage may write its whole output itself (Runtime.host_image), which spares the
        download; the result then has ``host`` set."""
        for i, stage in enumerate(schedule):
            stage_label(stage.name)
            out = None
            if into is not None and i == len(schedule) - 1:
                out = Pipeline._host_output(rt, stage, src, *into)
            dst = stage.enqueue(rt, src, origin) if out is None else stage.enqueue(rt, src, origin, out=out)
            rt.release(src)
            src, origin = dst, advance(origin, stage.halo)
        if not src.interleaved:
            planar, src = src, rt.interleave(src)
            rt.release(planar)
        return src

    @staticmethod
    def _host_output(rt: Any, stage: Stage, src: Any, host: np.ndarray, y: int) -> Any:
        """A host image over ``host[y:y + h]`` for ``stage``'s whole h x w output, when the stage
        can write into one, its output is interleaved and as wide as the band, and the rows fit
        (a last ragged tile's extra rows land in the band's spare rows, never past it)."""
        if not (stage.writes_into and stage.interleaved):
            return None
        h, w = stage.output_shape(src.height, src.width)
        if host.ndim != 3 or host.shape[1] != w or host.shape[2] != stage.out_channels \
                or host.dtype != stage.out_dtype or y + h > host.shape[0]:
            return None
        return rt.host_image(host[y:y + h])

    @staticmethod
    def _device_source(source: WindowSource) -> Any:
        """A device image over the whole mosaic of an in-memory source that the device reads in
        place (Runtime.host_source: a device sharing host memory, an aligned uint16 or float32
        array), so that each tile's window is gathered by the device (Runtime.gather_window), not
        copied by the host; None otherwise (files, discrete GPUs, other dtypes)."""
        if not isinstance(source, ArrayWindows) or source.data.dtype not in (np.uint16, np.float32):
            return None
        return get_runtime().host_source(source.data)

    def _compute_opencl(self, schedule: list[Stage], halo: int, t: Tile, window: np.ndarray | None,
                        target: tuple[np.ndarray, int, int], whole: Any = None,
                        window_shape: tuple[int, int] = (0, 0), image: tuple[int, int] | None = None) -> Any:
        """Enqueue one window's upload (none where the device reads the window in place; where
        ``window`` is None, the device gathers the ``window_shape`` window from ``whole``, its view
        of the whole mosaic), every stage and the download of the kept pixels into ``target`` (or,
        where the last stage wrote into the target itself, what makes those pixels readable);
        returns that event, after which nothing reads the window (nothing waits here: no host
        round trip). ``image``: the whole image's (H, W), passed with each window's Origin."""
        rt = get_runtime()
        stage_label("upload")
        origin = Origin(t.y0 - halo, t.x0 - halo, image)
        if window is None:
            src = rt.gather_window(whole, *origin, *window_shape, self.cfa.period)
        else:
            if window.dtype not in (np.uint16, np.float32):
                window = window.astype(np.float32)
            src = rt.host_input(window) or rt.upload(window)       # in place where the device can
        host, y, x = target
        into = (host, y) if x == 0 and t.w == host.shape[1] else None
        src = self._enqueue_tile(rt, schedule, src, origin, into)
        stage_label("download")
        if src.host is not None:
            event = rt.settle_host_image(src)
        else:
            event = rt.download_region(src, host, y, x, t.h, t.w)
            rt.release(src)                           # the in-order queue copies before reuse
        rt.queue.flush()
        return event


class KeepAlive:
    """A tile's event that also holds host arrays the device reads until it completes (a window
    made for one call, e.g. a path's cropped window): ``wait()`` waits for the event, then lets
    them go."""

    def __init__(self, event: Any, *arrays: np.ndarray) -> None:
        self.event, self.arrays = event, arrays

    def wait(self) -> None:
        if self.event is not None:
            self.event.wait()
        self.arrays = ()


def device_limits(backend: str) -> DeviceLimits:
    """The OpenCL device's memory limits (none for the NumPy reference)."""
    if backend != "opencl":
        return DeviceLimits()
    device = get_runtime().device
    return DeviceLimits(int(device.global_mem_size), int(device.max_mem_alloc_size))


def resolve_options(preset: str | None, demosaic: str | None, kind: str | None = None) -> dict[str, Any]:
    """The options for CFA ``kind`` ('lms' or 'bayer'): the preset's, overridden by explicit ones.

    Raises ClispError on unknown names, and on a demosaic that does not support ``kind``
    (a stage class may declare ``cfa_kinds``; without it, it supports every CFA). With
    ``kind=None`` only the names are checked.
    """
    name = preset or DEFAULT_PRESET
    if name not in PRESETS:
        raise ClispError(f"unknown preset {name!r}; available: {', '.join(PRESETS)}")
    if demosaic and demosaic not in DEMOSAICS:
        raise ClispError(f"unknown demosaic {demosaic!r}; available: {', '.join(DEMOSAICS)}")
    if kind is None:
        return {}
    options = {key: value[kind] if isinstance(value, dict) else value for key, value in PRESETS[name].items()}
    if demosaic:
        options["demosaic"] = demosaic
    kinds = DEMOSAICS[options["demosaic"]].cfa_kinds or (kind,)
    if kind not in kinds:
        raise ClispError(f"demosaic {options['demosaic']!r} works on {' and '.join(kinds)} CFAs, not {kind}")
    return options


def make_demosaic(name: str, raw: RawImage) -> Stage:
    """The demosaic stage ``name`` configured for ``raw`` (its CFA, and its noise if the stage uses it)."""
    return DEMOSAICS[name].for_raw(raw)


def build_pipeline(raw: RawImage, preset: str | None = None, demosaic: str | None = None,
                   output: str = "linear", denoise: ChromaDenoiseParams | bool | None = None,
                   wb2: str = "metadata", skip: bool | None = None,
                   highlights: str | None = None) -> Pipeline:
    """Stages for ``raw``: normalise, WB pass 1, demosaic, highlights, colour (+ chroma denoise),
    WB pass 2, tone curve.

    ``output='linear'`` ends in linear sRGB (for EXR); ``'srgb'`` appends the sRGB tone curve;
    ``'srgb16'`` the tone curve to 16-bit codes, uint16 (for 16-bit TIFF/PNG). ``denoise``: None =
    the preset's depth, False = off, True = on (the preset's depth, at least 1 level), or explicit
    ChromaDenoiseParams; its noise comes from the raw's sensor model, else it is estimated from the
    raw. ``wb2``: white balance pass 2 from
    'metadata' (known illuminant), 'gray_world' or 'gray_pixels'; left out when it is the identity.
    ``skip``: None = every stage on every tile, no scene analysis; True = analyse the raw and let
    each tile skip what it does not need (clisp.skip; the run's plan is ``Pipeline.skip_plan``);
    False = analyse and plan, but every tile takes the full path (``--no-skip --explain``). A
    pipeline without a chroma denoiser (preset fast) has nothing to skip: no analysis (it would
    cost 10-30 ms/MP for nothing). ``highlights``: 'clip', 'reconstruct' or 'off'
    (clisp.modules.highlights.stage), None = the preset's; the stage is left out of raws without clipped
    samples.
    """
    if output not in OUTPUTS:
        raise ClispError(f"unknown output {output!r}; expected one of {', '.join(OUTPUTS)}")
    check_raw(raw)
    cfa = raw.cfa
    options = resolve_options(preset, demosaic, cfa.kind)
    demosaic_stage = make_demosaic(options["demosaic"], raw)
    params = denoise_params(denoise, options["denoise_levels"])
    colour: Stage = ColourMatrix(raw.colour_matrix)
    if params is not None:
        try:
            noise = raw_noise(raw)
        except NoiseEstimateError:
            noise = None        # a raw too small to estimate its noise is processed without chroma denoise
        if noise is not None:
            colour = chroma_denoise_for(raw, demosaic_stage, params, noise, calibration_runtime())
    gains2 = _wb2_gains(raw, wb2)
    stages: list[Stage] = [normalize(cfa, raw.black_level, raw.white_level),
                           white_balance1(cfa, raw.pass1_gains()), demosaic_stage]
    highlight = highlight_stage(raw, highlights or options.get("highlights", DEFAULT_HIGHLIGHTS), gains2)
    if highlight is not None:
        stages.append(highlight)
    stages.append(colour)
    if not np.allclose(gains2, 1.0, rtol=0, atol=0):
        stages.append(WhiteBalance2(gains2))
    if output in ("srgb", "srgb16"):
        stages.append(ToneCurve(quantize=output == "srgb16"))
    pipeline = Pipeline(cfa, stages)
    if skip is not None and any(isinstance(stage, ChromaDenoise) for stage in stages):
        from .skip import Skipper          # deferred (7 ms of start-up); nothing to skip without a chroma denoiser
        pipeline.skipper = Skipper.for_pipeline(raw, stages, enabled=bool(skip))
    return pipeline


def chroma_denoise_for(raw: RawImage, demosaic: Stage, params: ChromaDenoiseParams | None = None,
                       noise: Any = None, rt: Any = None) -> Stage:
    """The colour stage that follows ``demosaic`` for ``raw``, with the noise calibration step of
    building a pipeline: the chroma denoiser's noise table measured through ``demosaic``.

    ``noise``: per-channel noise of the white-balanced raw (:class:`clisp.sim.noise.ChannelNoise`,
    or anything with ``shot``, ``floor`` and ``variance(channel, level)``); None takes it from the
    raw (its sensor model when the metadata has one, else estimated from the mosaic). ``rt``: the
    runtime whose device runs the calibration's demosaic (:func:`calibration_runtime`), None for
    the NumPy reference. Returns a :class:`ChromaDenoise` in the paper's space for the CFA kind
    (LMS: Y = (L+M)/2, chroma R-Y, G-Y, B-Y; Bayer: BT.601 YUV) with that table; when the raw has
    no noise (noiseless simulation) the plain ``ColourMatrix``, which the denoiser would equal
    anyway (so noiseless output is unchanged, and linear demosaics still fuse with it).
    """
    params = params or ChromaDenoiseParams()
    noise = raw_noise(raw) if noise is None else noise
    if is_noiseless(noise) or params.noise_scale == 0:
        return ColourMatrix(raw.colour_matrix)
    space = space_for(raw.cfa.kind, raw.colour_matrix, params.strengths)
    table = calibrate_noise(demosaic, raw.cfa, space, noise, params.levels, rt=rt)
    return ChromaDenoise(space, table, params)


def calibration_runtime() -> Any:
    """The runtime for the noise calibration when an OpenCL device can be had (the calibration
    then runs the demosaic's kernels), else None: the NumPy reference, so that a machine without
    OpenCL can still build a pipeline (and run it with the reference backend)."""
    try:
        return get_runtime()
    except ClispError:
        return None


def check_raw(raw: RawImage) -> None:
    """ClispError naming ``raw.source`` for what the pipeline cannot process into finite pixels:
    levels and gains out of range (rawimage.check_levels), NaN, infinite or absurd samples in a
    float raw (rawimage.check_samples; such raws are refused, not repaired), a mosaic smaller
    than one CFA tile."""
    problem = check_levels(raw)
    if problem:
        raise ClispError(f"{raw.source}: {problem}")
    if raw.data.ndim != 2 or min(raw.data.shape) < raw.cfa.period:
        raise ClispError(f"{raw.source}: raw of {raw.shape[1]}x{raw.shape[0]} is smaller than one "
                         f"{raw.cfa.period}x{raw.cfa.period} CFA tile")
    check_samples(raw)


def _wb2_gains(raw: RawImage, method: str) -> np.ndarray:
    """estimate_wb2's gains, refused (ClispError naming the raw) when not finite and positive:
    a gray-world estimate of a black frame, or a corrupt illuminant in the metadata."""
    try:
        gains = np.asarray(estimate_wb2(raw, method), dtype=np.float64).reshape(3)
    except ClispError as exc:
        raise ClispError(f"{raw.source}: {clip(exc, 120)}") from exc
    except (TypeError, ValueError, np.linalg.LinAlgError) as exc:
        raise ClispError(f"{raw.source}: white balance pass 2 from the metadata failed ({clip(exc)})") from exc
    if not np.all(np.isfinite(gains)) or np.any(gains < 1.0 / MAX_GAIN) or np.any(gains > MAX_GAIN):
        raise ClispError(f"{raw.source}: white balance pass 2 ({method}) gives unusable gains "
                         f"{', '.join(f'{g:.3g}' for g in gains)}")
    return gains


def denoise_params(denoise: ChromaDenoiseParams | bool | None, levels: int) -> ChromaDenoiseParams | None:
    """The chroma denoiser's parameters from a build_pipeline ``denoise`` argument and the preset's
    depth, or None for no denoiser."""
    if isinstance(denoise, ChromaDenoiseParams):
        return denoise
    if denoise is False or (denoise is None and levels == 0):
        return None
    return ChromaDenoiseParams(levels=max(1, int(levels)))


def orient(image: np.ndarray, flip: int) -> np.ndarray:
    """Apply LibRaw's ``sizes.flip`` code (0 none, 3 180 degrees, 5 90 CCW, 6 90 CW) to H x W x C."""
    if flip == 3:
        return image[::-1, ::-1]
    if flip == 5:
        return np.rot90(image, 1)
    if flip == 6:
        return np.rot90(image, -1)
    return image


def crop_of(raw: RawImage) -> tuple[int, int, int, int] | None:
    """The crop ``raw`` declares, (top, left, height, width) in its mosaic's coordinates
    (``metadata['crop']``: a DNG's DefaultCrop, see clisp.io.camera), or None for the whole mosaic
    (none declared, or one that does not lie inside the mosaic)."""
    crop = raw.metadata.get("crop")
    try:
        top, left, height, width = (int(v) for v in crop)
    except (TypeError, ValueError):
        return None
    h, w = raw.shape
    if top < 0 or left < 0 or height <= 0 or width <= 0 or top + height > h or left + width > w:
        return None
    return None if (top, left, height, width) == (0, 0, h, w) else (top, left, height, width)


def cropped_writes(write: Callable[[int, np.ndarray], None],
                   crop: tuple[int, int, int, int]) -> Callable[[int, np.ndarray], None]:
    """``write(y0, rows)`` of a band sink for the whole mosaic's rows, passing on only the crop's
    rows and columns, renumbered from the crop's top. The pipeline runs on the whole mosaic (the
    crop's border pixels see their real neighbours, and tiled still equals whole), the output
    holds the crop; memory stays one band."""
    top, left, height, width = crop

    def write_cropped(y0: int, rows: np.ndarray) -> None:
        a, b = max(y0, top), min(y0 + rows.shape[0], top + height)
        if a < b:
            write(a - top, rows[a - y0:b - y0, left:left + width])
    return write_cropped


def _crop_image(image: np.ndarray, crop: tuple[int, int, int, int] | None) -> np.ndarray:
    if crop is None:
        return image
    top, left, height, width = crop
    return image[top:top + height, left:left + width]


def process_with_stats(raw: RawImage, tile: int | None = None, backend: str = "opencl", crop: bool = True,
                       **options: Any) -> tuple[np.ndarray, RunStats]:
    """:func:`process` for a RawImage, also returning the run's timing."""
    pipeline = build_pipeline(raw, **options)
    image = pipeline.run(raw.data, tile=tile, backend=backend)
    image = _crop_image(image, crop_of(raw) if crop else None)
    image = np.ascontiguousarray(orient(image, int(raw.metadata.get("flip", 0) or 0)))
    return image, pipeline.stats


def process(raw: RawImage | str | Path, tile: int | None = None, backend: str = "opencl", crop: bool = True,
            **options: Any) -> np.ndarray:
    """Process a raw image (or a raw file's path) into H x W x 3 float32 sRGB.

    ``options`` are :func:`build_pipeline`'s: preset, demosaic, output ('linear': scene-linear
    sRGB, white 1.0, unclipped; 'srgb': sRGB-encoded in [0, 1]), denoise, wb2.
    ``crop``: keep only the crop the raw declares (:func:`crop_of`, a DNG's DefaultCrop); False
    keeps the whole mosaic. Orientation from camera metadata is applied last.
    """
    if not isinstance(raw, RawImage):
        raw = read_raw(raw)
    return process_with_stats(raw, tile, backend, crop, **options)[0]


def process_file(raw: RawImage, path: str | Path, tile: int | None = None, budget: int = DEFAULT_BUDGET,
                 backend: str = "opencl", progress: bool = False, compression: str | None = None,
                 explain: dict | None = None, crop: bool = True, **options: Any) -> tuple[tuple[int, int], RunStats]:
    """Process ``raw`` into the image file ``path`` (EXR linear, TIFF/PNG sRGB-encoded), streaming.

    Tile windows are read as needed (from disk for ``read_raw(path, lazy=True)``) and results
    written band by band (imageio.ImageWriter). ``budget`` bounds the peak resident memory of the
    whole process (clisp.engine.memory): what the process holds when planning, plus the tiles' counted
    bytes, plus RSS_MARGIN; ClispError when even the smallest tile does not fit, naming the
    minimum. Raws with a camera rotation are oriented in memory (the whole output counts).
    ``progress``: a progress bar on stderr (when it is a terminal). ``compression``: EXR/TIFF
    compression (default imageio.DEFAULT_COMPRESSION). ``options``: :func:`build_pipeline`'s
    (the output kind follows the extension). ``explain``: a dict that receives the pipeline
    (key 'pipeline'), whose skipper and skip_plan describe the run. ``crop``: write only the crop
    the raw declares (:func:`crop_of`; the whole mosaic is processed, see :func:`cropped_writes`);
    False writes the whole mosaic. The output carries the raw's metadata
    (clisp.io.exif.output_attributes). Atomic: on failure no file.
    Returns the output's (height, width) and the run's stats.
    """
    from .io.imageio import DEFAULT_COMPRESSION, ImageWriter, output_kind, write_image   # deferred: 2 ms of start-up
    compression = compression or DEFAULT_COMPRESSION
    region = crop_of(raw) if crop else None
    attributes = output_attributes(raw)
    kind = output_kind(path)
    pipeline = build_pipeline(raw, output="srgb16" if kind == "srgb" else kind, **options)
    if explain is not None:                       # the caller reads the plan after the run
        explain["pipeline"] = pipeline
    flip = int(raw.metadata.get("flip", 0) or 0)
    plan = _whole_process_plan(pipeline, raw, path, tile, budget, backend, in_memory=bool(flip))
    if flip:                    # rotated output rows are input columns: orient the whole result
        image = np.empty(raw.shape + (pipeline.out_channels,), dtype=pipeline.out_dtype)
        with closing(window_source(raw.data)) as source:
            pipeline.stream(source, ArraySink(image), plan, backend)
        oriented = orient(_crop_image(image, region), flip)
        write_image(path, oriented, compression=compression, attributes=attributes)
        return oriented.shape[:2], pipeline.stats
    (height, width), channels = raw.shape, pipeline.out_channels
    out_h, out_w = (height, width) if region is None else region[2:]
    bar = progress_bar(plan.tiles, Path(path).name) if progress else nullcontext(None)
    start = time.perf_counter()
    with closing(window_source(raw.data)) as source, \
            ImageWriter(path, out_w, out_h, channels, compression, attributes) as writer, \
            BandSink(writer.write_rows if region is None else cropped_writes(writer.write_rows, region),
                     plan, width, channels, pipeline.out_dtype) as sink, bar as update:
        stats = pipeline.stream(source, sink, plan, backend, progress=update)
    return (out_h, out_w), replace(stats, seconds=time.perf_counter() - start)    # the last write included


def _whole_process_plan(pipeline: Pipeline, raw: RawImage, path: str | Path, tile: int | None, budget: int,
                        backend: str, in_memory: bool) -> TilePlan:
    """The plan of :func:`process_file` for a whole-process ``budget`` (see clisp.engine.memory): the
    tiles get what the process does not already hold. ``in_memory``: the whole output is held
    (oriented raws) and counts too. ClispError naming the minimum when nothing fits."""
    from .engine.memory import RSS_MARGIN, format_bytes, resident_bytes   # deferred: 0.6 ms (with resource)
    shape, dtype = raw.shape, raw.data.dtype
    if backend != "opencl":
        return pipeline.plan(shape, dtype, tile, budget, backend)
    limits = device_limits(backend)
    cost = pipeline.tile_cost(dtype, shape[1], limits, sink_bands=not in_memory)
    smallest = cost(min(shape[0], MIN_TILE), min(shape[1], MIN_TILE))   # also builds the programs
    held = resident_bytes() + RSS_MARGIN
    if in_memory:
        held += shape[0] * shape[1] * pipeline.out_channels * pipeline.out_dtype.itemsize
    if budget - held < smallest:
        raise ClispError(f"{path}: --mem {format_bytes(budget)} is below the minimum of "
                         f"{format_bytes(held + smallest)} for this {shape[1]}x{shape[0]} raw and these "
                         f"settings ({format_bytes(held)} for the process itself, "
                         f"{format_bytes(smallest)} for the smallest tile)")
    needs = replace(pipeline.needs(dtype), cost=cost)
    try:
        return make_plan(shape[0], shape[1], needs, tile, budget - held, limits)
    except ClispError as exc:
        raise ClispError(f"{path}: {exc}") from exc
