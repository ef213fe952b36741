"""The statistics pass: the mosaic read once, and the small tables every estimate of the scene reads.

:func:`scene_statistics` reads a raw's mosaic once and keeps, before any white balance (so that
white balance ``auto`` itself can read it):

* the **block table** (:class:`BlockTable`) on a grid of BLOCK x BLOCK pixel blocks aligned to the
  CFA (fixed image coordinates, so any tile plan maps onto it): per CFA channel the sum of its
  samples over the block's whole CELL x CELL cells and the count of its clipped samples; whether
  every CFA phase is constant in the block; and the products of the channels' cell-sum
  Laplacians (the luminance and chroma detail of any white balance and any colour space, as a
  quadratic form). The skip planner's analysis (clisp.scene.block_analysis) reads it.
* the **cell thumbnail**: one camera triplet per CFA cell (period x period pixels: the mean of each
  channel's samples, black-subtracted and divided by white - black) and whether the cell holds a
  clipped sample, on every ``step``-th cell row and column (at most about MAX_CELLS cells). White
  balance ``auto`` (pass 1: clisp.scene.illuminant; without a daylight white: grey pixels, clisp.
  scene.white_balance), pass 2's gray world and gray pixels (clisp.scene.white_balance_pass2) and
  ``--auto-exposure`` (clisp.scene.exposure) read it.
* the **noise strips**: the first 3 period rows of every block row, in DN, copied out; the noise
  estimate of a camera raw (clisp.scene.noise.strip_noise) and the analysis's noise check read
  Immerkaer's residuals on their CFA phases.

Two faces, as a stage has: :func:`reference_statistics` is the NumPy definition, and the kernels of
``statistics.cl`` (clisp.scene.statistics_device, one work-item per block or per thumbnail cell)
fill the same tables on an OpenCL device from the raw's one upload; tests/scene/test_statistics.py
compares them. Values in the tables are exact sums (integer raws: integer sums of DN) where the
estimates square or difference them, so the two faces agree to the last bit on integer raws.
"""
from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..cfa import CFA
from ..engine import host_threads
from ..errors import ClispError

BLOCK = 64
"""Side of the table's blocks (px): a multiple of every CFA period and of the denoiser's 2^J
alignment, so blocks start on CFA phase (0, 0) and never straddle a pyramid cell."""
CELL = 4
"""Side of the cells whose sums the detail measures use (px, a multiple of every CFA period the
table serves): the same pixel scale for every CFA (clisp.scene.block_analysis says why)."""
CLIP_FRACTION = 0.98
"""A sample at or above black + CLIP_FRACTION (white - black) is clipped."""
MAX_CELLS = 2 ** 19
"""At most about this many CFA cells enter the thumbnail; larger raws use every k-th cell row and
column (a 768 x 512 Bayer raw: all of its 98304 cells; the 24 MP Bayer raw: k = 4)."""
STRIP_PERIODS = 3
"""Fewest rows of a noise strip, in CFA periods: three lattice rows of every phase, the 3 x 3
residual's support (the analysis's noise check reads these rows of its strips)."""
STRIP_SAMPLES = 1_000_000
"""Samples the noise strips hold together at least, where the raw has them: small raws get taller
strips (up to whole block rows: a 768 x 512 raw is read whole), large ones the STRIP_PERIODS rows
of every block row (the 24 MP Bayer raw: 63 strips of 6 rows, 2.3 M samples)."""
BAND_BLOCKS = 4
"""Block rows the reference summarises together in one band (BAND_BLOCKS * BLOCK rows, about 2 MB
of a 12 MP uint16 raw): large enough that NumPy's per-call overhead is small next to the work,
small enough to stay in cache and to keep a memory-mapped raw's reading in bands."""
PEAK = 16
"""Side (px) of the blocks whose largest sample the pass keeps (``SceneStatistics.peaks``): the
highlight stage's clip map looks for clipped samples in such blocks (clisp.modules.highlights:
TEST); a divisor of BLOCK, so a band holds whole ones."""

THREADS = 2
"""Threads of the reference's bands (NumPy releases the GIL in its loops)."""


@dataclass
class BlockTable:
    """Per-block sums of a mosaic on the BLOCK grid (``rows`` x ``cols`` blocks; the last row and
    column may be partial). Values are in the raw's DN, before black subtraction and white balance.

    ``sums``      (nch, rows, cols) float64: the sum of each channel's samples over the block's
                  whole CELL x CELL cells (cells past the last whole one are left out);
    ``cells``     (rows, cols) int: whole cells in the block;
    ``clipped``   (nch, rows, cols) int64: each channel's samples at or above its clip level (every
                  sample of the block, whole cells or not);
    ``uniform``   (rows, cols) bool: every CFA phase exactly constant in the block;
    ``lap``       (nch (nch + 1) / 2, rows, cols) float64: sum over the block's Laplacian positions
                  of L_i L_j (i <= j, in np.triu_indices order), L_c the 4-neighbour Laplacian of
                  channel c's cell sums (DN): the Laplacians run within each block row of cells
                  (they read no cell of the block rows above or below), the one centred on cell
                  column j counts in the block of column j - 1, and the energy of any weighted
                  plane sum_c w_c L_c is w^T lap w;
    ``positions`` (rows, cols) int: the Laplacian positions of each block.
    """

    sums: np.ndarray
    cells: np.ndarray
    clipped: np.ndarray
    uniform: np.ndarray
    lap: np.ndarray
    positions: np.ndarray

    def energy(self, weights: np.ndarray) -> np.ndarray:
        """Mean squared Laplacian per block of the plane ``sum_c weights[..., c] L_c`` (weights on
        the channels' DN cell sums, shape (..., nch)); shape (..., rows, cols), 0 where a block has
        no Laplacian position.

        >>> t = BlockTable(np.zeros((2, 1, 1)), np.ones((1, 1)), np.zeros((2, 1, 1)), np.ones((1, 1), bool),
        ...                np.array([4.0, 2.0, 9.0]).reshape(3, 1, 1), np.full((1, 1), 2))
        >>> t.energy(np.array([1.0, -1.0])).ravel().tolist()       # (4 - 2 * 2 + 9) / 2
        [4.5]
        """
        w = np.asarray(weights, dtype=np.float64)
        nch = w.shape[-1]
        iu, ju = np.triu_indices(nch)
        coef = w[..., iu] * w[..., ju] * np.where(iu == ju, 1.0, 2.0)        # (..., m)
        total = np.tensordot(coef, self.lap, axes=([-1], [0]))
        return total / np.maximum(self.positions, 1)


@dataclass
class SceneStatistics:
    """What one read of the mosaic keeps (module docstring).

    ``table``          the :class:`BlockTable`, None when the CFA's period does not divide CELL.
    ``cells``          (ty, tx, nch) float32: the cell thumbnail, each channel's mean normalised
                       sample ((DN - black) / (white - black)) in each CFA cell read.
    ``cells_clipped``  (ty, tx) bool: the cell holds a sample at or above CLIP_FRACTION.
    ``step``           every ``step``-th cell row and column was read into the thumbnail.
    ``strips``         {block row: (k p, W) DN}: the noise strips, the first k period rows of each
                       block row that has STRIP_PERIODS of them (k: :func:`strip_height`).
    ``seconds``        wall time of the pass; ``device`` where it ran ('' for the reference).
    """

    shape: tuple[int, int]
    period: int
    block: int
    table: BlockTable | None
    cells: np.ndarray | None
    cells_clipped: np.ndarray | None
    step: int
    strips: dict[int, np.ndarray]
    seconds: float = 0.0
    device: str = ""
    peaks: np.ndarray | None = None
    """(ceil(H / PEAK), ceil(W / PEAK)) the largest sample (DN, the raw's dtype) of each PEAK px
    block from (0, 0), the last row and column cut by the edge; None where the pass made no table."""
    raw: Any = field(default=None, repr=False)
    """The raw whose thumbnail the reference reads on first need (None once it is read)."""
    complete: bool = True
    """False for :func:`thumbnail_statistics`: only the cell thumbnail was read (no table, strips or
    peaks), for a run whose only estimate reads it; clisp.scene.measure.Scene.measured reads the rest
    if a later estimate asks for it."""

    def thumbnail(self) -> tuple[np.ndarray, np.ndarray]:
        """(cells, cells_clipped). The device path fills them in its pass; the reference reads
        them when an estimate first asks (a run with the camera's white balance and its noise
        model, whose only reader is the skip analysis, then never reads them: 20 ms of a 24 MP raw)."""
        if self.cells is None:
            start = time.perf_counter()
            raw = self.raw
            self.cells, self.cells_clipped = cell_thumbnail(raw.data, raw.cfa, raw.black_level, raw.white_level,
                                                            self.step)
            self.seconds += time.perf_counter() - start
            self.raw = None
        return self.cells, self.cells_clipped

    def summary(self) -> str:
        """One line for ``clisp process --explain``."""
        h, w = self.shape
        where = f"on {self.device}" if self.device else "NumPy"
        rows = f"{self.table.uniform.shape[0]}x{self.table.uniform.shape[1]} blocks of {self.block} px, " \
            if self.table is not None else ""
        thumb = f"{self.cells.shape[0]}x{self.cells.shape[1]} cells (every {self.step}), " if self.cells is not None \
            else "no thumbnail read, "
        strips = f"{len(self.strips)} noise strips" if self.complete else "the thumbnail only"
        return f"scene statistics: {w}x{h}, {rows}{thumb}{strips}, {self.seconds * 1e3:.0f} ms {where}"


# --------------------------------------------------------------------------------------------
# the thresholds and the grid
# --------------------------------------------------------------------------------------------

def clip_levels(black_level: np.ndarray, white_level: float, n_channels: int, dtype: np.dtype) -> np.ndarray:
    """(nch,) clip level per channel in the raw's own values, such that ``sample >= level`` is
    exactly ``sample >= black + CLIP_FRACTION (white - black)`` in float64: rounded up to the next
    value the dtype holds (integer raws: the next integer; float32 raws: the next float32), in
    float64. Other dtypes keep the float64 level."""
    black = np.broadcast_to(np.asarray(black_level, dtype=np.float64), (n_channels,))
    level = black + CLIP_FRACTION * (float(white_level) - black)
    dtype = np.dtype(dtype)
    if np.issubdtype(dtype, np.integer):
        info = np.iinfo(dtype)
        whole = np.ceil(level)
        if whole.max() <= info.max:
            return np.maximum(whole, info.min)
    elif dtype == np.float32:
        single = level.astype(np.float32)
        return np.where(single < level, np.nextafter(single, np.float32(np.inf)), single).astype(np.float64)
    return level


def table_fits(cfa: CFA, shape: tuple[int, int]) -> bool:
    """Whether the block table serves ``cfa`` (its period divides CELL) on a raw of ``shape``."""
    p = cfa.period
    return CELL % p == 0 and BLOCK % CELL == 0 and shape[0] >= p and shape[1] >= 3 * p


def thumbnail_step(shape: tuple[int, int], period: int, max_cells: int = MAX_CELLS) -> int:
    """Every this-many cell rows and columns enter the thumbnail (1 up to ``max_cells`` cells)."""
    cells = (shape[0] // period) * (shape[1] // period)
    return max(1, int(np.ceil(np.sqrt(cells / max_cells))))


def strip_height(shape: tuple[int, int], period: int, block: int = BLOCK) -> int:
    """Rows of each noise strip: STRIP_PERIODS periods, or more (whole periods, at most ``block``)
    until the strips hold STRIP_SAMPLES samples.

    >>> strip_height((4000, 6000), 2), strip_height((512, 768), 2), strip_height((3000, 4000), 4)
    (6, 64, 12)
    """
    rows = max(1, len(strip_rows(shape, period, block)))
    need = -(-STRIP_SAMPLES // (rows * max(shape[1], 1)))
    periods = max(STRIP_PERIODS, -(-need // period))
    return min(periods * period, block // period * period)


def noise_strips(read: Any, shape: tuple[int, int], period: int) -> dict[int, np.ndarray]:
    """{block row: its noise strip, a copy}: rows r BLOCK .. r BLOCK + strip_height (whole periods,
    within the image) of every block row of :func:`strip_rows`, each read by ``read(y0, y1)``."""
    h, tall = shape[0], strip_height(shape, period)
    return {r: np.array(read(r * BLOCK, r * BLOCK + (min(h - r * BLOCK, tall) // period) * period))
            for r in strip_rows(shape, period)}


def strip_rows(shape: tuple[int, int], period: int, block: int = BLOCK) -> list[int]:
    """Block rows that have a noise strip: their first STRIP_PERIODS periods of rows and at least
    one whole CELL row inside the image."""
    h = shape[0]
    return [r for r in range(-(-h // block)) if min(block, h - r * block) >= max(STRIP_PERIODS * period, CELL)]


# --------------------------------------------------------------------------------------------
# the reference
# --------------------------------------------------------------------------------------------

def reference_statistics(raw: Any, max_cells: int = MAX_CELLS, cells: bool = False) -> SceneStatistics:
    """The NumPy definition of :class:`SceneStatistics` for ``raw`` (RawImage: data H x W DN, cfa,
    black_level, white_level): the mosaic read once, in bands of BAND_BLOCKS block rows. ``cells``:
    the cell thumbnail too, from the same bands (an estimate will read it; without, it is read on
    first need: :meth:`SceneStatistics.thumbnail`)."""
    start = time.perf_counter()
    cfa: CFA = raw.cfa
    data = raw.data
    h, w = data.shape
    p, nch = cfa.period, cfa.n_channels
    if h < p or w < p:
        raise ClispError(f"raw of {w}x{h} is smaller than one {p}x{p} CFA cell")
    from ..engine.streaming import FileWindows, window_source     # deferred: the engine is not needed to import this
    clip = clip_levels(raw.black_level, raw.white_level, nch, data.dtype)
    step = thumbnail_step((h, w), p, max_cells)
    source = window_source(data)       # a raw file mapped in memory is read with pread: a file truncated
    try:                               # meanwhile raises ClispError instead of a bus error
        def read(y0: int, y1: int) -> np.ndarray:
            """Rows y0 .. y1 - 1: pread from a mapped file, a view of an array in memory."""
            return source.read_rows(y0, y1) if isinstance(source, FileWindows) else np.asarray(data[y0:y1])

        strips = noise_strips(read, (h, w), p)
        table = thumb = peaks = None
        if table_fits(cfa, (h, w)):
            table = empty_table(h, w, nch)
            peaks = np.zeros((-(-h // PEAK), -(-w // PEAK)), dtype=data.dtype)
            tile = clip_tile(clip, cfa, w, data.dtype)
            thumb = _Thumbnail(cfa, raw.black_level, raw.white_level, step, (h, w)) if cells else None
            with ThreadPoolExecutor(THREADS, thread_name_prefix="clisp-statistics") as pool:
                pending: list[Any] = []
                for r0, r1 in _bands(h):               # at most 2 THREADS bands read ahead (flat memory)
                    if len(pending) >= 2 * THREADS:
                        pending.pop(0).result()
                    pending.append(pool.submit(_scan_band, read(r0 * BLOCK, min(h, r1 * BLOCK)), r0, r1, cfa, tile,
                                               table, thumb, peaks))
                for done in pending:
                    done.result()
    finally:
        source.close()
    stats = SceneStatistics(shape=(h, w), period=p, block=BLOCK, table=table, cells=None, cells_clipped=None,
                            step=step, strips=strips, peaks=peaks, raw=raw)
    if thumb is not None:
        stats.cells, stats.cells_clipped, stats.raw = thumb.cells, thumb.clipped, None
    stats.seconds = time.perf_counter() - start
    if cells:
        stats.thumbnail()                              # a CFA whose period does not divide CELL: read now
    return stats


def thumbnail_statistics(raw: Any, max_cells: int = MAX_CELLS) -> SceneStatistics:
    """:class:`SceneStatistics` of ``raw`` holding the cell thumbnail alone (``complete`` False),
    the same cells :func:`reference_statistics` reads: for a run whose only estimate is the white
    balance of a file without one (the fast preset on the D30's DNG: 15 ms against the whole pass's
    91 ms, 24 MP, 2-core Xeon; clisp/scene/README.md)."""
    start = time.perf_counter()
    h, w = raw.data.shape
    p = raw.cfa.period
    if h < p or w < p:
        raise ClispError(f"raw of {w}x{h} is smaller than one {p}x{p} CFA cell")
    step = thumbnail_step((h, w), p, max_cells)
    cells, clipped = cell_thumbnail(raw.data, raw.cfa, raw.black_level, raw.white_level, step)
    return SceneStatistics(shape=(h, w), period=p, block=BLOCK, table=None, cells=cells, cells_clipped=clipped,
                           step=step, strips={}, seconds=time.perf_counter() - start, complete=False)


def empty_table(h: int, w: int, nch: int) -> BlockTable:
    """A zeroed :class:`BlockTable` for an H x W raw of ``nch`` channels, with its grid's counts
    (whole cells and Laplacian positions per block) filled in: what both faces of the pass fill."""
    rows, cols = -(-h // BLOCK), -(-w // BLOCK)
    hc, wc, cb = h // CELL, w // CELL, BLOCK // CELL
    # whole cells per block, and Laplacian positions: cell rows 1 .. hc_b - 2 of each block row, centre
    # columns 1 .. wc - 2 counted in the block of column j - 1
    cell_rows = np.array([max(0, min(cb, hc - r * cb)) for r in range(rows)])
    cell_cols = np.array([max(0, min(cb, wc - c * cb)) for c in range(cols)])
    lap_cols = np.array([max(0, min(cb, wc - 2 - c * cb)) for c in range(cols)])
    positions = np.outer(np.where(cell_rows >= 3, cell_rows - 2, 0), lap_cols)
    if wc < 3:
        positions[:] = 0
    m = nch * (nch + 1) // 2
    return BlockTable(sums=np.zeros((nch, rows, cols)), cells=np.outer(cell_rows, cell_cols),
                      clipped=np.zeros((nch, rows, cols), dtype=np.int64), uniform=np.ones((rows, cols), dtype=bool),
                      lap=np.zeros((m, rows, cols)), positions=positions)


def _bands(h: int) -> list[tuple[int, int]]:
    """(first, end) block rows of each band: BAND_BLOCKS whole block rows at a time, and a last
    partial block row (image height not a multiple of the block) on its own."""
    whole, rows = h // BLOCK, -(-h // BLOCK)
    bands = [(r, min(r + BAND_BLOCKS, whole)) for r in range(0, whole, BAND_BLOCKS)]
    if whole < rows:
        bands.append((whole, rows))
    return bands


def _scan_band(rows: np.ndarray, r0: int, r1: int, cfa: CFA, tile: np.ndarray, table: BlockTable,
               thumb: "_Thumbnail | None" = None, peaks: np.ndarray | None = None) -> None:
    """Write the sums of block rows r0 .. r1 - 1 (``rows``: their samples, DN) into ``table``, the
    band's cell rows into ``thumb`` and its PEAK px blocks' maxima into ``peaks`` when given (only
    those rows: bands may run in parallel)."""
    if thumb is not None:
        thumb.fill(rows, r0 * BLOCK)
    if peaks is not None:
        first = r0 * BLOCK // PEAK
        band_peaks = block_maxima(rows, PEAK)
        peaks[first:first + band_peaks.shape[0]] = band_peaks
    w = rows.shape[1]
    band = rows.reshape(r1 - r0, -1, w)          # (kb, bh, W): bh = BLOCK, but in a last partial block row
    rs = slice(r0, r1)
    edges = np.arange(0, w, BLOCK)
    table.clipped[:, rs] = _clipped_counts(band, cfa, tile, edges)
    table.uniform[rs] = _uniform(band, cfa.period, edges, w)
    hc, wc = band.shape[1] // CELL, w // CELL
    if hc > 0 and wc > 0:
        sums = _cell_sums(band, cfa, hc, wc)
        cell_edges = np.arange(0, wc, BLOCK // CELL)
        block_sum = np.add.reduceat(sums.sum(axis=2, dtype=np.float64), cell_edges, axis=-1)  # (nch, kb, cols')
        table.sums[:, rs, :block_sum.shape[-1]] = block_sum
        if hc >= 3 and wc >= 3:
            _laplacian_products(sums, rs, table)


def block_maxima(data: np.ndarray, b: int) -> np.ndarray:
    """The largest sample of each b x b block of ``data`` (blocks on its grid from (0, 0); the last
    row and column of blocks may be cut by its edge): ceil(H / b) x ceil(W / b), ``data``'s dtype.
    By b strided maxima along the rows, then b along the columns (NumPy's reductions over short
    axes are several times slower), in row bands on the host's threads (clisp.engine.host_threads).

    >>> block_maxima(np.arange(30).reshape(5, 6), 4).tolist()
    [[21, 23], [27, 29]]
    """
    h, w = data.shape
    out = np.zeros((-(-h // b), -(-w // b)), dtype=data.dtype)

    def band(r0: int, r1: int) -> None:           # rows r0:r1 (a multiple of b from r0)
        out[r0 // b:-(-r1 // b)] = _block_maxima_rows(data[r0:r1], b)
    host_threads.run_bands(band, h, data.nbytes, multiple=b)
    return out


def _block_maxima_rows(data: np.ndarray, b: int) -> np.ndarray:
    """:func:`block_maxima` of one band of rows, on this thread."""
    h, w = data.shape
    wf = w // b * b
    cols = np.zeros((h, -(-w // b)), dtype=data.dtype)
    if wf:
        cols[:, :w // b] = data[:, 0:wf:b]
        for k in range(1, b):
            np.maximum(cols[:, :w // b], data[:, k:wf:b], out=cols[:, :w // b])
    if wf < w:
        cols[:, -1] = data[:, wf:].max(axis=1)
    rows = np.zeros((-(-h // b) * b, cols.shape[1]), dtype=data.dtype)
    rows[:h] = cols
    rows = rows.reshape(-1, b, cols.shape[1])
    out = rows[:, 0].copy()
    for k in range(1, b):
        np.maximum(out, rows[:, k], out=out)
    return out


def clip_tile(clip: np.ndarray, cfa: CFA, w: int, dtype: np.dtype) -> np.ndarray:
    """(BLOCK, w) clip level of every sample of a block row (its rows start on CFA phase 0), in
    the raw's dtype where :func:`clip_levels` made the comparison exact in it."""
    dtype = np.dtype(dtype)
    levels = clip.astype(dtype) if dtype.kind in "ui" or dtype == np.float32 else clip
    p = cfa.period
    return np.tile(levels[cfa.pattern], (BLOCK // p, -(-w // p)))[:, :w].copy()


def _clipped_counts(band: np.ndarray, cfa: CFA, tile: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """(nch, kb, cols) each channel's samples at or above its clip level per block of ``band``
    (``tile``: :func:`clip_tile`); a band whose largest sample is below every level (most of a
    photo) is not compared. The hits are counted per CFA phase row and column in one reduction."""
    nch, p = cfa.n_channels, cfa.period
    kb, bh, w = band.shape
    out = np.zeros((nch, kb, len(edges)), dtype=np.int64)
    if band.max() < tile.min():
        return out
    hit = band >= tile[:bh]
    if not hit.any():
        return out
    for py in range(min(p, bh)):
        per_column = hit[:, py::p].sum(axis=1, dtype=np.uint16 if bh <= 0xFFFF else np.int64)   # (kb, W)
        for px in range(min(p, w)):
            out[int(cfa.pattern[py, px])] += np.add.reduceat(per_column[:, px::p].astype(np.int64),
                                                             -(-(edges - px) // p), axis=-1)
    return out


def _uniform(band: np.ndarray, p: int, edges: np.ndarray, w: int) -> np.ndarray:
    """(kb, cols) bool: every CFA phase exactly constant in the block. Most blocks of a photo
    differ within their first 2 p rows, so those are compared first and the whole band only when
    some block is still a candidate."""
    cross = np.zeros(max(w - p, 0), dtype=bool)
    for e in range(BLOCK, w, BLOCK):
        cross[e - p:e] = True
    top = _differs(band[:, :2 * p], p, edges, cross)
    if top.all():
        return ~top
    return ~_differs(band, p, edges, cross)


def _differs(band: np.ndarray, p: int, edges: np.ndarray, cross: np.ndarray) -> np.ndarray:
    """(kb, cols) bool: some sample of the block differs from the one a CFA period to its right or
    below it in the same block (False <=> every phase is constant in the block)."""
    right = (band[:, :, p:] != band[:, :, :-p]).any(axis=1)          # (kb, W - p)
    right[:, cross] = False                                          # a block's last p columns vs the next block
    below = (band[:, p:] != band[:, :-p]).any(axis=1)                # (kb, W)
    below[:, :right.shape[1]] |= right
    return np.logical_or.reduceat(below, edges, axis=-1)


def _cell_sums(band: np.ndarray, cfa: CFA, hc: int, wc: int) -> np.ndarray:
    """(nch, kb, hc, wc) sum of each channel's samples in every CELL x CELL cell, DN: int32 for
    integer raws of at most 16 bits (exact), float32 for others (as the analysis always summed them)."""
    kb = band.shape[0]
    v = band[:, :hc * CELL, :wc * CELL].reshape(kb, hc, CELL, wc, CELL)
    dtype = np.int32 if band.dtype.kind in "ui" and band.dtype.itemsize <= 2 else np.float32
    sums = np.zeros((cfa.n_channels, kb, hc, wc), dtype=dtype)
    for py in range(CELL):
        for px in range(CELL):
            sums[int(cfa.pattern[py % cfa.period, px % cfa.period])] += v[:, :, py, :, px]
    return sums


def _laplacian_products(sums: np.ndarray, rs: slice, table: BlockTable) -> None:
    """Sum per block of L_i L_j over the band's Laplacian positions (BlockTable.lap), from the cell
    sums (nch, kb, hc, wc). Exact for integer raws of at most 16 bits: the Laplacians are int32 (at
    most 8 x 16 x 65535 < 2^23), their products and the products' sums over a block's positions (at
    most 224) integers below 2^53, which float64 holds exactly in any order."""
    nch, _, _, wc = sums.shape
    # (nch, kb, hc - 2, wc - 2)
    lap = _laplacian(sums).astype(np.float64) if sums.dtype.kind == "i" else _laplacian(sums.astype(np.float64))
    edges = np.arange(0, wc - 2, BLOCK // CELL)
    k = min(len(edges), table.lap.shape[-1])
    for i, (a, b) in enumerate(zip(*np.triu_indices(nch))):
        product = np.einsum("kij,kij->kj", lap[a], lap[b])          # (kb, wc - 2), summed over the rows
        table.lap[i, rs, :k] = np.add.reduceat(product, edges, axis=-1)[..., :k]


def _laplacian(a: np.ndarray) -> np.ndarray:
    """4-neighbour Laplacian on the interior of the last two axes (in a's dtype)."""
    lap = a[..., :-2, 1:-1] + a[..., 2:, 1:-1]
    lap += a[..., 1:-1, :-2]
    lap += a[..., 1:-1, 2:]
    lap -= 4 * a[..., 1:-1, 1:-1]
    return lap


def thumbnail(data: np.ndarray, cfa: CFA, black_level: np.ndarray, white_level: float,
              max_cells: int = MAX_CELLS) -> tuple[np.ndarray, np.ndarray]:
    """(cells, clipped): the cell thumbnail of SceneStatistics read alone, for an estimate made
    without the run's statistics (tools, a RawImage read and estimated by hand); every k-th cell
    row and column where the raw has more than ``max_cells`` cells."""
    return cell_thumbnail(data, cfa, black_level, white_level, thumbnail_step(data.shape, cfa.period, max_cells))


def cell_thumbnail(data: np.ndarray, cfa: CFA, black_level: np.ndarray, white_level: float,
               step: int) -> tuple[np.ndarray, np.ndarray]:
    """(cells, clipped) of SceneStatistics: every ``step``-th whole CFA cell row and column, each
    channel's mean normalised sample (float32 arithmetic) and whether a sample is at or above
    CLIP_FRACTION. Rows are read through clisp.engine.streaming.window_source (pread for a raw file
    mapped in memory)."""
    from ..engine.streaming import FileWindows, window_source     # deferred: the engine is not needed to import this
    p = cfa.period
    h, w = data.shape[0] // p * p, data.shape[1] // p * p
    source = window_source(data)
    try:
        if not isinstance(source, FileWindows):       # in memory: the rows as one strided view
            rows = np.asarray(data[:h, :w]).reshape(h // p, p, w)[::step].reshape(-1, w)
        else:                                          # whole rows inside the image: no mirroring to do
            starts = range(0, h, step * p)
            rows = np.concatenate([source.read_rows(y, y + p)[:, :w] for y in starts])
    finally:
        source.close()
    return thumbnail_cells(rows, cfa, black_level, white_level, step, w)


def thumbnail_cells(rows: np.ndarray, cfa: CFA, black_level: np.ndarray, white_level: float, step: int,
                    w: int) -> tuple[np.ndarray, np.ndarray]:
    """(cells, clipped) of the thumbnail cell rows whose samples are ``rows`` (their p rows each, in
    order; columns from 0, the first ``w`` used): every ``step``-th whole cell of each, each channel's
    mean normalised sample (float32 arithmetic) and whether a sample is at or above CLIP_FRACTION."""
    p = cfa.period
    black = np.broadcast_to(np.asarray(black_level, dtype=np.float64), (cfa.n_channels,))
    scale = 1.0 / (float(white_level) - black)
    channel = cfa.channel_map(p, p)
    ny, nx = rows.shape[0] // p, (w // p + step - 1) // step
    cells = np.zeros((ny, nx, cfa.n_channels), dtype=np.float32)
    clipped = np.zeros((ny, nx), dtype=bool)
    counts = np.bincount(channel.ravel(), minlength=cfa.n_channels)
    for dy in range(p):
        for dx in range(p):
            c = int(channel[dy, dx])
            plane = rows[dy::p, dx:w:p * step].astype(np.float32)
            plane = (plane - np.float32(black[c])) * np.float32(scale[c])
            clipped |= plane >= CLIP_FRACTION
            cells[..., c] += plane
    cells /= counts.astype(np.float32)
    return cells, clipped


class _Thumbnail:
    """The cell thumbnail filled band by band by the reference's pass (:func:`_scan_band`)."""

    def __init__(self, cfa: CFA, black_level: np.ndarray, white_level: float, step: int,
                 shape: tuple[int, int]) -> None:
        p = cfa.period
        self.cfa, self.black, self.white, self.step = cfa, black_level, white_level, step
        self.h, self.w = shape[0] // p * p, shape[1] // p * p
        ny, nx = -(-(self.h // p) // step), -(-(self.w // p) // step)
        self.cells = np.zeros((ny, nx, cfa.n_channels), dtype=np.float32)
        self.clipped = np.zeros((ny, nx), dtype=bool)

    def fill(self, rows: np.ndarray, y0: int) -> None:
        """The thumbnail's cell rows among the mosaic rows y0 .. y0 + len(rows) - 1 (``rows``)."""
        p, every = self.cfa.period, self.step * self.cfa.period
        first = -(-y0 // every)                                   # the first cell row at or after y0
        last = min(y0 + rows.shape[0], self.h)
        starts = np.arange(first * every, last - p + 1, every)
        if not len(starts):
            return
        take = (starts[:, None] - y0 + np.arange(p)[None, :]).ravel()
        cells, clipped = thumbnail_cells(rows[take], self.cfa, self.black, self.white, self.step, self.w)
        self.cells[first:first + len(starts)] = cells
        self.clipped[first:first + len(starts)] = clipped
