"""Build the OpenCL programs of the presets ahead of the first real run (``clisp info --device --warm``).

A program is compiled the first time a process on this machine builds it for a device and clisp
version; clisp keeps the binary (clisp.engine.programs, in :func:`clisp.engine.disk_cache.cache_dir`),
so later processes only load it. A first run of a 24 MP raw
otherwise spends most of its time compiling. Warming runs, for each CFA kind and preset, the path
``clisp process`` takes on small raws simulated in code: a noisy chart with a light whose samples
clip (demosaic, highlights, colour and chroma denoiser with its noise calibration, tone curve to
16-bit and linear output; one tile, and several) and a flat field (the skip planner's flat path),
so that every program a default run of those presets builds is in the caches. Camera raws whose CFA phase or noise the
small raws do not have may still build a program or two of their own.
"""
from __future__ import annotations

import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from .engine.runtime import get_runtime
from .io.rawfile import read_raw, write_raw
from .pipeline import DEFAULT_PRESET, process_file
from .sim.simulate import simulate

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


def aligned(array: np.ndarray, align: int = 4096) -> np.ndarray:
    """A C-contiguous copy of ``array`` whose data start at a multiple of ``align`` bytes."""
    buffer = np.empty(array.nbytes + align, dtype=np.uint8)
    offset = -buffer.ctypes.data % align
    out = buffer[offset:offset + array.nbytes].view(array.dtype).reshape(array.shape)
    out[...] = array
    return out


def warm_kernels(presets: Sequence[str] = DEFAULT_WARM_PRESETS, kinds: Sequence[str] = WARM_KINDS,
                 report: Callable[[str], None] | None = print) -> float:
    """Run every (kind, preset, scene, output) path once; returns the seconds it took. ``report``
    gets one line per preset and kind (None: silent)."""
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="clisp-warm-") as tmp:
        for kind in kinds:
            raws = []
            for i, scene in enumerate(warm_scenes()):         # read back from files, as the CLI does
                path = Path(tmp) / f"{kind}{i}.dng"
                write_raw(path, simulate(scene, kind, gain=WARM_GAIN, seed=0).raw)
                raws.append(read_raw(path, lazy=True))
            for preset in presets:
                t0 = time.perf_counter()
                for i, raw in enumerate(raws):
                    for suffix in (".tif", ".exr"):
                        process_file(raw, Path(tmp) / f"warm{i}{suffix}", preset=preset, skip=True)
                    process_file(replace(raw, data=aligned(raw.data)), Path(tmp) / f"warm{i}.tif", tile=WARM_TILE,
                                 preset=preset, skip=True)
                if report is not None:
                    report(f"  {kind:5s} {preset:8s} {time.perf_counter() - t0:6.1f} s")
    t0 = time.perf_counter()
    kept = get_runtime().save_programs()
    if report is not None and kept:
        report(f"  binaries of {kept} programs kept ({time.perf_counter() - t0:.1f} s)")
    return time.perf_counter() - start
