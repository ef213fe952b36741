"""The processing pipeline: a list of configured stages run over tiles on OpenCL or NumPy.

The pipeline is data. :func:`build_pipeline` turns a raw image and a few choices into a list of
stages; later work can drop or swap stages per image or per tile without touching the runner.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from .cfa import CFA
from .errors import ClispError
from .rawimage import RawImage
from .runtime import get_runtime
from .stages.base import Stage, fuse_stages
from .stages.colour import ColourMatrix, ToneCurve, WhiteBalance2
from .stages.demosaic_bilinear import DemosaicBilinear
from .stages.demosaic_dlmmse import DemosaicDLMMSE
from .stages.demosaic_lms import DemosaicLMSHybrid
from .stages.demosaic_malvar import DemosaicMalvar
from .stages.raw_scale import normalize, white_balance1
from .tiling import Tile, gather_window, plan_tiles

DEMOSAICS: dict[str, Callable[[CFA], Stage]] = {
    "bilinear": DemosaicBilinear,
    "malvar": DemosaicMalvar,
    "dlmmse": DemosaicDLMMSE,
    "hybrid": DemosaicLMSHybrid,
}
"""Demosaic stages by CLI name; each takes the CFA description."""

PRESETS: dict[str, dict[str, dict[str, str]]] = {
    "fast": {"demosaic": {"lms": "bilinear", "bayer": "bilinear"}},
}
"""Named parameter sets (``--preset``), each option given per CFA kind; explicit options override."""

DEFAULT_PRESET = "fast"
OUTPUTS = ("linear", "srgb")


@dataclass
class RunStats:
    """Wall time of the last run and its throughput in megapixels per second."""

    seconds: float = 0.0
    megapixels: float = 0.0
    tiles: int = 0

    @property
    def mp_per_s(self) -> float:
        return self.megapixels / self.seconds if self.seconds > 0 else float("nan")


@dataclass
class Pipeline:
    """Stages applied in order to a raw mosaic; the first stage reads raw DN, the last writes RGB."""

    cfa: CFA
    stages: list[Stage]
    stats: RunStats = field(default_factory=RunStats)

    @property
    def halo(self) -> int:
        """Total input border one output pixel needs (sum of the stage halos)."""
        return sum(stage.halo for stage in self.stages)

    def describe(self) -> str:
        return " -> ".join(stage.name for stage in self.stages)

    def run(self, data: np.ndarray, tile: int | None = None, backend: str = "opencl",
            fuse: bool = True) -> np.ndarray:
        """Process an H x W raw mosaic (DN, uint16 or float32) into H x W x 3 float32.

        ``tile``: output tile side in pixels (None: the whole image is one tile).
        ``backend``: 'opencl' (kernels) or 'reference' (NumPy, float64 inside, stage by stage).
        ``fuse``: on OpenCL, merge neighbouring stages that compose (e.g. normalise, WB 1, bilinear
        demosaic and colour matrix become one kernel); False runs one kernel per stage.
        """
        if backend not in ("opencl", "reference"):
            raise ClispError(f"unknown backend {backend!r}; expected opencl or reference")
        height, width = data.shape
        if min(height, width) < self.cfa.period:
            raise ClispError(f"raw of {width}x{height} is smaller than one CFA tile")
        out = np.empty((height, width, self.stages[-1].out_channels), dtype=np.float32)
        tiles = plan_tiles(height, width, tile, align=self.cfa.period)
        start = time.perf_counter()
        if backend == "opencl":
            schedule = self.schedule(fuse)
            for t in tiles:
                self._run_tile_opencl(schedule, data, t, out)
        else:
            for t in tiles:
                out[t.y0:t.y0 + t.h, t.x0:t.x0 + t.w] = self._run_tile_reference(data, t)
        self.stats = RunStats(time.perf_counter() - start, height * width / 1e6, len(tiles))
        return out

    def _window(self, data: np.ndarray, t: Tile) -> tuple[np.ndarray, tuple[int, int]]:
        halo = self.halo
        origin = (t.y0 - halo, t.x0 - halo)
        window = gather_window(data, origin[0], origin[1], t.h + 2 * halo, t.w + 2 * halo, self.cfa.period)
        return window, origin

    def _run_tile_reference(self, data: np.ndarray, t: Tile) -> np.ndarray:
        x, origin = self._window(data, t)
        for stage in self.stages:
            x = stage.reference(x, origin)
            origin = (origin[0] + stage.halo, origin[1] + stage.halo)
        return x

    def schedule(self, fuse: bool = True) -> list[Stage]:
        """The stages as run on OpenCL: fused where they compose, the last one writing the host's
        interleaved layout when it can."""
        schedule = fuse_stages(self.stages) if fuse else list(self.stages)
        last = schedule[-1].with_interleaved_output()
        if last is not None:
            schedule[-1] = last
        return schedule

    def _run_tile_opencl(self, schedule: list[Stage], data: np.ndarray, t: Tile, out: np.ndarray) -> None:
        """Upload one window, run every stage on the device, download once into ``out``."""
        rt = get_runtime()
        window, origin = self._window(data, t)
        if window.dtype not in (np.uint16, np.float32):
            window = window.astype(np.float32)
        src = rt.upload(window)
        for stage in schedule:
            dst = stage.enqueue(rt, src, origin)
            rt.release(src)
            src, origin = dst, (origin[0] + stage.halo, origin[1] + stage.halo)
        if src.channels > 1 and not src.interleaved:
            planar, src = src, rt.interleave(src)
            rt.release(planar)
        region = out[t.y0:t.y0 + t.h, t.x0:t.x0 + t.w]
        if region.flags.c_contiguous:
            rt.download(src, into=region)
        else:
            region[...] = rt.download(src)
        rt.release(src)


def resolve_options(preset: str | None, demosaic: str | None, kind: str | None = None) -> dict[str, str]:
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
    options = {key: per_kind[kind] for key, per_kind in PRESETS[name].items()}
    if demosaic:
        options["demosaic"] = demosaic
    kinds = getattr(DEMOSAICS[options["demosaic"]], "cfa_kinds", (kind,))
    if kind not in kinds:
        raise ClispError(f"demosaic {options['demosaic']!r} works on {' and '.join(kinds)} CFAs, not {kind}")
    return options


def build_pipeline(raw: RawImage, preset: str | None = None, demosaic: str | None = None,
                   output: str = "linear") -> Pipeline:
    """Stages for ``raw``: normalise, WB pass 1, demosaic, colour matrix, WB pass 2, tone curve.

    ``output='linear'`` ends in linear sRGB (for EXR); ``'srgb'`` appends the sRGB tone curve
    (for 16-bit TIFF/PNG). WB pass 2 is left out when its gains are exactly 1 (identity).
    """
    if output not in OUTPUTS:
        raise ClispError(f"unknown output {output!r}; expected one of {', '.join(OUTPUTS)}")
    cfa = raw.cfa
    options = resolve_options(preset, demosaic, cfa.kind)
    stages: list[Stage] = [
        normalize(cfa, raw.black_level, raw.white_level),
        white_balance1(cfa, raw.pass1_gains()),
        DEMOSAICS[options["demosaic"]](cfa),
        ColourMatrix(raw.colour_matrix),
    ]
    if not np.allclose(raw.wb2, 1.0, rtol=0, atol=0):
        stages.append(WhiteBalance2(raw.wb2))
    if output == "srgb":
        stages.append(ToneCurve())
    return Pipeline(cfa, stages)


def orient(image: np.ndarray, flip: int) -> np.ndarray:
    """Apply LibRaw's ``sizes.flip`` code (0 none, 3 180 degrees, 5 90 CCW, 6 90 CW) to H x W x C."""
    if flip == 3:
        return image[::-1, ::-1]
    if flip == 5:
        return np.rot90(image, 1)
    if flip == 6:
        return np.rot90(image, -1)
    return image


def process_with_stats(raw: RawImage, preset: str | None = None, demosaic: str | None = None,
                       tile: int | None = None, output: str = "linear",
                       backend: str = "opencl") -> tuple[np.ndarray, RunStats]:
    """:func:`process` for a RawImage, also returning the run's timing."""
    pipeline = build_pipeline(raw, preset=preset, demosaic=demosaic, output=output)
    image = pipeline.run(raw.data, tile=tile, backend=backend)
    image = np.ascontiguousarray(orient(image, int(raw.metadata.get("flip", 0) or 0)))
    return image, pipeline.stats


def process(raw: RawImage | str | Path, preset: str | None = None, demosaic: str | None = None,
            tile: int | None = None, output: str = "linear", backend: str = "opencl") -> np.ndarray:
    """Process a raw image (or a raw file's path) into H x W x 3 float32 sRGB.

    ``output='linear'``: scene-linear sRGB (white 1.0, unclipped); ``'srgb'``: sRGB-encoded in
    [0, 1]. Orientation from camera metadata is applied last.
    """
    if not isinstance(raw, RawImage):
        from .rawfile import read_raw
        raw = read_raw(raw)
    return process_with_stats(raw, preset, demosaic, tile, output, backend)[0]
