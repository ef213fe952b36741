"""The executor: a list of stages run over tiles, on OpenCL or the NumPy reference.

:class:`Pipeline` holds the stages; :meth:`Pipeline.plan` sizes the tiles from the stages' declared
needs and the memory budget (clisp.engine.tiling), :meth:`Pipeline.stream` runs them window by
window (clisp.engine.streaming), each window's stages enqueued one after another on the device
with no host round trip, and each window's origin passed as an Origin that carries the image's
extent (the planner alone knows the image). Which stages a raw gets is clisp.pipeline's.
"""
from __future__ import annotations

import math
import pickle
import threading
import time
from collections import OrderedDict
from contextlib import closing
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Any, Callable

import numpy as np

from ..cfa import CFA
from ..errors import ClispError
from .disk_cache import device_identity, entry_name, read_json, write_json
from . import profile
from .profile import host_timer, path_label, stage_label
from .runtime import DeviceImage, get_runtime
from .stage import Origin, Stage, advance, fuse_stages
from .streaming import (READ_AHEAD, ArrayWindows, TileSink, WindowPool, WindowSource, aligned_array, array_sink,
                        run_tiles, window_source)
from .tiling import (DEVICE_SHARE, GPU_TARGET_TILE_PIXELS, TARGET_TILE_PIXELS, DeviceLimits, Tile, TileNeeds,
                     TilePlan, make_plan)

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
    """Wall time of the last run, its throughput in megapixels per second, its tiling and what its
    kernels counted (Runtime.counter: e.g. 'sensor_found', the pixels the auto search replaced; empty
    on the reference backend)."""

    seconds: float = 0.0
    megapixels: float = 0.0
    tiles: int = 0
    tile_shape: tuple[int, int] = (0, 0)
    counts: dict[str, int] = field(default_factory=dict)

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
    """A clisp.pipeline.skip.Skipper (build_pipeline ``skip``): per-tile paths from the scene analysis."""
    skip_plan: Any = None
    """The clisp.pipeline.skip.SkipPlan of the last run (None without a skipper)."""
    exposure_ev: float = 0.0
    """The exposure (EV) build_pipeline applied, manual and automatic together."""
    wb_source: str = "camera"
    """Where white balance pass 1's multipliers came from (``--wb``; clisp.scene.white_balance)."""
    wb_explain: str = ""
    """What ``--wb auto`` found and what decided it, one line (``--explain``); empty otherwise."""
    stage_choice: Any = None
    """The noise-adaptive choice build_pipeline made (clisp.pipeline.demosaic_choice.Choice), None without one."""
    skip_off: str = ""
    """Why build_pipeline made no skipper although skipping was asked for (clisp.pipeline.skip.why_not_skip)."""
    scene_statistics: Any = None
    """The raw's clisp.scene.statistics.SceneStatistics when build_pipeline's estimates read them (``--explain``)."""

    @property
    def halo(self) -> int:
        """Total input border one output pixel needs, in input (raw) pixels: the sum of the stage
        halos, each times the input pixels per pixel of its own input (after a stage of downscale 2,
        a halo of 1 is 2 raw pixels)."""
        total, scale = 0, 1
        for stage in self.stages:
            total += stage.halo * scale
            scale *= stage.downscale
        return total

    @property
    def downscale(self) -> int:
        """Input pixels per output pixel along each axis: 1, or 2 with the half-size binning."""
        return math.prod(stage.downscale for stage in self.stages)

    @property
    def align(self) -> int:
        """Tile-origin multiple, in output pixels: the CFA period and every stage's alignment (with
        ``downscale`` > 1 the windows then start ``downscale`` times further apart: still on the period)."""
        return math.lcm(self.cfa.period, *(stage.align for stage in self.stages))

    def output_shape(self, shape: tuple[int, int]) -> tuple[int, int]:
        """The output (H, W) for an H x W raw: the raw's, divided by :attr:`downscale` and rounded up (a
        last odd row or column is binned with its CFA-mirrored padding, as LibRaw's half_size)."""
        s = self.downscale
        return -(-int(shape[0]) // s), -(-int(shape[1]) // s)

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
        area = float(self.downscale ** 2)                 # output pixels are this many raw pixels
        out_bytes = float(self.out_dtype.itemsize * self.out_channels) / area
        stage_bytes, scale = [], 1
        for stage in self.stages:                        # declared per pixel of its own input: per raw pixel
            stage_bytes.append(float(stage.bytes_per_pixel) / scale ** 2)
            scale *= stage.downscale
        return TileNeeds(halo=self.halo, align=self.align,
                         device_bytes=raw_bytes + sum(stage_bytes) + out_bytes,
                         host_bytes=TILES_IN_FLIGHT * (raw_bytes + out_bytes),
                         largest_bytes=max(stage_bytes + [raw_bytes, out_bytes]), downscale=self.downscale)

    def plan(self, shape: tuple[int, int], raw_dtype: Any, tile: int | None = None,
             budget: int = DEFAULT_BUDGET, backend: str = "opencl", sink_bands: bool = False) -> TilePlan:
        """Tiles for an H x W raw: ``tile`` None = from ``budget`` (bytes for the tiles in flight)
        and the device's limits, 0 = the whole image, N = N x N (see tiling.make_plan); tiles are
        in output pixels (:meth:`output_shape`).

        On OpenCL the tiles' bytes are counted exactly (:meth:`tile_cost`); ``sink_bands``: also
        count the band buffers and writer rows of a streamed output file (process_file)."""
        limits = device_limits(backend)
        key = self._key(True)
        if key is not None:
            key += repr((tuple(shape), np.dtype(raw_dtype).str, tile, budget, backend, sink_bands, limits)).encode()
            plan = PLANS.get(key)
            if plan is not None:
                return plan
        needs = self.needs(raw_dtype)
        out_h, out_w = self.output_shape(shape)
        if backend == "opencl":
            needs = replace(needs, cost=self.tile_cost(raw_dtype, out_w, limits, sink_bands))
        plan = make_plan(out_h, out_w, needs, tile, budget, limits)
        if key is not None:
            PLANS.put(key, plan)
        return plan

    def tile_cost(self, raw_dtype: Any, image_width: int, limits: DeviceLimits,
                  sink_bands: bool) -> Callable[[int, int], float]:
        """Bytes one tile of (rows, columns) output pixels takes while it runs, as a function:
        its device buffers, measured by enqueueing the tile's schedule in a metering run (exact,
        whatever the stages allocate), counted as host memory when they are
        (:func:`device_buffers_in_host_memory`: a CPU device, not a discrete GPU); READ_WINDOWS raw windows; with
        ``sink_bands`` SINK_BANDS output bands of the image's width and the writer's converted rows.
        inf past DEVICE_SHARE of the device's memory or its largest allocation. ``image_width``:
        the output's (:meth:`output_shape`)."""
        rt = get_runtime()
        schedule = self.schedule()
        shared = device_buffers_in_host_memory(rt)
        raw_item = np.dtype(raw_dtype).itemsize
        out_px = self.out_channels * self.out_dtype.itemsize
        halo, scale = self.halo, self.downscale
        kept = _kept_metering_name(rt, schedule, raw_dtype)
        metered: dict[str, list[int]] | None = METERED.get(kept) if kept else None
        if metered is None:
            metered = (read_json("metering", kept) if kept else None) or {}
            if kept:
                METERED.put(kept, metered)

        def cost(rows: int, cols: int) -> float:
            window = (rows * scale + 2 * halo, cols * scale + 2 * halo)
            at = f"{window[0]}x{window[1]}"
            if at not in metered:
                metered[at] = list(self.metered_tile(schedule, window, raw_dtype))
                if kept:
                    write_json("metering", kept, metered)
            created, largest = metered[at]
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
            rt.release(self._enqueue_tile(rt, schedule, src, (-self.halo, -self.halo)))   # the first tile's origin
        return meter.created, meter.largest

    def run(self, data: np.ndarray, tile: int | None = None, backend: str = "opencl",
            fuse: bool = True, budget: int = DEFAULT_BUDGET) -> np.ndarray:
        """Process an H x W raw mosaic (DN, uint16 or float32) into H x W x 3 float32 (uint16
        for a pipeline built with output 'srgb16'); with ``downscale`` 2 (half size) into
        :meth:`output_shape` x 3.

        ``tile``: output tile side in pixels; None (default) chooses tiles from ``budget`` (bytes)
        and the device's limits, 0 runs the whole image as one tile.
        ``backend``: 'opencl' (kernels) or 'reference' (NumPy, float64 inside, stage by stage).
        ``fuse``: on OpenCL, merge neighbouring stages that compose (e.g. normalise, WB 1, bilinear
        demosaic and colour matrix become one kernel); False runs one kernel per stage.
        A read-only memory map of a raw file (``read_raw(path, lazy=True)``) is read tile by tile.
        """
        self._check(data.shape, backend)
        out = aligned_array(self.output_shape(data.shape) + (self.out_channels,), self.out_dtype)
        plan = self.plan(data.shape, data.dtype, tile, budget, backend)
        sink = array_sink(out, get_runtime() if backend == "opencl" else None)
        with closing(window_source(data)) as source, closing(sink):
            self.stream(source, sink, plan, backend, fuse)
        return out

    def stream(self, source: WindowSource, sink: TileSink, plan: TilePlan, backend: str = "opencl",
               fuse: bool = True, progress: Callable[[Tile], None] | None = None) -> RunStats:
        """Run ``plan`` from ``source`` into ``sink`` (see streaming.run_tiles); sets and returns
        :attr:`stats`."""
        self._check(source.shape, backend)
        image = (int(source.shape[0]), int(source.shape[1]))     # the planner's alone; stages get it per window
        win_h, win_w = plan.window_shape
        whole = self._device_source(source, plan) if backend == "opencl" else None
        if backend == "opencl":                      # halo passed on: stages recompute it per call
            schedule = self.schedule(fuse)           # the pool holds what this plan's tiles need
            get_runtime().trim_pool(keep=_pool_key(schedule, plan, whole is not None, self.skipper))
            compute = partial(self._compute_opencl, schedule, plan, whole=whole, image=image)
        else:
            compute = partial(self._compute_reference, plan, image=image)

        if self.skipper is not None:                 # per-tile paths (clisp.pipeline.skip), on the raw's grid
            compute = self._path_compute(plan, backend, fuse, whole, compute, image)

        rt = get_runtime() if backend == "opencl" else None
        windows = WindowPool(staging=rt.staging if rt is not None and not rt.host_unified else None)

        def read(t: Tile) -> np.ndarray:
            with host_timer("read tile windows"):
                return source.read(*plan.window_origin(t), win_h, win_w, self.cfa.period,
                                   windows.take((win_h, win_w), source.window_dtype))

        recording = profile.active()
        loop = recording.begin_loop() if recording is not None else None
        if rt is not None:
            rt.reset_counters()                      # this run's counts only (Runtime.counter)
        counts: dict[str, int] = {}
        start = time.perf_counter()
        try:                                         # where the device gathers each window: no reads
            run_tiles(plan, None if whole is not None else read, compute, sink, progress,
                      release=None if whole is not None else windows.give)
        finally:
            if backend == "opencl":
                get_runtime().finish()                # no copy may still target the sink's arrays
                if whole is not None:
                    get_runtime().release(whole)      # a staged mosaic's buffers back to their pools
            windows.close()
        seconds = time.perf_counter() - start
        if rt is not None:
            counts = rt.read_counters()
        if loop is not None:
            recording.end_loop(loop, seconds, len(plan.tiles))
        height, width = source.shape
        self.stats = RunStats(seconds, height * width / 1e6, len(plan.tiles), (plan.tile_h, plan.tile_w), counts)
        return self.stats

    def _path_compute(self, plan: TilePlan, backend: str, fuse: bool, whole: Any,
                      full: Callable[..., Any], image: tuple[int, int]) -> Callable[..., Any]:
        """The compute step of :meth:`stream` choosing each tile's path from the skipper's plan
        (sets :attr:`skip_plan`). A path with a smaller halo runs on the centre of the tile's
        window (its origin moves in by the difference), so every path sees the image's pixels
        at the same coordinates and tiled equals whole per path."""
        skipper = self.skipper
        assert plan.downscale == 1, "skip paths run on the raw's grid (no skipper with --half-size)"
        self.skip_plan = skip_plan = skipper.plan(plan)
        halo = plan.halo
        computes: dict[str, Callable[..., Any]] = {"full": full}
        if "mixed" in skip_plan.counts:
            computes["mixed"] = partial(self._mixed_compute, MixedRun.of(skipper, skip_plan, self.cfa, fuse),
                                        plan, backend, whole, image)
        for name in set(skip_plan.counts) - {"full", "mixed"}:
            sub = Pipeline(self.cfa, skipper.paths[name])
            d = halo - sub.halo
            sub_plan = replace(plan, halo=sub.halo)
            if backend == "opencl":
                run = partial(sub._compute_opencl, sub.schedule(fuse), sub_plan, whole=whole, image=image)
            else:
                run = partial(sub._compute_reference, sub_plan, image=image)

            def crop(t: Tile, window: np.ndarray | None, target: Any, run: Callable[..., Any] = run,
                     d: int = d) -> Any:
                if window is None:
                    return run(t, window, target)
                inner = np.ascontiguousarray(window[d:window.shape[0] - d, d:window.shape[1] - d])
                # the device may read ``inner`` in place (or copy it asynchronously) until the tile's
                # event: keep it alive with the event, not only for this call
                return KeepAlive(run(t, inner, target), inner)
            computes[name] = crop
        def compute(t: Tile, window: np.ndarray | None, target: Any) -> Any:
            path = skip_plan.path_of(t)
            path_label(path)
            return computes[path](t, window, target)
        return compute

    def _mixed_compute(self, mixed: "MixedRun", plan: TilePlan, backend: str, whole: Any, image: tuple[int, int],
                       t: Tile, window: np.ndarray | None, target: tuple[np.ndarray, int, int]) -> Any:
        """One ``mixed`` tile of the skip plan (clisp.pipeline.skip): the flat path's head over the whole
        tile, the tile's detail path's head on each of its rectangles, joined into the flat output
        by the block blend (clisp.modules.block_blend: per pixel, by the distance to texture), then
        the stages every path shares, once. Each head runs on its own window of the image (cut from
        the tile's window, or gathered by the device), so a pixel's output does not depend on the
        tiling. No host round trip: the join is a kernel."""
        choice = self.skip_plan.choice(t)
        blend, heads, margins = mixed.blend, mixed.heads, mixed.margins
        halo = plan.halo
        kept: list[np.ndarray] = []

        def region_window(y0: int, x0: int, h: int, w: int, margin: int) -> np.ndarray:
            oy, ox = y0 - margin - (t.y0 - halo), x0 - margin - (t.x0 - halo)
            return window[oy:oy + h + 2 * margin, ox:ox + w + 2 * margin]

        regions = [("flat", t)] + [(choice.detail, r) for r in choice.rects]
        if backend != "opencl":
            out = None
            for name, r in regions:
                x = region_window(r.y0, r.x0, r.h, r.w, margins[name])
                origin = Origin(r.y0 - margins[name], r.x0 - margins[name], image)
                for stage in heads[name]:
                    x = stage.reference(x, origin)
                    origin = advance(origin, stage.halo, stage.downscale)
                if out is None:
                    out = x
                else:
                    blend.reference(out, x, (r.y0 - t.y0, r.x0 - t.x0), (r.y0, r.x0))
            origin = Origin(t.y0, t.x0, image)
            for stage in mixed.tail:
                out = stage.reference(out, origin)
            host, y, x0 = target
            host[y:y + t.h, x0:x0 + t.w] = out
            return None

        rt = get_runtime()
        flat = None
        for k, (name, r) in enumerate(regions):
            m = margins[name]
            path_label(f"mixed: {'flat' if k == 0 else choice.detail} path")
            stage_label("upload")
            part = None
            if window is not None:
                part = np.ascontiguousarray(region_window(r.y0, r.x0, r.h, r.w, m),
                                            dtype=None if window.dtype in (np.uint16, np.float32) else np.float32)
                kept.append(part)                     # the device may read it in place until the tile's event
            origin = Origin(r.y0 - m, r.x0 - m, image)
            src = self._window_image(rt, whole, part, origin, (r.h + 2 * m, r.w + 2 * m))
            dst = self._enqueue_stages(rt, mixed.schedules[name], src, origin)
            if flat is None:
                flat = dst
            else:
                path_label("mixed: join and the shared stages")
                stage_label("block_blend")
                blend.enqueue(rt, flat, dst, (r.y0 - t.y0, r.x0 - t.x0), (r.y0, r.x0))
                rt.release(dst)
        path_label("mixed: join and the shared stages")
        host, y, x = target
        into = (host, y) if x == 0 and t.w == host.shape[1] else None
        src = self._enqueue_tile(rt, mixed.tail_schedule, flat, Origin(t.y0, t.x0, image), into)
        return KeepAlive(self._deliver(rt, src, t, target), *kept)

    def _check(self, shape: tuple[int, ...], backend: str) -> None:
        if backend not in ("opencl", "reference"):
            raise ClispError(f"unknown backend {backend!r}; expected opencl or reference")
        if len(shape) != 2:
            raise ClispError(f"raw data must be H x W, got shape {tuple(shape)}")
        if min(shape) < self.cfa.period:
            raise ClispError(f"raw of {shape[1]}x{shape[0]} is smaller than one CFA tile")

    def _compute_reference(self, plan: TilePlan, t: Tile, window: np.ndarray,
                           target: tuple[np.ndarray, int, int], image: tuple[int, int] | None = None) -> None:
        """The NumPy stages on the tile's own window (the plan's may reach past the image);
        ``image``: the whole (input) image's (H, W), passed to the stages with each window's Origin."""
        s, halo = plan.downscale, plan.halo
        x, origin = window[:t.h * s + 2 * halo, :t.w * s + 2 * halo], Origin(*plan.window_origin(t), image)
        for stage in self.stages:
            x = stage.reference(x, origin)
            origin = advance(origin, stage.halo, stage.downscale)
        host, y, x0 = target
        host[y:y + t.h, x0:x0 + t.w] = x
        return None

    def _key(self, fuse: bool) -> bytes | None:
        """:func:`_stages_key` of this pipeline's stages, pickled once per list of stage objects (in
        this process: :data:`KEYS`, so the pipelines that clisp.pipeline.build makes of the same
        kept stages pickle none)."""
        ident = tuple(map(id, self.stages))
        cached = KEYS.get(ident)
        if cached is None or any(a is not b for a, b in zip(cached[0], self.stages)):
            cached = (tuple(self.stages), {})
            KEYS.put(ident, cached)
        if fuse not in cached[1]:
            cached[1][fuse] = _stages_key(self.stages, fuse)
        return cached[1][fuse]

    def schedule(self, fuse: bool = True) -> list[Stage]:
        """The stages as run on OpenCL: fused where they compose, the last one writing the host's
        interleaved layout when it can. Made once per process for equal stages (:data:`SCHEDULES`,
        keyed by their pickle), so every call of one camera and settings launches the same stage
        objects, whose kernels, sources and constants are resolved once."""
        key = self._key(fuse)
        schedule = SCHEDULES.get(key) if key is not None else None
        if schedule is None:
            schedule = fuse_stages(self.stages) if fuse else list(self.stages)
            last = schedule[-1].with_interleaved_output()
            if last is not None:
                schedule[-1] = last
            if key is not None:
                SCHEDULES.put(key, schedule)
        return list(schedule)

    @staticmethod
    def _enqueue_tile(rt: Any, schedule: list[Stage], src: Any, origin: tuple[int, int],
                      into: tuple[np.ndarray, int] | None = None) -> Any:
        """Enqueue every stage of ``schedule`` on the uploaded window ``src`` (released on the
        way); returns the interleaved result. ``into``: (host band array, first row): where the
        last stage may write its whole output itself (Runtime.host_image), which spares the
        download; the result then has ``host`` set."""
        src = Pipeline._enqueue_stages(rt, schedule, src, origin, into)
        if not src.interleaved:
            planar, src = src, rt.interleave(src)
            rt.release(planar)
        return src

    @staticmethod
    def _enqueue_stages(rt: Any, schedule: list[Stage], src: Any, origin: tuple[int, int],
                        into: tuple[np.ndarray, int] | None = None) -> Any:
        """Enqueue every stage of ``schedule`` on ``src`` (released on the way); returns the last
        stage's output as it is (planar or interleaved). ``into``: see :meth:`_enqueue_tile`."""
        for i, stage in enumerate(schedule):
            stage_label(stage.name)
            out = None
            if into is not None and i == len(schedule) - 1:
                out = Pipeline._host_output(rt, stage, src, *into)
            dst = stage.enqueue(rt, src, origin) if out is None else stage.enqueue(rt, src, origin, out=out)
            rt.release(src)
            src, origin = dst, advance(origin, stage.halo, stage.downscale)
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
    def _device_source(source: WindowSource, plan: TilePlan) -> Any:
        """The whole mosaic of an in-memory source (uint16 or float32) on the device, so that each
        tile's window is gathered there (Runtime.gather_window), not copied by the host; None where
        the host reads the windows (files, other dtypes; see :func:`resident_policy`)."""
        if not isinstance(source, ArrayWindows) or source.data.dtype not in (np.uint16, np.float32):
            return None
        rt = get_runtime()
        if rt.host_unified:                    # read in place where aligned; one window the host gathers
            return rt.host_source(source.data) if len(plan.tiles) > 1 else None
        if not resident_policy(rt, source.data.nbytes, len(plan.tiles)):
            return None
        return rt.resident_mosaic(source.data)

    def _compute_opencl(self, schedule: list[Stage], plan: TilePlan, t: Tile, window: np.ndarray | None,
                        target: tuple[np.ndarray, int, int], whole: Any = None,
                        image: tuple[int, int] | None = None) -> Any:
        """Enqueue one window's upload (none where the device reads the window in place; where
        ``window`` is None, the device gathers the plan's window from ``whole``, its view of the
        whole mosaic), every stage and the download of the kept pixels into ``target`` (or,
        where the last stage wrote into the target itself, what makes those pixels readable);
        returns that event, after which nothing reads the window (nothing waits here: no host
        round trip). ``image``: the whole (input) image's (H, W), passed with each window's Origin."""
        rt = get_runtime()
        stage_label("upload")
        origin = Origin(*plan.window_origin(t), image)
        src = self._window_image(rt, whole, window, origin, plan.window_shape)
        host, y, x = target
        into = (host, y) if x == 0 and t.w == host.shape[1] else None
        src = self._enqueue_tile(rt, schedule, src, origin, into)
        return self._deliver(rt, src, t, target)

    def _window_image(self, rt: Any, whole: Any, window: np.ndarray | None, origin: tuple[int, int],
                      shape: tuple[int, int]) -> Any:
        """The device image of an input window at image ``origin`` of ``shape``: gathered by the
        device from ``whole`` where ``window`` is None, else the host window read in place where
        the device can, or uploaded (as float32 unless uint16 or float32)."""
        if window is None:
            return rt.gather_window(whole, *origin, *shape, self.cfa.period)
        if window.dtype not in (np.uint16, np.float32):
            window = window.astype(np.float32)
        return rt.host_input(window) or rt.upload(window)       # in place where the device can

    @staticmethod
    def _deliver(rt: Any, src: Any, t: Tile, target: tuple[np.ndarray, int, int]) -> Any:
        """The download of tile ``t``'s interleaved result ``src`` into ``target`` (or, where the
        last stage wrote into the target itself, what makes those pixels readable); its event."""
        host, y, x = target
        stage_label("download")
        if src.host is not None:
            event = rt.settle_host_image(src)
        else:
            event = rt.download_region(src, host, y, x, t.h, t.w)
            rt.release(src, after=event)              # reused once the copy has read it
        rt.queue.flush()
        return event


def _kept_metering_name(rt: Any, schedule: list[Stage], raw_dtype: Any) -> str | None:
    """The name under which the metered tiles of ``schedule`` on ``rt``'s device are kept on disk
    (clisp.engine.disk_cache): from the pickled stages (their parameters, matrices, noise tables),
    the raw's dtype, the device and whether it shares host memory. A metering run of a 0.25 MP
    quality pipeline costs 20-30 ms of Python; a raw of the same camera and gain reads it instead.
    None when a stage does not pickle (then nothing is kept)."""
    try:
        stages = pickle.dumps((schedule, np.dtype(raw_dtype).str), protocol=4)
    except (pickle.PicklingError, TypeError, AttributeError):
        return None
    return entry_name(stages, device_identity(rt.platform, rt.device), str(rt.host_unified))


@dataclass
class MixedRun:
    """What every ``mixed`` tile of one run shares (clisp.pipeline.skip): the join, each path's head (the
    flat one with its texture blocks unread), their halos and OpenCL schedules, and the stages
    after the join with theirs. Made once per run by :meth:`of`."""

    blend: Any
    heads: dict[str, list[Stage]]
    margins: dict[str, int]
    schedules: dict[str, list[Stage]]
    tail: list[Stage]
    tail_schedule: list[Stage]

    @classmethod
    def of(cls, skipper: Any, skip_plan: Any, cfa: CFA, fuse: bool) -> "MixedRun":
        blend = skipper.block_blend()
        names = {"flat"} | {c.detail for c in skip_plan.choices if c.rects}
        heads = {name: skipper.mixed_head(name, blend) for name in names}
        return cls(blend, heads, {name: sum(stage.halo for stage in head) for name, head in heads.items()},
                   {name: fuse_stages(head) if fuse else list(head) for name, head in heads.items()},
                   skipper.tail, Pipeline(cfa, skipper.tail).schedule(fuse) if skipper.tail else [])


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


def device_buffers_in_host_memory(rt: Any) -> bool:
    """Whether the device buffers of runtime ``rt`` are this host's memory, so that a plan counts
    them against the host budget (``--mem``; :meth:`Pipeline.tile_cost`): on a device sharing host
    memory or a CPU device (PoCL's buffers are resident pages of this process). False on a
    discrete GPU: its own memory bounds its buffers (DEVICE_SHARE), the budget only the host's."""
    return bool(rt.host_unified or rt.device.type & rt.cl.device_type.CPU)


def device_limits(backend: str) -> DeviceLimits:
    """The OpenCL device's memory limits (none for the NumPy reference)."""
    if backend != "opencl":
        return DeviceLimits()
    rt = get_runtime()
    device = rt.device
    target = TARGET_TILE_PIXELS if rt.host_unified else GPU_TARGET_TILE_PIXELS
    return DeviceLimits(int(device.global_mem_size), int(device.max_mem_alloc_size), target)


class Memo:
    """A small least-recently-used map of what a process works out once per camera and settings
    (schedules, plans, metered tiles): ``get`` (None when absent) and ``put``; at most ``size``
    entries, the oldest dropped first."""

    def __init__(self, size: int = 32) -> None:
        self.size = size
        self._items: OrderedDict[Any, Any] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: Any) -> Any:
        with self._lock:
            value = self._items.get(key)
            if value is not None:
                self._items.move_to_end(key)
            return value

    def put(self, key: Any, value: Any) -> None:
        with self._lock:
            self._items[key] = value
            self._items.move_to_end(key)
            while len(self._items) > self.size:
                self._items.popitem(last=False)

    def clear(self) -> None:
        with self._lock:
            self._items.clear()

    def __len__(self) -> int:
        return len(self._items)


KEYS = Memo()
"""Pipeline._key's pickled stages by the identities of the stage objects, with the objects themselves
(held, so no other object takes one of their identities while the entry lives)."""

SCHEDULES = Memo()
"""Pipeline.schedule's fused stages, by the pickled stages (:func:`_stages_key`)."""

PLANS = Memo()
"""Pipeline.plan's TilePlans (frozen), by the pickled stages and the plan's arguments."""

METERED = Memo()
"""Pipeline.tile_cost's metered windows, by the kept name (also on disk: clisp.engine.disk_cache)."""


def _stages_key(stages: list[Stage], fuse: bool) -> bytes | None:
    """The memo key of ``stages`` (their pickle: every parameter, matrix and noise table) run with
    ``fuse``, and the runtime's device; None when a stage does not pickle (nothing is memoised)."""
    try:
        return pickle.dumps((stages, fuse), protocol=4) + str(id(get_runtime())).encode()
    except (pickle.PicklingError, TypeError, AttributeError):
        return None


def _pool_key(schedule: list[Stage], plan: TilePlan, gathered: bool, skipper: Any) -> Any:
    """What a run's pooled buffers depend on (Runtime.trim_pool): the identity of its schedule's
    stages (memoised per settings: Pipeline.schedule), its window shape and whether the device
    gathers the windows; None (always trim) with a skipper, whose per-tile paths vary."""
    if skipper is not None:
        return None
    return tuple(id(stage) for stage in schedule), plan.window_shape, plan.tile_h, plan.tile_w, gathered


RESIDENT_SHARE = 0.25
"""Largest share of a discrete device's global memory that a whole mosaic may take to stay on the
device for a run (Runtime.resident_mosaic); its tiles' buffers keep the rest of DEVICE_SHARE. A
24 MP uint16 mosaic is 48 MB: 0.06 % of an 80 GB GPU."""


def resident_policy(rt: Any, nbytes: int, tiles: int) -> bool:
    """Whether a run copies an in-memory mosaic the device cannot read in place (not aligned, or a
    discrete device) to the device once (Runtime.resident_mosaic) instead of the host gathering
    each tile's window: on a discrete device when it fits RESIDENT_SHARE of its memory (one upload
    from pinned memory, then windows gathered on the device); never on a device sharing host
    memory. There the reader thread gathers windows while the device runs; a plan of one tile has
    its window gathered by the host on the calling thread, which for a 0.26 MP raw costs 40 us
    against 250 us for a staging copy and a gather kernel with its dispatch (README.md)."""
    if rt.host_unified:
        return False
    return nbytes <= RESIDENT_SHARE * int(rt.device.global_mem_size)
