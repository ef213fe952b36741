"""Tile planning and CFA-preserving border padding.

The pipeline pads the raw input once, by the sum of all stage halos, and every stage shrinks its
window by its own halo. Because padding happens only at the image level and is a fixed index map,
a tile sees exactly the pixels the whole image would, so tiled output equals whole-image output.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Tile:
    """Output region of one tile in image coordinates: rows y0..y0+h, columns x0..x0+w."""

    y0: int
    x0: int
    h: int
    w: int


def plan_tiles(height: int, width: int, tile: int | None, align: int = 1) -> list[Tile]:
    """Cover an H x W image with tiles of at most ``tile`` x ``tile`` (None or 0: one tile).

    Tile sides are rounded down to a multiple of ``align`` (the CFA period) so tiles start on
    the same CFA phase; the last row/column of tiles takes the remainder.
    """
    if not tile or tile >= max(height, width):
        return [Tile(0, 0, height, width)]
    step = max(align, tile // align * align)
    return [Tile(y, x, min(step, height - y), min(step, width - x))
            for y in range(0, height, step) for x in range(0, width, step)]


def cfa_mirror_index(idx: np.ndarray, n: int, period: int) -> np.ndarray:
    """Map indices (possibly outside [0, n)) into [0, n), mirrored and CFA-phase preserving.

    First whole-sample symmetric reflection (-1 -> 1, n -> n-2); then the nearest index congruent
    to the original modulo ``period``, so the padded pixel has the same CFA colour as the position
    it stands for (a plain mirror breaks the 4x4 LMS pattern). Needs n >= period.
    """
    idx = np.asarray(idx, dtype=np.int64)
    if n < period:
        raise ValueError(f"image side {n} is smaller than the CFA period {period}")
    if n == 1:
        return np.zeros_like(idx)
    cycle = 2 * n - 2
    m = np.abs(idx) % cycle
    m = np.where(m >= n, cycle - m, m)
    delta = (idx - m) % period
    up = m + delta
    down = up - period
    take_up = ((delta <= period // 2) & (up < n)) | (down < 0)
    out = np.where(take_up, up, down)
    inside = (idx >= 0) & (idx < n)
    return np.where(inside, idx, out)


def _runs(idx: np.ndarray) -> list[tuple[int, int, int]]:
    """Split an index array into (dst_start, src_start, length) runs of consecutive indices."""
    breaks = np.flatnonzero(np.diff(idx) != 1) + 1
    starts = np.concatenate(([0], breaks))
    ends = np.concatenate((breaks, [len(idx)]))
    return [(int(a), int(idx[a]), int(b - a)) for a, b in zip(starts, ends)]


def gather_window(data: np.ndarray, y0: int, x0: int, h: int, w: int, period: int) -> np.ndarray:
    """The h x w window of ``data`` starting at (y0, x0), padded outside the image by
    :func:`cfa_mirror_index`. Returns a contiguous copy with the dtype of ``data``.

    Copied as slices of consecutive rows/columns (the interior is one block, each padded
    border line its own short run), which is much faster than fancy indexing on large windows.
    """
    rows = _runs(cfa_mirror_index(np.arange(y0, y0 + h), data.shape[0], period))
    cols = _runs(cfa_mirror_index(np.arange(x0, x0 + w), data.shape[1], period))
    window = np.empty((h, w), dtype=data.dtype)
    for dy, sy, ny in rows:
        for dx, sx, nx in cols:
            window[dy:dy + ny, dx:dx + nx] = data[sy:sy + ny, sx:sx + nx]
    return window
