"""The statistics pass on an OpenCL device: the kernels of ``statistics.cl`` fill the tables of
clisp.scene.statistics (:class:`~clisp.scene.statistics.SceneStatistics`) from the raw's one
upload, and only those small tables come back (the block table: 2 (nch + 1) + nch (nch + 1) / 2
numbers per 64 px block, 0.1 MB for 24 MP; the thumbnail: at most MAX_CELLS cells). The noise
strips, a few rows of the mosaic, are copied on the host from the raw in memory.

Launches, by name (Runtime.launch_named):

========================  =====================  ==========================================
kernel                    over                   halo
========================  =====================  ==========================================
``stats_blocks``          one work-item / block  one cell column right of the block
``stats_cells``           one work-item / cell   0
========================  =====================  ==========================================

Integer raws come out bit-identical to the NumPy reference (sums and Laplacian products in 64-bit
integers, the thumbnail in float32 with the reference's order of operations); float raws within
float32 rounding of it (tests/scene/test_statistics.py).
"""
from __future__ import annotations

import time
from typing import Any

import numpy as np

from ..engine.runtime import Runtime
from ..engine.stage import as_f32
from .statistics import (BLOCK, CELL, CLIP_FRACTION, MAX_CELLS, SceneStatistics, empty_table, noise_strips,
                         clip_levels, reference_statistics, table_fits, thumbnail_statistics, thumbnail_step)

DEVICE_DTYPES = (np.dtype(np.uint16), np.dtype(np.float32))
"""Raw sample types the kernels read (RAW_T); others take the reference."""


def device_statistics(raw: Any, rt: Runtime, max_cells: int = MAX_CELLS, cells: bool = True) -> SceneStatistics:
    """:class:`SceneStatistics` of ``raw`` computed by ``statistics.cl`` on ``rt``'s device (the
    NumPy reference for a raw whose samples the kernels do not read, whose CFA the block table
    does not serve (the thumbnail alone would not pay for a launch), or that streams from its file
    (read in bands there: flat memory, and a truncated file is an error, not a bus error)). The
    kernels always fill the thumbnail; ``cells`` is the reference's (:func:`reference_statistics`)."""
    from ..engine.streaming import FileWindows, window_source   # deferred: as the reference, only when measuring
    data = raw.data
    cfa = raw.cfa
    h, w = data.shape
    if data.dtype not in DEVICE_DTYPES or not table_fits(cfa, (h, w)) or isinstance(window_source(data), FileWindows):
        return reference_statistics(raw, max_cells, cells)   # a raw streamed from its file is read in bands, with pread
    start = time.perf_counter()
    p, nch = cfa.period, cfa.n_channels
    integer = data.dtype.kind == "u"
    defines = {"RAW_T": "ushort" if integer else "float", "ACC_T": "long" if integer else "float",
               "CFA_PERIOD": p, "NCH": nch, "BLOCK": BLOCK, "CELL": CELL}
    acc = np.dtype(np.int64 if integer else np.float32)
    table = empty_table(h, w, nch)
    rows, cols = table.uniform.shape
    step = thumbnail_step((h, w), p, max_cells)
    th, tw = -(-(h // p) // step), -(-(w // p) // step)
    black = np.broadcast_to(np.asarray(raw.black_level, dtype=np.float64), (nch,))
    counts = np.bincount(cfa.pattern.ravel(), minlength=nch).astype(np.float32)
    pattern = rt.constant(cfa.pattern)
    mosaic = rt.resident_mosaic(np.ascontiguousarray(data))
    out = {"sums": rt.acquire(nch, rows, cols, acc), "clipped": rt.acquire(nch, rows, cols, np.int32),
           "uniform": rt.acquire(1, rows, cols, np.int32), "lap": rt.acquire(nch * (nch + 1) // 2, rows, cols, acc),
           "cells": rt.acquire(nch, th, tw, np.float32), "cells_clipped": rt.acquire(1, th, tw, np.uint8)}
    try:
        rt.launch_named("statistics", "stats_blocks", cols, rows, dict(
            raw=mosaic, width=w, height=h, cols=cols, rows=rows, pattern=pattern,
            clip=rt.constant(as_f32(clip_levels(raw.black_level, raw.white_level, nch, data.dtype))),
            sums=out["sums"], clipped=out["clipped"], uniform=out["uniform"], lap=out["lap"]), defines, group=(8, 8))
        rt.launch_named("statistics", "stats_cells", tw, th, dict(
            raw=mosaic, width=w, stride=step, tw=tw, th=th, pattern=pattern, black=rt.constant(as_f32(black)),
            scale=rt.constant(as_f32(1.0 / (float(raw.white_level) - black))), counts=rt.constant(counts),
            clip_fraction=CLIP_FRACTION, cells=out["cells"], clipped=out["cells_clipped"]), defines)
        host = {name: rt.download(image) for name, image in out.items()}
    finally:
        for image in out.values():
            rt.release(image)
        rt.release(mosaic)
    table.sums[...] = host["sums"].reshape(nch, rows, cols)
    table.clipped[...] = host["clipped"].reshape(nch, rows, cols)
    table.uniform[...] = host["uniform"].reshape(rows, cols) != 0
    table.lap[...] = host["lap"].reshape(-1, rows, cols)
    strips = noise_strips(lambda y0, y1: data[y0:y1], (h, w), p)
    return SceneStatistics(shape=(h, w), period=p, block=BLOCK, table=table,
                           cells=host["cells"].reshape(th, tw, nch),     # written pixel-interleaved
                           cells_clipped=host["cells_clipped"].reshape(th, tw) != 0, step=step, strips=strips,
                           seconds=time.perf_counter() - start, device=rt.device.name.strip())


def statistics_runtime(rt: Any) -> Any:
    """The runtime whose device should measure the statistics: ``rt`` on a device that is not the
    host's CPU (a GPU, where the raw is uploaded anyway and the kernels take a few ms), None (the
    NumPy reference) on PoCL's CPU device, where the reference is faster: on the 24 MP D30 DNG,
    2-core Xeon, the table alone 60-90 ms against the kernels' 180-260 ms (clisp/scene/README.md)."""
    if rt is None or bool(rt.device.type & rt.cl.device_type.CPU):
        return None
    return rt


def scene_statistics(raw: Any, rt: Any = None, cells: bool = False, table: bool = True) -> SceneStatistics:
    """The statistics of ``raw`` (a RawImage): on ``rt``'s device when given (:func:`device_statistics`),
    else the NumPy reference (clisp.scene.statistics.reference_statistics). ``cells``: an estimate
    will read the cell thumbnail, so the reference fills it in the same read of the mosaic.
    ``table`` False: no estimate will read more than the thumbnail, so the reference reads that
    alone (clisp.scene.statistics.thumbnail_statistics); the device's pass fills everything anyway."""
    if rt is not None:
        return device_statistics(raw, rt, cells=cells)
    if not table:
        return thumbnail_statistics(raw)
    return reference_statistics(raw, cells=cells)
