"""Tile planning and CFA-preserving border padding.

The pipeline pads the raw input once, by the sum of all stage halos, and every stage shrinks its
window by its own halo. Because padding happens only at the image level and is a fixed index map,
a tile sees exactly the pixels the whole image would, so tiled output equals whole-image output.

The planner alone decides windows, from a few numbers the stages declare (darktable's tiling
contract, :class:`TileNeeds`): total halo, tile-origin alignment and bytes per pixel. Every tile of
a plan computes the same window size (the last row/column of tiles reaches past the image edge and
is cropped), so the device buffer pool holds one set of buffers however many tiles run.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from typing import Callable

import numpy as np

from ..errors import ClispError
from . import host_threads

TARGET_TILE_PIXELS = 2_000_000
"""On a device that shares host memory (a CPU device: PoCL), automatic tiles stop growing at about
this many window pixels even when the memory budget allows more: 2 MP bands ran at 1.08-1.46x the
whole image's throughput, 4-16 MP bands at 0.85-1.15x (PoCL, 25 MP LMS; README.md)."""

GPU_TARGET_TILE_PIXELS = 64_000_000
"""The same target on a discrete device (a GPU): large enough for a 24 MP raw and the quality
path's 107 px halo in one window, so the whole image is one launch per kernel and the raw one
upload; the device's memory (DEVICE_SHARE) and the host's budget bound it as they bound any tile.
A choice from the GPU's shape (a 24 MP stage is milliseconds of kernels there, a tile's Python
launches a fixed cost: docs/RESULTS.md, issue 41), to be re-measured with tools/bench_tiling.py
--sweep on the GPU (README.md)."""

MIN_BAND_ROWS = 32
"""Automatic tiles are full-width bands (one read per band, scanline output, no assembly). A
band this tall is allowed past TARGET_TILE_PIXELS (never past the budget), since shorter bands
spend a large share on their halo rows."""

MIN_TILE = 16
"""Smallest tile side in pixels the planner accepts."""

DEVICE_SHARE = 0.75
"""Fraction of the device's global memory a plan may use (the rest is left to the driver)."""


@dataclass(frozen=True)
class Tile:
    """Output region of one tile in image coordinates: rows y0..y0+h, columns x0..x0+w."""

    y0: int
    x0: int
    h: int
    w: int


@dataclass(frozen=True)
class TileNeeds:
    """What the planner knows about a pipeline, per pixel of a tile's input window.

    halo           input border one output pixel needs, px (sum of the stage halos)
    align          tile origins are multiples of this, px (CFA period and stage alignments)
    device_bytes   device memory per window pixel: input plus every stage's buffers, B/px
    host_bytes     host memory per window pixel for the tiles in flight (read, run, write), B/px
    largest_bytes  bytes per pixel of the largest single device buffer, B/px
    cost           optional exact count: bytes that tiles of (rows, columns) output pixels take
                   (device buffers, host buffers in flight; inf past a device limit). When set,
                   the planner uses it instead of the per-pixel figures (Pipeline.tile_cost).
    downscale      input pixels per output pixel along each axis (2: --half-size); tiles are
                   planned in output pixels, ``halo`` and the windows are in input pixels
    """

    halo: int
    align: int
    device_bytes: float
    host_bytes: float
    largest_bytes: float
    cost: Callable[[int, int], float] | None = None
    downscale: int = 1

    def window(self, rows: int, cols: int) -> tuple[int, int]:
        """Input window (rows, columns) of a tile of ``rows x cols`` output pixels."""
        return rows * self.downscale + 2 * self.halo, cols * self.downscale + 2 * self.halo


@dataclass(frozen=True)
class DeviceLimits:
    """CL_DEVICE_GLOBAL_MEM_SIZE and CL_DEVICE_MAX_MEM_ALLOC_SIZE in bytes (None: no device), and
    the window size automatic tiles aim for on that kind of device (TARGET_TILE_PIXELS on a device
    sharing host memory, GPU_TARGET_TILE_PIXELS on a discrete one)."""

    global_mem: int | None = None
    max_alloc: int | None = None
    target_pixels: int = TARGET_TILE_PIXELS


@dataclass(frozen=True)
class TilePlan:
    """Tiles in row-major order; each computes a ``tile_h x tile_w`` output (``halo`` more on
    every side as input), of which ``Tile.h x Tile.w`` lie inside the image and are kept.

    ``downscale``: input pixels per output pixel (2: --half-size). Tiles are in output pixels; a
    tile's window is in input pixels: ``downscale`` times the tile, plus ``halo`` on every side."""

    tiles: list[Tile]
    tile_h: int
    tile_w: int
    halo: int
    downscale: int = 1

    @property
    def window_shape(self) -> tuple[int, int]:
        """Input window of every tile, (rows, columns)."""
        return self.tile_h * self.downscale + 2 * self.halo, self.tile_w * self.downscale + 2 * self.halo

    def window_origin(self, tile: Tile) -> tuple[int, int]:
        """The input image coordinate (y, x) of ``tile``'s window's pixel (0, 0)."""
        return tile.y0 * self.downscale - self.halo, tile.x0 * self.downscale - self.halo


def plan_tiles(height: int, width: int, tile: int | None, align: int = 1) -> list[Tile]:
    """Cover an H x W image with tiles of at most ``tile`` x ``tile`` (None or 0: one tile).

    Tile sides are rounded down to a multiple of ``align`` (the CFA period) so tiles start on
    the same CFA phase; the last row/column of tiles takes the remainder.
    """
    return make_plan(height, width, TileNeeds(0, align, 1.0, 0.0, 1.0), tile or 0).tiles


def grid(height: int, width: int, step_h: int, step_w: int) -> list[Tile]:
    """Row-major tiles of ``step_h x step_w`` covering H x W; the last ones are cropped."""
    return [Tile(y, x, min(step_h, height - y), min(step_w, width - x))
            for y in range(0, height, step_h) for x in range(0, width, step_w)]


def make_plan(height: int, width: int, needs: TileNeeds, tile: int | None = None,
              budget: int = 2**30, limits: DeviceLimits = DeviceLimits()) -> TilePlan:
    """The tiles for an H x W image (output pixels: the input's divided by ``needs.downscale``).

    ``tile``: None chooses the tile shape from ``budget`` (bytes) and the device ``limits``
    (:func:`auto_tile_shape`); 0 processes the whole image as one tile; N gives N x N tiles
    (rounded down to ``needs.align``).
    """
    if tile is None and needs.cost is not None:
        step_h, step_w = costed_tile_shape(height, width, needs, budget, limits.target_pixels)
    elif tile is None:
        step_h, step_w = auto_tile_shape(height, width, needs, budget, limits)
    elif tile == 0 or tile >= max(height, width):
        step_h, step_w = height, width
    else:
        step_h = step_w = max(needs.align, tile // needs.align * needs.align)
    step_h, step_w = min(step_h, height), min(step_w, width)
    return TilePlan(grid(height, width, step_h, step_w), step_h, step_w, needs.halo, needs.downscale)


def auto_tile_shape(height: int, width: int, needs: TileNeeds, budget: int,
                    limits: DeviceLimits = DeviceLimits()) -> tuple[int, int]:
    """Tile (rows, columns) for an H x W image: the whole image if it fits the device kind's target
    (``limits.target_pixels``) and the memory limits, else full-width bands, else (images too wide for even MIN_TILE rows
    within ``budget``) squares. Sides are split evenly over the image (the last tile is no
    sliver) and aligned. Raises ClispError when not even a MIN_TILE square fits."""
    most = max_window_pixels(needs, budget, limits)
    halo, align, s = needs.halo, needs.align, needs.downscale
    target = min(most, max(limits.target_pixels, halo_target_pixels(width * s, halo)))
    if math.prod(needs.window(height, width)) <= target:
        return height, width
    row_pixels = width * s + 2 * halo
    rows = (max(target // row_pixels, min(MIN_BAND_ROWS * s + 2 * halo, most // row_pixels)) - 2 * halo) // s
    if rows >= MIN_TILE:
        return even_split(height, rows, align), width
    side = (math.isqrt(most) - 2 * halo) // s
    if side < MIN_TILE:
        per_px = needs.device_bytes + needs.host_bytes
        need = (MIN_TILE * s + 2 * halo) ** 2 * per_px
        raise ClispError(f"memory budget of {budget / 2**20:.0f} MiB is too small: one "
                         f"{MIN_TILE}x{MIN_TILE} tile needs {need / 2**20:.1f} MiB ({per_px:.0f} B/px)")
    return even_split(height, side, align), even_split(width, side, align)


def costed_tile_shape(height: int, width: int, needs: TileNeeds, budget: float,
                      target_pixels: int = TARGET_TILE_PIXELS) -> tuple[int, int]:
    """Tile (rows, columns) as :func:`auto_tile_shape` chooses them (aiming at ``target_pixels`` per
    window), with ``needs.cost`` deciding what fits ``budget``: the whole image if it fits the target size; else full-width bands of the
    target height (at least MIN_BAND_ROWS), or the tallest that fit; else the largest squares.
    Raises ClispError naming the smallest tile's bytes when not even a MIN_TILE square fits."""
    cost, halo, align, s = needs.cost, needs.halo, needs.align, needs.downscale
    assert cost is not None
    target = max(target_pixels, halo_target_pixels(width * s, halo))
    if math.prod(needs.window(height, width)) <= target and cost(height, width) <= budget:
        return height, width
    want = max((target // (width * s + 2 * halo) - 2 * halo) // s, MIN_BAND_ROWS)
    rows = largest_fitting(lambda r: cost(r, width) <= budget, min(want, height))
    if rows >= MIN_TILE:
        return even_split(height, rows, align), width
    side = largest_fitting(lambda s: cost(s, s) <= budget, min(height, width))
    if side < MIN_TILE:
        need = cost(MIN_TILE, MIN_TILE)
        raise ClispError(f"memory budget of {budget / 2**20:.0f} MiB for tiles is too small: one "
                         f"{MIN_TILE}x{MIN_TILE} tile needs {need / 2**20:.1f} MiB")
    return even_split(height, side, align), even_split(width, side, align)


def largest_fitting(fits: Callable[[int], bool], most: int) -> int:
    """The largest n in [1, most] with fits(n), for fits monotone (true up to some n); 0 if none."""
    if most < 1 or not fits(1):
        return 0
    lo, hi = 1, most
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if fits(mid):
            lo = mid
        else:
            hi = mid - 1
    return lo


HALO_ROWS_FACTOR = 8
"""Bands aim for at least this many output rows per halo row on each side, so recomputed halo rows
stay under (2 / 8 =) 25% of a band (a 107 px halo in 120-row bands ran at 66% of whole-image
speed; README.md)."""


def halo_target_pixels(width: int, halo: int) -> int:
    """Window pixels of a full-width band with HALO_ROWS_FACTOR x halo output rows (``width``:
    the input window's, less its halo)."""
    return (HALO_ROWS_FACTOR + 2) * halo * (width + 2 * halo)


def max_window_pixels(needs: TileNeeds, budget: int, limits: DeviceLimits) -> int:
    """Most input-window pixels one tile may have: within ``budget`` (host + device bytes),
    DEVICE_SHARE of global memory and the largest allocation."""
    caps = [budget / (needs.device_bytes + needs.host_bytes)]
    if limits.global_mem:
        caps.append(DEVICE_SHARE * limits.global_mem / needs.device_bytes)
    if limits.max_alloc:
        caps.append(limits.max_alloc / needs.largest_bytes)
    return int(min(caps))


def even_split(n: int, most: int, align: int) -> int:
    """Side of ceil(n / most) equal tiles covering n, rounded up to ``align`` (never above
    ``most`` rounded down to ``align``)."""
    most = max(align, most // align * align)
    side = -(-n // -(-n // most))                  # ceil(n / count) with count = ceil(n / most)
    return -(-side // align) * align


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


def window_indices(y0: int, x0: int, h: int, w: int, shape: tuple[int, int],
                   period: int) -> tuple[np.ndarray, np.ndarray]:
    """Source rows (h,) and columns (w,) of the window at (y0, x0) of an image of ``shape``,
    padded by :func:`cfa_mirror_index`; read-only arrays, memoised (a run asks for the same
    windows call after call, and the two mirror maps cost about 30 us of a 0.26 MP call)."""
    layout = _window_layout(int(y0), int(x0), int(h), int(w), (int(shape[0]), int(shape[1])), int(period))
    return layout.rows, layout.cols


Piece = tuple[slice, "slice | np.ndarray"]
"""A border part of a window: (the window's lines, where they come from): a slice (a run read as a
view, possibly reversed) or, where no few slices describe the mirror, an index array."""


@dataclass(frozen=True)
class WindowLayout:
    """Where a window's rows and columns come from (:func:`window_indices`), in the shapes
    :func:`gather` copies: the interior (the longest runs of consecutive rows and columns) and
    the mirrored border lines as a few slices each.

    rows, cols    the source index of every window row and column.
    row_run       (window start, source start, length) of the rows' longest run; col_run the same.
    col_pieces    the border columns, each (window columns, source columns).
    row_pieces    the border rows, each (window rows, source rows); the source rows are the
                  window's own (already copied, border columns included) where ``from_window``.
    """

    rows: np.ndarray
    cols: np.ndarray
    row_run: tuple[int, int, int]
    col_run: tuple[int, int, int]
    col_pieces: tuple[Piece, ...]
    row_pieces: tuple[Piece, ...]
    from_window: tuple[bool, ...]

    @classmethod
    def of(cls, rows: np.ndarray, cols: np.ndarray, period: int) -> "WindowLayout":
        row_run, col_run = _longest_run(rows), _longest_run(cols)
        (dy, sy, ny), (dx, _, nx) = row_run, col_run
        col_pieces = _border_pieces(cols, dx, nx, period)
        row_pieces, from_window = [], []
        for dst, src in _border_pieces(rows, dy, ny, period):
            src_rows = rows[dst]
            inside = src_rows.min() >= sy and src_rows.max() < sy + ny      # rows the window holds
            if inside:
                src = _shifted(src, dy - sy) if isinstance(src, slice) else src_rows - sy + dy
            row_pieces.append((dst, src))
            from_window.append(bool(inside))
        return cls(rows, cols, row_run, col_run, tuple(col_pieces), tuple(row_pieces), tuple(from_window))


def _border_pieces(idx: np.ndarray, start: int, length: int, period: int) -> list[Piece]:
    """The window lines of ``idx`` before ``start`` and from ``start + length`` on, as pieces: each
    side one slice where its sources step evenly (a plain mirror), else per phase of the CFA
    ``period`` its runs of even steps (the phase-keeping mirror of a 4 x 4 pattern steps by -period
    within a phase, but for a line or two at the image's edge), else, past MAX_PIECES slices, the
    side's index array.

    >>> [(d, s) for d, s in _border_pieces(np.array([2, 1, 0, 1, 2, 2, 1]), 2, 3, 1)]
    [(slice(0, 2, None), slice(2, 0, -1)), (slice(5, 7, None), slice(2, 0, -1))]
    """
    pieces: list[Piece] = []
    for a, b in ((0, start), (start + length, len(idx))):
        if b <= a:
            continue
        side = _as_slice(idx[a:b])
        if side is not None:
            pieces.append((slice(a, b), side))
            continue
        runs = [run for r in range(min(period, b - a)) for run in _even_runs(idx, a + r, b, period)]
        if len(runs) <= MAX_PIECES:
            pieces += runs
        else:
            pieces.append((slice(a, b), idx[a:b].copy()))
    return pieces


MAX_PIECES = 16
"""Slices per side of a window's border past which :func:`gather` indexes the side's lines instead."""


def _even_runs(idx: np.ndarray, a: int, b: int, step: int) -> list[Piece]:
    """The window lines a, a + step, ... (< b) as pieces of evenly stepping sources, each as long
    as it goes from where the last ended (greedy).

    >>> [(d, s) for d, s in _even_runs(np.array([5, 4, 3, 7, 6]), 0, 5, 1)]
    [(slice(0, 3, 1), slice(5, 2, -1)), (slice(3, 5, 1), slice(7, 5, -1))]
    """
    values = idx[a:b:step]
    pieces: list[Piece] = []
    i = 0
    while i < len(values):
        j = i + 1                                   # the run is values[i:j]
        if j < len(values) and values[j] != values[i]:
            d = values[j] - values[i]
            while j < len(values) and values[j] - values[j - 1] == d:
                j += 1
        src = _as_slice(values[i:j])
        pieces.append((slice(a + i * step, a + (j - 1) * step + 1, step), src))
        i = j
    return pieces


def _as_slice(values: np.ndarray) -> slice | None:
    """``values`` (source indices, >= 0) as a slice when they step evenly, else None.

    >>> _as_slice(np.array([3, 2, 1])), _as_slice(np.array([5, 7])), _as_slice(np.array([3, 2, 5]))
    (slice(3, 0, -1), slice(5, 9, 2), None)
    """
    first = int(values[0])
    if len(values) == 1:
        return slice(first, first + 1, 1)
    step = int(values[1] - values[0])
    if step == 0 or np.any(np.diff(values) != step):
        return None
    stop = first + step * len(values)
    return slice(first, stop if stop >= 0 else None, step)


def _shifted(sl: slice, by: int) -> slice:
    """The slice ``sl`` (of non-negative indices, as :func:`_as_slice` makes them) with every index
    moved by ``by``.

    >>> _shifted(slice(3, None, -1), 2), _shifted(slice(3, 0, -1), -1)
    (slice(5, 1, -1), slice(2, None, -1))
    """
    n = len(range(sl.start, -1 if sl.stop is None else sl.stop, sl.step))
    first = sl.start + by
    stop = first + sl.step * n
    return slice(first, stop if stop >= 0 else None, sl.step)


@lru_cache(maxsize=256)
def _window_layout(y0: int, x0: int, h: int, w: int, shape: tuple[int, int], period: int) -> WindowLayout:
    """The :class:`WindowLayout` of :func:`window_indices` (see :func:`gather`), its arrays read-only."""
    rows = cfa_mirror_index(np.arange(y0, y0 + h), shape[0], period)
    cols = cfa_mirror_index(np.arange(x0, x0 + w), shape[1], period)
    rows.setflags(write=False)
    cols.setflags(write=False)
    return WindowLayout.of(rows, cols, period)


def _longest_run(idx: np.ndarray) -> tuple[int, int, int]:
    """(dst_start, src_start, length) of the longest run of consecutive indices in ``idx``: a
    window's interior (its padded border lines are mirrored, so each is a run of its own)."""
    breaks = np.flatnonzero(np.diff(idx) != 1) + 1
    starts = np.concatenate(([0], breaks))
    ends = np.concatenate((breaks, [len(idx)]))
    i = int(np.argmax(ends - starts))
    return int(starts[i]), int(idx[starts[i]]), int(ends[i] - starts[i])


def gather(data: np.ndarray, rows: np.ndarray, cols: np.ndarray, out: np.ndarray | None = None,
           layout: WindowLayout | None = None, period: int = 1) -> np.ndarray:
    """``data[rows][:, cols]`` as a contiguous copy: the interior (the longest runs of consecutive
    rows and columns) as one block copy on the host's cores, the mirrored border columns and rows as
    a few slice copies (:class:`WindowLayout`; fancy indexing of the border lines cost 46 of a 0.26
    MP window's 130 us with a 67 px halo, the slices 14). A border row the window's interior already
    holds (a mirror of a row near the image's edge) is copied from the window, whole, its border
    columns included. ``out``: a len(rows) x len(cols) array of ``data``'s dtype to fill instead of a
    new one (a reused buffer spares the new pages' faults). ``layout``: the indices' layout where
    the caller has it (:func:`gather_window` keeps them per window), else made from ``rows``,
    ``cols`` and the CFA ``period`` (the mirror's phases).

    >>> data = np.arange(12).reshape(3, 4)
    >>> gather(data, np.array([1, 0, 1, 2, 1]), np.array([2, 1, 0, 1, 2, 3, 2])).tolist()[0]
    [6, 5, 4, 5, 6, 7, 6]
    """
    shape = (len(rows), len(cols))
    if out is None:
        window = np.empty(shape, dtype=data.dtype)
    elif out.shape != shape or out.dtype != data.dtype:
        raise ValueError(f"gather target {out.shape} {out.dtype} does not fit window {shape} {data.dtype}")
    else:
        window = out
    layout = layout or WindowLayout.of(rows, cols, period)
    (dy, sy, ny), (dx, sx, nx) = layout.row_run, layout.col_run
    host_threads.copy(window[dy:dy + ny, dx:dx + nx], data[sy:sy + ny, sx:sx + nx])   # on the host's cores
    interior = data[sy:sy + ny]
    for dst, src in layout.col_pieces:
        window[dy:dy + ny, dst] = interior[:, src]
    for (dst, src), inside in zip(layout.row_pieces, layout.from_window):
        window[dst] = window[src] if inside else data[src][:, layout.cols]
    return window


def gather_window(data: np.ndarray, y0: int, x0: int, h: int, w: int, period: int,
                  out: np.ndarray | None = None) -> np.ndarray:
    """The h x w window of ``data`` starting at (y0, x0), padded outside the image by
    :func:`cfa_mirror_index`. Returns a contiguous copy with the dtype of ``data`` (``out``
    filled, when given)."""
    layout = _window_layout(int(y0), int(x0), int(h), int(w), (int(data.shape[0]), int(data.shape[1])), int(period))
    return gather(data, layout.rows, layout.cols, out=out, layout=layout)
