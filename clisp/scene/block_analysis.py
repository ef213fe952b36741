"""Scene analysis: a cheap pass over the mosaic that tells the skip planner what a scene needs.

:func:`analyse` reads the raw once, in bands of BAND_BLOCKS block rows, and summarises it on a grid
of BLOCK x BLOCK pixel blocks (fixed image coordinates, so any tile plan can be mapped onto them):

* per CFA channel, the noise of the white-balanced, normalised samples (ChannelNoise units,
  var = shot * s + floor): Immerkaer's 3 x 3 residual on each phase's lattice (the operator of
  clisp.scene.noise), taken on a strip of 3 lattice rows at the top of every n-th block row
  (NOISE_STRIPS strips or a few more; 3 p rows each), fitted by noise_estimate's robust
  binned line (flattest 30 % per level bin, MAD). When the raw carries a sensor model, the
  measured sigma at each channel's median level is compared with the model's (``noise_ratio``);
* the clipped fraction (samples at or above CLIP_FRACTION of the white level);
* per block: mean luminance Y (the denoiser's Y, from per-channel block means), luminance detail
  and chroma activity (energy of a 4-neighbour Laplacian of the per-cell (CELL x CELL) means, divided
  by what the noise alone would give there: ~1 flat, >> 1 textured), colour saturation (chroma
  magnitude / Y), clipped fraction, and uniform (every phase exactly constant in the block).

Everything is NumPy: the mosaic is read once in bands (a memory-mapped raw stays mapped; the noise
strips are copied out first), the noise and the bands are tasks shared by THREADS threads, and the
cost is printed by ``clisp process --explain``. Clipped and uniform are exact sample tests; the
detail and chroma Laplacians are taken on integer cell sums (exact), so only their weighting and
squaring round (float64). Measured with ``python tools/calibrate_skip.py --cost`` (kodim05 simulated
and tiled to 12 MP, in memory, best of 3) on 2 shared Xeon cores: LMS 41-46 ms = 3.5-3.8 ms/MP
(under 1 % of the quality LMS pipeline, ~750 ms/MP), Bayer 32-34 ms = 2.7-2.8 ms/MP (about 2 % of
the quality Bayer pipeline, ~160 ms/MP); the per-block-row loop this replaced took 102-108 and
68-73 ms in the same runs (197 and 133 ms when first measured). ``clisp process`` analyses once,
in a fresh process, and pays first-touch page faults on top: 12 MP DNG, 9 fresh processes, LMS
64-68 ms (the old loop 119-133), Bayer 50-55 ms (84-88).
"""
from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..cfa import CFA
from ..errors import ClispError
from ..sim.noise import ChannelNoise
from .noise import CLIP_FRACTION, IMMERKAER, SOBEL, fit_affine_variance, MAD_TO_STD, median
from ..io.rawimage import RawImage
from ..modules.chroma_denoise.stage import space_for

BLOCK = 64
"""Side of the analysis blocks (px): a multiple of every CFA period and of the denoiser's 2^J
alignment, so blocks start on CFA phase (0, 0) and never straddle a pyramid cell."""

FLAT_FRACTION = 0.3
"""Share of each level bin (flattest by Sobel gradient) whose residuals give the noise."""

NOISE_MODEL_TOLERANCE = 4.0
"""Measured / model noise std above which the model is distrusted (see SceneAnalysis.noise_excess)."""

CELL = 4
"""Side of the cells whose means the detail and chroma measures use, px (a multiple of every CFA
period): the same pixel scale for every CFA. On Bayer's own 2 px cells the Laplacian sees only
the highest frequencies, and smooth texture read as flat (measured: a sigma-4 px random texture
at gain 1 gave detail 1.4 on 2 px cells, against 28 for LMS's 4 px cells)."""

LAPLACIAN_NOISE_GAIN = 20.0
"""Sum of squared taps of the 4-neighbour Laplacian [[0,1,0],[1,-4,1],[0,1,0]]: its output
variance on white noise of variance v is 20 v."""


@dataclass
class SceneAnalysis:
    """What :func:`analyse` found; every per-block array is (rows, cols) of the BLOCK grid.

    noise        measured ChannelNoise (WB'd normalised units), or None when too few samples.
    model        the sensor model's ChannelNoise (simulated raws), else None.
    sigma        (n_channels,) measured noise std at each channel's median level (with a model: the
                 model's std times the robust ratio of the model-normalised residuals).
    sigma_model  (n_channels,) the model's std at the same levels (NaN without a model).
    levels       (n_channels,) median WB'd level of each channel.
    clipped_fraction  share of all samples at or above the clip threshold.
    luma         per block mean Y (the chroma denoiser's Y: LMS (L + M)/2 of WB'd values, Bayer
                 BT.601 of the colour matrix's RGB; white ~ 1).
    detail       per block luminance detail: Laplacian energy / noise-only energy (~1 flat).
    chroma       per block chroma activity, the same ratio on the chroma planes (max over them).
    saturation   per block colour saturation: |chroma| / Y of the block means.
    clipped      per block fraction of clipped samples.
    uniform      per block: every CFA phase exactly constant (constant fill possible).
    means        (n_channels, rows, cols) per block mean of each WB'd normalised channel.
    seconds      wall time of the analysis.
    """

    shape: tuple[int, int]
    cfa: str
    block: int
    noise: ChannelNoise | None
    model: ChannelNoise | None
    sigma: np.ndarray
    sigma_model: np.ndarray
    levels: np.ndarray
    clipped_fraction: float
    luma: np.ndarray
    detail: np.ndarray
    chroma: np.ndarray
    saturation: np.ndarray
    clipped: np.ndarray
    uniform: np.ndarray
    means: np.ndarray
    seconds: float = 0.0
    channel_names: tuple[str, ...] = field(default_factory=tuple)

    @property
    def grid(self) -> tuple[int, int]:
        return self.luma.shape  # type: ignore[return-value]

    @property
    def noise_ratio(self) -> np.ndarray:
        """Measured / model noise std per channel (NaN without a model or a measurement)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return self.sigma / self.sigma_model

    @property
    def noise_excess(self) -> float:
        """Factor on the planner's noise std: the largest measured / model ratio when it exceeds
        NOISE_MODEL_TOLERANCE (the model is then clearly wrong and the raw noisier than it says),
        else 1 (also without a model). The tolerance is wide because texture inflates the measured
        noise where the noise is tiny: on simulated raws the ratio is 0.9-1.1 on smooth scenes at
        gains 1-64, but up to 3.6 on Kodak 5 (dense texture) at gain 1 (1.0-1.2 at gain 64)."""
        ratio = self.noise_ratio
        ratio = ratio[np.isfinite(ratio)]
        if not ratio.size or ratio.max() <= NOISE_MODEL_TOLERANCE:
            return 1.0
        return float(ratio.max())

    def blocks_for(self, y0: int, x0: int, h: int, w: int, margin: int = 0) -> tuple[slice, slice]:
        """The block rows and columns overlapping the region (y0, x0, h, w) grown by ``margin`` px."""
        rows, cols = self.grid
        b = self.block
        r0, r1 = max(0, (y0 - margin) // b), min(rows, -(-(y0 + h + margin) // b))
        c0, c1 = max(0, (x0 - margin) // b), min(cols, -(-(x0 + w + margin) // b))
        return slice(r0, max(r1, r0 + 1)), slice(c0, max(c1, c0 + 1))

    def summary(self) -> str:
        """Human-readable report (``clisp process --explain``)."""
        h, w = self.shape
        rows, cols = self.grid
        lines = [f"scene analysis: {w}x{h} {self.cfa}, {rows}x{cols} blocks of {self.block} px, "
                 f"{self.seconds * 1e3:.0f} ms ({self.seconds * 1e3 / max(h * w / 1e6, 1e-9):.1f} ms/MP)"]
        names = self.channel_names or tuple(str(c) for c in range(len(self.sigma)))
        src = "model" if self.model is not None else "no sensor model"
        for c, name in enumerate(names):
            ratio = self.noise_ratio[c]
            check = f", model {self.sigma_model[c]:.2e} (measured/model {ratio:.2f})" if np.isfinite(ratio) else ""
            lines.append(f"  noise {name:>2}: sigma {self.sigma[c]:.2e} at level {self.levels[c]:.3f}{check}")
        if self.model is None:
            lines.append(f"  ({src}: the measurement stands alone)")
        n = rows * cols
        lines.append(f"  clipped samples {100 * self.clipped_fraction:.3f} %  (blocks with clipping: "
                     f"{int(np.count_nonzero(self.clipped > 0))}/{n})")
        flat = int(np.count_nonzero(self.detail < 2.0))
        lines.append(f"  blocks: flat (detail < 2x noise) {flat}/{n}, uniform {int(self.uniform.sum())}/{n}, "
                     f"luma median {np.median(self.luma):.3f} (5-95 %: {np.percentile(self.luma, 5):.3f}"
                     f"-{np.percentile(self.luma, 95):.3f}), chroma activity median {np.median(self.chroma):.2f}, "
                     f"saturation median {np.median(self.saturation):.2f}")
        return "\n".join(lines)

    __str__ = summary


def _luma_chroma(raw: RawImage) -> tuple[np.ndarray, np.ndarray]:
    """(luma (n_ch,), chroma (k, n_ch)) weights on WB'd camera channels: the chroma denoiser's space."""
    try:
        space = space_for(raw.cfa.spectral, raw.colour_matrix)
        return space.luma, space.chroma
    except ClispError:                       # another CFA kind: plain mean and differences from it
        n = raw.cfa.n_channels
        luma = np.full(n, 1.0 / n)
        return luma, np.eye(n) - luma[None, :]


NOISE_STRIPS = 16
"""Block rows whose strip measures the noise (spread evenly; all of them in smaller images): at
16 strips of 3 lattice rows a 12 MP raw gives 8-64 thousand residuals per channel, plenty for the
robust fit, at a quarter of the cost of every block row (12 MP LMS: 313 -> ~100 ms in all)."""


THREADS = min(4, os.cpu_count() or 1)
"""Threads of the analysis: the noise samples, each channel's noise fit and the bands are tasks
shared among them (NumPy releases the GIL in its loops). On 2 shared Xeon cores, 12 MP, best of
7 in one process: LMS 56 -> 46 ms, Bayer 35 -> 30 ms with 2 threads; in fresh processes, where
page faults weigh more, LMS 77 -> 64-68 ms, Bayer 52-55 -> 50-55 ms."""

BAND_BLOCKS = 4
"""Block rows summarised together in one band (BAND_BLOCKS * BLOCK rows, about 2 MB of a 12 MP
uint16 raw): large enough that NumPy's per-call overhead is small next to the work, small enough
to stay in cache and to keep a memory-mapped raw's reading in bands."""


@dataclass(frozen=True)
class _Layout:
    """What every band pass shares: the block grid, the cells and the per-channel constants.

    Pixel sizes are px; DN are the raw's units; "WB'd" values are black-subtracted, white-normalised
    and white-balanced (``(DN - black) * scale``)."""

    h: int
    w: int
    block: int
    p: int                      # CFA period
    nch: int
    pattern: np.ndarray         # (p, p) channel of each CFA phase
    rows: int                   # block rows
    cols: int                   # block columns
    wc: int                     # whole cells per image row
    px_edges: np.ndarray        # (cols,) first pixel column of each block
    cell_edges: np.ndarray      # first cell column of each block (whole cells only)
    lap_edges: np.ndarray       # first Laplacian column of each block (it drops a cell each side)
    cross: np.ndarray           # (w - p,) bool: comparisons of x with x + p that cross a block edge
    clip_tile: np.ndarray       # (block, w) clip threshold per sample of a block row (see _clip_tile)
    black: np.ndarray           # (nch,) DN
    scale: np.ndarray           # (nch,) DN -> WB'd normalised
    gains: np.ndarray           # (nch,) pass-1 gains (a WB'd sample at CLIP_FRACTION * gain is clipped)
    counts: np.ndarray          # (nch,) samples of each channel in a cell
    luma_w: np.ndarray          # (nch,) luma weights on WB'd channels
    chroma_w: np.ndarray        # (k, nch) chroma weights
    planes: np.ndarray          # (1 + k, nch) luma, chroma of WB'd cell means per DN of a channel's cell sum
    sums_dtype: type            # dtype of the cell sums (int32 for integer raws: exact)


def _clip_tile(clip_dn: np.ndarray, pattern: np.ndarray, block: int, w: int, dtype: np.dtype) -> np.ndarray:
    """(block, w) threshold per sample of a block row (its rows start on CFA phase 0) in the raw's
    own dtype, such that ``band >= tile`` is exactly ``band >= clip_dn[channel]`` (float64): each
    threshold is rounded up to the next value the dtype holds (x >= t <=> x >= ceil(t) for integer
    x; the same with the next float32 for float32 x). Other dtypes compare in float64."""
    p = pattern.shape[0]
    per_phase = clip_dn[pattern]                                     # (p, p) float64
    if np.issubdtype(dtype, np.integer):
        info = np.iinfo(dtype)
        whole = np.ceil(per_phase)
        if whole.max() <= info.max:
            per_phase = np.maximum(whole, info.min).astype(dtype)
    elif dtype == np.float32:
        single = per_phase.astype(np.float32)
        per_phase = np.where(single < per_phase, np.nextafter(single, np.float32(np.inf)), single)
    return np.tile(per_phase, (block // p, -(-w // p)))[:, :w].copy()


def _layout(raw: RawImage, block: int) -> _Layout:
    """The grid and constants of ``raw`` for :func:`analyse` (raises ClispError on bad sizes)."""
    cfa: CFA = raw.cfa
    p, nch = cfa.period, cfa.n_channels
    if block % p or block % CELL or CELL % p:
        raise ClispError(f"analysis block {block} / cell {CELL} is not a multiple of the CFA period {p}")
    h, w = raw.shape
    if h < p or w < 3 * p:
        raise ClispError(f"raw of {w}x{h} is too small to analyse")
    black = np.asarray(raw.black_level, dtype=np.float64)
    gains = raw.pass1_gains()
    clip_dn = black + CLIP_FRACTION * (float(raw.white_level) - black)
    luma_w, chroma_w = _luma_chroma(raw)
    pattern = cfa.pattern
    wc, cb = w // CELL, block // CELL
    scale = gains / (float(raw.white_level) - black)
    counts = np.array([np.count_nonzero(pattern == c) for c in range(nch)], dtype=np.float64) * (CELL // p) ** 2
    cross = np.zeros(max(w - p, 0), dtype=bool)
    for e in range(block, w, block):
        cross[e - p:e] = True
    return _Layout(
        h=h, w=w, block=block, p=p, nch=nch, pattern=pattern, rows=-(-h // block), cols=-(-w // block),
        wc=wc, px_edges=np.arange(0, w, block), cell_edges=np.arange(0, wc, cb),
        lap_edges=np.arange(0, max(wc - 2, 0), cb), cross=cross,
        clip_tile=_clip_tile(clip_dn, pattern, block, w, raw.data.dtype), black=black,
        scale=scale, gains=gains,
        counts=counts, luma_w=luma_w, chroma_w=chroma_w,
        planes=np.concatenate([luma_w[None], chroma_w]).astype(np.float32).astype(np.float64)
        * (scale.astype(np.float32) / counts)[None, :],
        sums_dtype=np.int32 if raw.data.dtype.kind in "ui" and raw.data.dtype.itemsize <= 2 else np.float32)


def analyse(raw: RawImage, block: int = BLOCK, strip_every: int | None = None) -> SceneAnalysis:
    """Analyse ``raw`` (see the module docstring) on a grid of ``block`` x ``block`` blocks.

    ``strip_every``: measure noise on the strip of every n-th block row only (None: as many as
    give NOISE_STRIPS strips, 1 = all)."""
    start = time.perf_counter()
    lay = _layout(raw, block)
    h, w, nch = lay.h, lay.w, lay.nch
    if strip_every is None:
        strip_every = max(1, lay.rows // NOISE_STRIPS)
    strips = [np.array(raw.data[r * block:r * block + 3 * lay.p]) for r in _strip_rows(lay, strip_every)]
    model = _model_noise(raw)
    acc = _BlockSums.empty(lay)
    # the first free thread takes each task: the noise samples, half the bands, each channel's noise
    # fit (queued once the samples are there), the other half
    bands = _bands(lay)
    with ThreadPoolExecutor(THREADS, thread_name_prefix="clisp-analysis") as pool:
        sampled = pool.submit(_strip_samples, strips, lay)
        scans = [pool.submit(_scan_band, raw.data, r0, r1, lay, acc) for r0, r1 in bands[:len(bands) // 2]]
        fits = [pool.submit(_channel_noise, one, c, model) for c, one in enumerate(sampled.result())]
        scans += [pool.submit(_scan_band, raw.data, r0, r1, lay, acc) for r0, r1 in bands[len(bands) // 2:]]
        for done in scans:
            done.result()
        noise, sigma, sigma_model, levels = _noise(model, [f.result() for f in fits])
    px_per_block = np.outer(np.diff(np.append(np.arange(0, h, block), h)), np.diff(np.append(lay.px_edges, w)))
    clipped_fraction = float(acc.clipped.sum() / float(h * w))
    clipped = acc.clipped / px_per_block
    means = acc.means
    # noise-only energy of the Laplacians of the cell means, per block, from the noise in use
    ref = model if model is not None else noise
    luma_w, chroma_w, counts = lay.luma_w, lay.chroma_w, lay.counts
    luma = np.tensordot(luma_w, means, axes=1)
    chroma_means = np.tensordot(chroma_w, means, axes=1)
    if ref is not None:
        var_cells = np.stack([ref.variance(c, means[c]) / counts[c] for c in range(nch)])     # (nch, r, c)
        var_y = np.tensordot(luma_w ** 2, var_cells, axes=1)
        var_c = np.tensordot(chroma_w ** 2, var_cells, axes=1)
    else:
        var_y = np.zeros_like(luma)
        var_c = np.zeros_like(chroma_means)
    tiny = 1e-12
    detail = acc.lap_y / (LAPLACIAN_NOISE_GAIN * var_y + tiny)
    chroma = (acc.lap_c / (LAPLACIAN_NOISE_GAIN * var_c + tiny)).max(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        saturation = np.sqrt((chroma_means ** 2).sum(axis=0)) / np.maximum(np.abs(luma), 1e-6)
    cfa = raw.cfa
    return SceneAnalysis(
        shape=(h, w), cfa=cfa.name, block=block, noise=noise, model=model, sigma=sigma,
        sigma_model=sigma_model, levels=levels, clipped_fraction=clipped_fraction, luma=luma,
        detail=detail, chroma=chroma, saturation=saturation, clipped=clipped, uniform=acc.uniform, means=means,
        seconds=time.perf_counter() - start, channel_names=tuple(getattr(cfa, "channels", ()) or ()))


def _strip_rows(lay: _Layout, strip_every: int) -> list[int]:
    """Block rows whose strip (their first 3 p rows) measures the noise: every ``strip_every``-th
    one that has those rows and at least one whole cell row."""
    return [r for r in range(0, lay.rows, strip_every)
            if min(lay.block, lay.h - r * lay.block) >= max(3 * lay.p, CELL)]


def _noise(model: ChannelNoise | None, fits: list["_ChannelFit"]
           ) -> tuple[ChannelNoise | None, np.ndarray, np.ndarray, np.ndarray]:
    """(fitted noise, sigma, sigma_model, levels) of SceneAnalysis from each channel's measurement
    and the sensor model (None: none; sigma_model is then NaN). The fitted noise needs every
    channel's line; with a model, sigma is the model's times the measured ratio where there is one."""
    levels = np.array([f.level for f in fits])
    sigma = np.array([f.sigma for f in fits])
    lines = [f.line for f in fits if f.line is not None]
    noise = None
    if len(lines) == len(fits):
        noise = ChannelNoise(tuple(shot for shot, _ in lines), tuple(floor for _, floor in lines), "estimate")
    sigma_model = np.full(len(fits), np.nan)
    if model is not None:
        sigma_model = np.array([float(np.sqrt(model.variance(c, levels[c]))) for c in range(len(fits))])
        ratio = np.array([f.ratio for f in fits])
        sigma = np.where(np.isfinite(ratio), ratio * sigma_model, sigma)
    return noise, sigma, sigma_model, levels


@dataclass
class _BlockSums:
    """The per-block sums the band passes fill in (each band writes only its own block rows).

    means    (nch, rows, cols) mean WB'd value of each channel.
    lap_y    (rows, cols) mean squared Laplacian of the luma cell means.
    lap_c    (k, rows, cols) the same for each chroma plane.
    clipped  (rows, cols) clipped samples (a count).
    uniform  (rows, cols) every CFA phase exactly constant in the block."""

    means: np.ndarray
    lap_y: np.ndarray
    lap_c: np.ndarray
    clipped: np.ndarray
    uniform: np.ndarray

    @classmethod
    def empty(cls, lay: _Layout) -> "_BlockSums":
        shape = (lay.rows, lay.cols)
        return cls(np.zeros((lay.nch,) + shape), np.zeros(shape), np.zeros((lay.chroma_w.shape[0],) + shape),
                   np.zeros(shape), np.ones(shape, dtype=bool))


def _bands(lay: _Layout) -> list[tuple[int, int]]:
    """(first, end) block rows of each band: BAND_BLOCKS whole block rows at a time, and a last
    partial block row (image height not a multiple of the block) on its own."""
    whole = lay.h // lay.block
    bands = [(r, min(r + BAND_BLOCKS, whole)) for r in range(0, whole, BAND_BLOCKS)]
    if whole < lay.rows:
        bands.append((whole, lay.rows))
    return bands


def _scan_band(data: np.ndarray, r0: int, r1: int, lay: _Layout, acc: _BlockSums) -> None:
    """Read block rows r0 .. r1 - 1 of the mosaic ``data`` (H x W DN) and write their per-block
    sums to ``acc`` (only those rows: bands may run in parallel)."""
    band = np.asarray(data[r0 * lay.block:min(lay.h, r1 * lay.block)])
    band = band.reshape(r1 - r0, -1, lay.w)      # (kb, bh, W): bh = block, but in a last partial block row
    rs = slice(r0, r1)
    acc.clipped[rs] = _clipped_counts(band, lay)
    acc.uniform[rs] = _uniform(band, lay)
    hc = band.shape[1] // CELL
    if hc > 0:
        _cell_activity(_cell_sums(band, lay, hc), rs, lay, acc)


def _clipped_counts(band: np.ndarray, lay: _Layout) -> np.ndarray:
    """(kb, cols) clipped samples (at or above their channel's threshold) per block of ``band``;
    a band whose largest sample is below every threshold (most of a photo) is not compared."""
    if band.max() < lay.clip_tile.min():
        return np.zeros((band.shape[0], lay.cols), dtype=np.int64)
    hit = band >= lay.clip_tile[:band.shape[1]]
    per_column = hit.sum(axis=1, dtype=np.uint16 if band.shape[1] <= 0xFFFF else np.int64)
    return np.add.reduceat(per_column.astype(np.int64), lay.px_edges, axis=-1)


def _uniform(band: np.ndarray, lay: _Layout) -> np.ndarray:
    """(kb, cols) bool: every CFA phase exactly constant in the block. Most blocks of a photo
    differ within their first 2 p rows, so those are compared first and the whole band only when
    some block is still a candidate."""
    top = _differs(band[:, :2 * lay.p], lay)
    if top.all():
        return ~top
    return ~_differs(band, lay)


def _differs(band: np.ndarray, lay: _Layout) -> np.ndarray:
    """(kb, cols) bool: some sample of the block differs from the one a CFA period to its right or
    below it in the same block (False <=> every phase is constant in the block)."""
    p = lay.p
    right = (band[:, :, p:] != band[:, :, :-p]).any(axis=1)          # (kb, W - p)
    right[:, lay.cross] = False                                      # a block's last p columns vs the next block
    below = (band[:, p:] != band[:, :-p]).any(axis=1)                # (kb, W)
    below[:, :right.shape[1]] |= right
    return np.logical_or.reduceat(below, lay.px_edges, axis=-1)


def _cell_sums(band: np.ndarray, lay: _Layout, hc: int) -> np.ndarray:
    """(nch, kb, hc, wc) sum of each channel's samples in every CELL x CELL cell, DN: int32 for
    integer raws (exact), float32 (as always) for others."""
    kb = band.shape[0]
    v = band[:, :hc * CELL, :lay.wc * CELL].reshape(kb, hc, CELL, lay.wc, CELL)
    sums = np.empty((lay.nch, kb, hc, lay.wc), dtype=lay.sums_dtype)
    started = set()
    for py in range(CELL):
        for px in range(CELL):
            c = int(lay.pattern[py % lay.p, px % lay.p])
            if c in started:
                sums[c] += v[:, :, py, :, px]
            else:
                sums[c] = v[:, :, py, :, px]
                started.add(c)
    return sums


def _cell_activity(sums: np.ndarray, rs: slice, lay: _Layout, acc: _BlockSums) -> None:
    """Block means of the cells' WB'd channel means, and the mean squared Laplacian of their luma
    and chroma planes (within each block row: it reads no cell of the block rows above or below),
    from the cell sums ``sums`` (nch, kb, hc, wc) DN, written to the block rows ``rs`` of ``acc``.

    The Laplacian is linear and its taps sum to 0, so the luma / chroma Laplacian is lay.planes
    times the Laplacians of the channels' cell sums: those are exact (int32 for integer raws,
    float64 of the float32 sums for others), and only the weighting and squaring round (float64)."""
    _, _, hc, wc = sums.shape
    block_sum = np.add.reduceat(sums.sum(axis=2, dtype=np.float64), lay.cell_edges, axis=-1)   # (nch, kb, cols')
    n_cells = np.add.reduceat(np.full(wc, hc, dtype=np.float64), lay.cell_edges)
    shape = (-1, 1, 1)                         # black and scale rounded to float32, as the cell means always were
    acc.means[:, rs, :block_sum.shape[-1]] = (block_sum / (lay.counts.reshape(shape) * n_cells)
                                              - lay.black.astype(np.float32).reshape(shape)) \
        * lay.scale.astype(np.float32).reshape(shape)
    if hc < 3 or wc < 3:
        return
    planes = np.tensordot(lay.planes, _laplacian(sums if sums.dtype.kind == "i" else sums.astype(np.float64)), axes=1)
    planes *= planes                                                 # (1 + k, kb, hc - 2, wc - 2)
    e = lay.lap_edges
    k = min(len(e), lay.cols)
    n_lap = np.add.reduceat(np.full(wc - 2, hc - 2.0), e)[:k]                       # Laplacians per block
    energy = np.add.reduceat(planes.sum(axis=-2), e, axis=-1)[..., :k] / n_lap
    acc.lap_y[rs, :k] = energy[0]
    acc.lap_c[:, rs, :k] = energy[1:]


def _laplacian(a: np.ndarray) -> np.ndarray:
    """4-neighbour Laplacian on the interior of the last two axes (in a's dtype)."""
    lap = a[..., :-2, 1:-1] + a[..., 2:, 1:-1]
    lap += a[..., 1:-1, :-2]
    lap += a[..., 1:-1, 2:]
    lap -= 4 * a[..., 1:-1, 1:-1]
    return lap


Samples = list[tuple[np.ndarray, np.ndarray, np.ndarray]]
"""Per channel, the noise samples of every strip: (level, Immerkaer residual, squared Sobel
gradient), each (n,) float64 in WB'd normalised units, in the order strip, phase row, phase column,
position."""


def _strip_samples(strips: list[np.ndarray], lay: _Layout) -> Samples:
    """Noise samples of the strips (each (3 p, W) DN): on each phase's lattice (3 rows), the 3 x 3
    residual, level and texture of every position whose 3 x 3 holds no clipped sample."""
    p, w, s = lay.p, lay.w, len(strips)
    n = -(-w // p)                                                   # lattice columns, the last padded
    # the phases (py, px) sorted by channel (row-major within one), so each channel's are a slice
    py, px = np.divmod(np.argsort(lay.pattern.ravel(), kind="stable"), p)
    ends = np.cumsum([np.count_nonzero(lay.pattern == c) for c in range(lay.nch)])
    chan = lay.pattern[py, px]
    black, scale = lay.black[chan][:, None, None], lay.scale[chan][:, None, None]
    clip = (CLIP_FRACTION * lay.gains[chan])[:, None, None]
    columns = -(-(w - px) // p)                                      # lattice columns of each phase
    inside = np.arange(n - 2)[None, :] < (columns - 2)[:, None]      # (phase, n - 2): not reading the padding
    measures = np.zeros((3, s, p * p, n - 2))                        # level, residual, texture
    keep = np.empty((s, p * p, n - 2), dtype=bool)
    dn = np.zeros((3, p, n, p), dtype=strips[0].dtype if strips else np.float64)
    lat = np.empty((p * p, 3, n))                                    # (phase, lattice row, lattice column)
    for i, strip in enumerate(strips):
        dn.reshape(3 * p, n * p)[:, :w] = strip
        lat[...] = dn[:, py, :, px]                                  # every phase's lattice, WB'd
        lat -= black
        lat *= scale
        bad = (lat >= clip).any(axis=-2)
        keep[i] = ~(bad[..., :-2] | bad[..., 1:-1] | bad[..., 2:]) & inside
        _lattice_measures(lat, *measures[:, i])
    samples = []
    for a, b in zip(np.append(0, ends[:-1]), ends):
        k = keep[:, a:b]
        lvl, res, tex = (m[:, a:b][k] for m in measures)
        samples.append((lvl, res, tex))
    return samples


_IMMERKAER_UNIT = float(IMMERKAER[0, 0])
_IMMERKAER_TAPS = np.rint(IMMERKAER / _IMMERKAER_UNIT).astype(int)
"""IMMERKAER = _IMMERKAER_UNIT (1/6) times these taps (1, -2 or 4: powers of two, so each tap's product
is the unit's product scaled exactly)."""


def _lattice_measures(lat: np.ndarray, level: np.ndarray, resid: np.ndarray, texture: np.ndarray) -> None:
    """Level (3 x 3 mean), Immerkaer residual and squared Sobel gradient of 3-row lattice strips
    ``lat`` (..., 3, n), written into the zeroed (..., n - 2) arrays ``level``, ``resid``, ``texture``.

    Bit for bit the tap-by-tap sums 0 + k[0, 0] x[0, 0:] + k[0, 1] x[0, 1:] + ... (row-major) of
    noise_estimate's correlation: every tap is one value (1/9, 1/6, 1) times +-1, 2 or 4, whose
    products are exact scalings of one product array."""
    sixth = lat * _IMMERKAER_UNIT
    _taps(resid, (sixth, sixth * 2.0, sixth * 4.0), _IMMERKAER_TAPS)
    _taps(level, (lat * (1.0 / 9.0),), np.ones((3, 3), dtype=int))
    double = lat * 2.0
    _taps(texture, (lat, double), SOBEL.astype(int))
    gy = _taps(np.zeros_like(texture), (lat, double), SOBEL.T.astype(int))
    texture *= texture
    gy *= gy
    texture += gy


def _taps(out: np.ndarray, scaled: tuple[np.ndarray, ...], weights: np.ndarray) -> np.ndarray:
    """Add to ``out`` (..., n) each tap weights[dy, dx] * lat[..., dy, dx:dx + n] in turn (row-major),
    from ``scaled`` = (lat, 2 lat, 4 lat)[:k] (k as the largest |weight| needs); returns ``out``."""
    n = out.shape[-1]
    for dy in range(3):
        for dx in range(3):
            wt = int(weights[dy, dx])
            if wt == 0:
                continue
            term = scaled[abs(wt).bit_length() - 1][..., dy, dx:dx + n]
            if wt > 0:
                out += term
            else:
                out -= term
    return out


@dataclass(frozen=True)
class _ChannelFit:
    """One channel's noise measurement (WB'd normalised units; NaN where there are no samples).

    level  median level of the samples.
    line   (shot, floor) of noise_estimate's binned fit, or None when too few samples for a line.
    sigma  the measured noise std at ``level``: the line's, else the robust 1.4826 median |residual|.
    ratio  measured / model noise std (NaN without a model or with under 50 samples)."""

    level: float
    line: tuple[float, float] | None
    sigma: float
    ratio: float


def _channel_noise(samples: tuple[np.ndarray, np.ndarray, np.ndarray], c: int,
                   model: ChannelNoise | None) -> _ChannelFit:
    """Channel ``c``'s noise from its samples (level, residual, texture)."""
    lvl, res, tex = samples
    ratio = _model_ratio(lvl, res, tex, model.variance(c, lvl)) if model is not None else float("nan")
    if lvl.size == 0:
        return _ChannelFit(float("nan"), None, float("nan"), ratio)
    level = median(lvl)
    try:
        shot, floor = fit_affine_variance(lvl, res, tex, bins=8, min_per_bin=150, flat_fraction=FLAT_FRACTION)
    except ClispError:                          # too few samples for a line: one robust sigma
        return _ChannelFit(level, None, MAD_TO_STD * median(np.abs(res)), ratio)
    return _ChannelFit(level, (shot, floor), float(np.sqrt(shot * max(level, 0.0) + floor)), ratio)


def _model_ratio(lvl: np.ndarray, res: np.ndarray, tex: np.ndarray, var: np.ndarray) -> float:
    """Measured / model noise std of one channel's samples, ``var`` the model's variance at each
    sample's level: every residual is divided by the model's std there, and the robust std
    (1.4826 median |z|) of the FLAT_FRACTION flattest (by Sobel gradient, also in model units)
    is the ratio. No line fit, so it is stable on few samples (NaN under 50)."""
    ok = var > 0
    if np.count_nonzero(ok) < 50:
        return float("nan")
    if not ok.all():
        res, tex, var = res[ok], tex[ok], var[ok]
    keep = max(1, int(FLAT_FRACTION * res.size))
    flat = np.argpartition(tex / var, keep - 1)[:keep]
    return MAD_TO_STD * median(np.abs(res[flat] / np.sqrt(var[flat])))


def _model_noise(raw: RawImage) -> ChannelNoise | None:
    """The sensor model's noise when the raw carries one (clisp simulations), else None."""
    md: dict[str, Any] = raw.metadata or {}
    if "noise" not in md or "gain" not in md:
        return None
    if md["gain"] is None:
        return ChannelNoise.zero(raw.cfa.n_channels)
    return ChannelNoise.from_metadata(md, raw.pass1_gains())
