"""Build the OpenCL programs of the presets ahead of the first real run (``clisp info --device --warm``).

A program is compiled the first time a process on this machine builds it for a device and clisp
version; clisp keeps the binary (clisp.engine.programs, in :func:`clisp.engine.disk_cache.cache_dir`),
so later processes only load it. A first run of a 24 MP raw
otherwise spends most of its time compiling. Warming runs, for each CFA kind and preset, the path
``clisp process`` takes on small raws simulated in code: a noisy chart with a light whose samples
clip (demosaic, highlights, colour and chroma denoiser with its noise calibration, tone curve to
16-bit and linear output; one tile, and several), a flat field (the skip planner's flat path) and
the chart again with mixed tiles forced (the flat and full paths joined inside a tile),
so that every program a default run of those presets builds is in the caches. Camera raws whose CFA phase or noise the
small raws do not have may still build a program or two of their own.
"""
from __future__ import annotations

import tempfile
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..engine.runtime import get_runtime
from ..io.rawfile import read_raw, write_raw
from ..pipeline import DEFAULT_PRESET, process_file
from ..sim.simulate import simulate

WARM_SIDE = 96
"""Side (px) of the small raws warming runs through each path."""
WARM_TILE = 48
"""Tile side (px) of a third run of each small raw, from a page-aligned copy in memory: the
device then gathers each tile's window from the mosaic in place (Runtime.gather_window, with its
mirrored edges), which it does for any raw whose pixels happen to sit at an aligned address."""
WARM_GAIN = 4.0
WARM_KINDS = ("lms", "bayer")
DEFAULT_WARM_PRESETS = (DEFAULT_PRESET, "fast")
"""What ``--warm`` builds: the default preset and the fastest (the others on request)."""


def warm_scenes(side: int = WARM_SIDE) -> list[np.ndarray]:
    """Linear sRGB scenes (side x side x 3): a colour ramp with a 2x overexposed light in one corner,
    and a flat mid-grey field."""
    y, x = np.mgrid[0:side, 0:side] / side
    chart = np.stack([0.1 + 0.8 * x, 0.1 + 0.8 * y, 0.5 - 0.4 * x * y], axis=-1)
    chart[: side // 4, : side // 4] = 2.0
    return [chart, np.full((side, side, 3), 0.18)]


MIXED_SIDE = 192
"""Side (px) of the raw whose tiles mix the flat and full paths: the flat path needs this much image
at the image's edges (DemosaicFlat.min_inside_px)."""


def mixed_scene(side: int = MIXED_SIDE) -> np.ndarray:
    """A flat mid-grey field with a band of fine coloured texture across its middle (side x side x 3)."""
    y, x = np.mgrid[0:side, 0:side]
    scene = np.full((side, side, 3), 0.18)
    band = slice(side // 2 - 16, side // 2 + 16)
    texture = 0.5 + 0.4 * np.stack([np.sin(x / 1.7 + y), np.sin(x / 2.3 - y / 1.3), np.cos((x + y) / 1.9)], -1)
    scene[band] = 0.3 * texture[band]
    return scene


def aligned(array: np.ndarray, align: int = 4096) -> np.ndarray:
    """A C-contiguous copy of ``array`` whose data start at a multiple of ``align`` bytes."""
    buffer = np.empty(array.nbytes + align, dtype=np.uint8)
    offset = -buffer.ctypes.data % align
    out = buffer[offset:offset + array.nbytes].view(array.dtype).reshape(array.shape)
    out[...] = array
    return out


@contextmanager
def mixing_forced() -> Iterator[None]:
    """Tiles mix their paths whenever they hold texture and flat blocks (clisp.pipeline.skip.MIX_GAIN lifted):
    on the small raws the detail path's halo would make mixing cost more than it saves, and the
    join's kernel would not be built."""
    from ..pipeline import skip                 # deferred: skip and analysis cost 7 ms of start-up
    saved = skip.MIX_GAIN
    skip.MIX_GAIN = float("inf")
    try:
        yield
    finally:
        skip.MIX_GAIN = saved


def warm_kernels(presets: Sequence[str] = DEFAULT_WARM_PRESETS, kinds: Sequence[str] = WARM_KINDS,
                 report: Callable[[str], None] | None = print) -> float:
    """Run every (kind, preset, scene, output) path once; returns the seconds it took. ``report``
    gets one line per preset and kind (None: silent)."""
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="clisp-warm-") as tmp:
        for kind in kinds:
            raws = []
            for i, scene in enumerate(warm_scenes() + [mixed_scene()]):   # read back from files, as the CLI does
                path = Path(tmp) / f"{kind}{i}.dng"
                write_raw(path, simulate(scene, kind, gain=WARM_GAIN, seed=0).raw)
                raws.append(read_raw(path, lazy=True))
            raws, mixed = raws[:-1], raws[-1]
            for preset in presets:
                t0 = time.perf_counter()
                for i, raw in enumerate(raws):
                    for suffix in (".tif", ".exr"):
                        process_file(raw, Path(tmp) / f"warm{i}{suffix}", preset=preset, skip=True)
                    process_file(replace(raw, data=aligned(raw.data)), Path(tmp) / f"warm{i}.tif", tile=WARM_TILE,
                                 preset=preset, skip=True)
                with mixing_forced():                         # the join of mixed tiles (issue 30)
                    for suffix in (".tif", ".exr"):
                        process_file(mixed, Path(tmp) / f"warm_mixed{suffix}", preset=preset, skip=True)
                if report is not None:
                    report(f"  {kind:5s} {preset:8s} {time.perf_counter() - t0:6.1f} s")
    t0 = time.perf_counter()
    kept = get_runtime().save_programs()
    if report is not None and kept:
        report(f"  binaries of {kept} programs kept ({time.perf_counter() - t0:.1f} s)")
    return time.perf_counter() - start
