"""Scene analysis: a cheap pass over the mosaic that tells the skip planner what a scene needs.

:func:`analyse` reads the raw once, in bands of BLOCK rows, and summarises it on a grid of
BLOCK x BLOCK pixel blocks (fixed image coordinates, so any tile plan can be mapped onto them):

* per CFA channel, the noise of the white-balanced, normalised samples (ChannelNoise units,
  var = shot * s + floor): Immerkaer's 3 x 3 residual on each phase's lattice (the operator of
  clisp.noise_estimate), taken on a strip of 3 lattice rows at the top of every block row (about
  3 p / BLOCK of the rows: 19 % for LMS, 9 % for Bayer), fitted by noise_estimate's robust
  binned line (flattest 30 % per level bin, MAD). When the raw carries a sensor model, the
  measured sigma at each channel's median level is compared with the model's (``noise_ratio``);
* the clipped fraction (samples at or above CLIP_FRACTION of the white level);
* per block: mean luminance Y (the denoiser's Y, from per-channel block means), luminance detail
  and chroma activity (energy of a 4-neighbour Laplacian of the per-cell (CELL x CELL) means, divided
  by what the noise alone would give there: ~1 flat, >> 1 textured), colour saturation (chroma
  magnitude / Y), clipped fraction, and uniform (every phase exactly constant in the block).

Everything is NumPy; the mosaic is read once in bands (a memory-mapped raw stays mapped) and the
cost is printed by ``clisp process --explain``. Measured (tools/calibrate_skip.py --cost, 2 shared
cores, 12 MP, best of 3): LMS 197 ms = 16.4 ms/MP (about 2 % of the quality LMS pipeline,
~750 ms/MP), Bayer 133 ms = 11.1 ms/MP (about 7 % of the quality Bayer pipeline, ~160 ms/MP:
over the 5 % aim; the per-phase clipped/uniform reductions are the part to trim).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .cfa import CFA
from .errors import ClispError
from .sim.noise import ChannelNoise
from . import noise_estimate
from .noise_estimate import CLIP_FRACTION, IMMERKAER, SOBEL, fit_affine_variance, MAD_TO_STD
from .io.rawimage import RawImage
from .modules.chroma_denoise.stage import space_for

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


def analyse(raw: RawImage, block: int = BLOCK, strip_every: int | None = None) -> SceneAnalysis:
    """Analyse ``raw`` (see the module docstring) on a grid of ``block`` x ``block`` blocks.

    ``strip_every``: measure noise on the strip of every n-th block row only (None: as many as
    give NOISE_STRIPS strips, 1 = all)."""
    start = time.perf_counter()
    cfa: CFA = raw.cfa
    p, nch = cfa.period, cfa.n_channels
    if block % p or block % CELL or CELL % p:
        raise ClispError(f"analysis block {block} / cell {CELL} is not a multiple of the CFA period {p}")
    h, w = raw.shape
    if h < p or w < 3 * p:
        raise ClispError(f"raw of {w}x{h} is too small to analyse")
    black = np.asarray(raw.black_level, dtype=np.float64)
    gains = raw.pass1_gains()
    scale = gains / (float(raw.white_level) - black)                 # DN -> WB'd normalised
    clip_dn = black + CLIP_FRACTION * (float(raw.white_level) - black)
    luma_w, chroma_w = _luma_chroma(raw)
    pattern = cfa.pattern
    clip_rows = clip_dn[pattern][:, np.arange(w) % p]                 # (p, W) threshold per phase row
    counts = np.array([np.count_nonzero(pattern == c) for c in range(nch)], dtype=np.float64) * (CELL // p) ** 2

    rows, cols = -(-h // block), -(-w // block)
    if strip_every is None:
        strip_every = max(1, rows // NOISE_STRIPS)
    wc = w // CELL                                                   # whole cells per row
    cb = block // CELL                                               # cells per block side
    col_edges = np.arange(0, wc, cb)
    px_edges = np.arange(0, w, block)
    means = np.zeros((nch, rows, cols))
    lap_y = np.zeros((rows, cols))
    lap_c = np.zeros((chroma_w.shape[0], rows, cols))
    clipped = np.zeros((rows, cols))
    uniform = np.ones((rows, cols), dtype=bool)
    samples: list[list[tuple[np.ndarray, np.ndarray, np.ndarray]]] = [[] for _ in range(nch)]
    data = raw.data
    for r in range(rows):
        y0 = r * block
        band = np.asarray(data[y0:min(h, y0 + block)])
        hc = band.shape[0] // CELL
        # clipped samples per block (per channel thresholds) and uniformity: every phase constant
        # in the block <=> each sample equals the one a CFA period to its right and below
        phase_rows = (y0 + np.arange(band.shape[0])) % p
        clip_hit = band >= clip_rows[phase_rows]
        clipped[r] += np.add.reduceat(clip_hit.sum(axis=0), px_edges)[:cols]
        same = np.ones(band.shape, dtype=bool)
        same[:, :-p] = band[:, p:] == band[:, :-p]
        same[:-p] &= band[p:] == band[:-p]
        # a block's last period of columns compares with the next block's: leave those out
        inner = same.copy()
        for e in px_edges[1:]:
            inner[:, e - p:e] = True
        uniform[r] &= np.logical_and.reduceat(inner.all(axis=0), px_edges)[:cols]
        if hc == 0:
            continue
        cells = np.zeros((nch, hc, wc), dtype=np.float32)
        for py in range(CELL):
            for px in range(CELL):
                c = int(pattern[py % p, px % p])
                cells[c] += band[py:hc * CELL:CELL, px:wc * CELL:CELL]
        cells = (cells / counts[:, None, None] - black[:, None, None].astype(np.float32)) \
            * scale[:, None, None].astype(np.float32)
        block_sum = np.add.reduceat(cells.sum(axis=1), col_edges, axis=1)        # (nch, cols')
        n_cells = np.add.reduceat(np.full(wc, hc, dtype=np.float64), col_edges)
        means[:, r, :block_sum.shape[1]] = block_sum / n_cells
        y = np.tensordot(luma_w.astype(np.float32), cells, axes=1)
        ch = np.tensordot(chroma_w.astype(np.float32), cells, axes=1)
        if hc >= 3 and wc >= 3:
            ly = _laplacian(y)
            lc = _laplacian(ch)
            e = np.arange(0, wc - 2, cb)
            k = min(len(e), cols)
            lap_y[r, :k] = np.add.reduceat((ly ** 2).sum(axis=0), e)[:k] / np.add.reduceat(
                np.full(wc - 2, hc - 2.0), e)[:k]
            lap_c[:, r, :k] = np.add.reduceat((lc ** 2).sum(axis=1), e, axis=1)[:, :k] / np.add.reduceat(
                np.full(wc - 2, hc - 2.0), e)[:k]
        # noise strip: the first 3 lattice rows of every phase
        if r % strip_every == 0 and band.shape[0] >= 3 * p:
            for py in range(p):
                for px in range(p):
                    c = int(pattern[py, px])
                    lat = (band[py:3 * p:p, px::p].astype(np.float64) - black[c]) * scale[c]
                    if lat.shape[1] < 3:
                        continue
                    bad = lat >= CLIP_FRACTION * gains[c]
                    keep = ~(bad[:, :-2] | bad[:, 1:-1] | bad[:, 2:]).any(axis=0)
                    res = _row3(lat, IMMERKAER)[keep]
                    lvl = _row3(lat, np.full((3, 3), 1.0 / 9.0))[keep]
                    tex = (_row3(lat, SOBEL) ** 2 + _row3(lat, SOBEL.T) ** 2)[keep]
                    samples[c].append((lvl, res, tex))
    total = float(h * w)
    px_per_block = np.outer(np.diff(np.append(np.arange(0, h, block), h)), np.diff(np.append(px_edges, w)))
    clipped_fraction = float(clipped.sum() / total)
    clipped = clipped / px_per_block

    noise, sigma, levels = _fit_noise(samples, nch)
    model = _model_noise(raw)
    sigma_model = np.full(nch, np.nan)
    if model is not None:
        sigma_model = np.array([float(np.sqrt(model.variance(c, levels[c]))) for c in range(nch)])
        ratio = _model_ratio(samples, model, nch)
        sigma = np.where(np.isfinite(ratio), ratio * sigma_model, sigma)
    # noise-only energy of the Laplacians of the cell means, per block, from the noise in use
    ref = model if model is not None else noise
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
    detail = lap_y / (LAPLACIAN_NOISE_GAIN * var_y + tiny)
    chroma = (lap_c / (LAPLACIAN_NOISE_GAIN * var_c + tiny)).max(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        saturation = np.sqrt((chroma_means ** 2).sum(axis=0)) / np.maximum(np.abs(luma), 1e-6)
    return SceneAnalysis(
        shape=(h, w), cfa=cfa.name, block=block, noise=noise, model=model, sigma=sigma,
        sigma_model=sigma_model, levels=levels, clipped_fraction=clipped_fraction, luma=luma,
        detail=detail, chroma=chroma, saturation=saturation, clipped=clipped, uniform=uniform, means=means,
        seconds=time.perf_counter() - start, channel_names=tuple(getattr(cfa, "channels", ()) or ()))


def _laplacian(a: np.ndarray) -> np.ndarray:
    """4-neighbour Laplacian on the interior of the last two axes."""
    return (a[..., :-2, 1:-1] + a[..., 2:, 1:-1] + a[..., 1:-1, :-2] + a[..., 1:-1, 2:]
            - 4.0 * a[..., 1:-1, 1:-1])


def _row3(lat: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """The 3 x 3 correlation of a 3-row lattice strip: one output row of width W - 2."""
    n = lat.shape[1] - 2
    out = np.zeros(n)
    for dy in range(3):
        for dx in range(3):
            if kernel[dy, dx] != 0:
                out += kernel[dy, dx] * lat[dy, dx:dx + n]
    return out


def _fit_noise(samples: list[list[tuple[np.ndarray, np.ndarray, np.ndarray]]],
               nch: int) -> tuple[ChannelNoise | None, np.ndarray, np.ndarray]:
    """(fitted ChannelNoise or None, sigma at each channel's median level, median levels)."""
    shot, floor = [], []
    sigma, levels = np.full(nch, np.nan), np.full(nch, np.nan)
    ok = True
    for c in range(nch):
        if not samples[c]:
            ok = False
            continue
        lvl, res, tex = (np.concatenate(parts) for parts in zip(*samples[c]))
        if lvl.size == 0:
            ok = False
            continue
        levels[c] = float(np.median(lvl))
        saved = noise_estimate.FLAT_FRACTION
        noise_estimate.FLAT_FRACTION = FLAT_FRACTION
        try:
            s, f = fit_affine_variance(lvl, res, tex, bins=8, min_per_bin=150)
        except ClispError:
            ok = False                          # too few samples for a line: one robust sigma
            sigma[c] = MAD_TO_STD * float(np.median(np.abs(res)))
            continue
        finally:
            noise_estimate.FLAT_FRACTION = saved
        shot.append(s)
        floor.append(f)
        sigma[c] = float(np.sqrt(s * max(levels[c], 0.0) + f))
    noise = ChannelNoise(tuple(shot), tuple(floor), "estimate") if ok and len(shot) == nch else None
    return noise, sigma, levels


def _model_ratio(samples: list[list[tuple[np.ndarray, np.ndarray, np.ndarray]]], model: ChannelNoise,
                 nch: int) -> np.ndarray:
    """Measured / model noise std per channel: every residual is divided by the model's std at its
    level, and the robust std (1.4826 median |z|) of the FLAT_FRACTION flattest (by Sobel
    gradient, also in model units) is the ratio. No line fit, so it is stable on few samples."""
    ratio = np.full(nch, np.nan)
    for c in range(nch):
        if not samples[c]:
            continue
        lvl, res, tex = (np.concatenate(parts) for parts in zip(*samples[c]))
        var = model.variance(c, lvl)
        ok = var > 0
        if np.count_nonzero(ok) < 50:
            continue
        z, t = res[ok] / np.sqrt(var[ok]), tex[ok] / var[ok]
        keep = max(1, int(FLAT_FRACTION * z.size))
        flat = np.argpartition(t, keep - 1)[:keep]
        ratio[c] = MAD_TO_STD * float(np.median(np.abs(z[flat])))
    return ratio


def _model_noise(raw: RawImage) -> ChannelNoise | None:
    """The sensor model's noise when the raw carries one (clisp simulations), else None."""
    md: dict[str, Any] = raw.metadata or {}
    if "noise" not in md or "gain" not in md:
        return None
    if md["gain"] is None:
        return ChannelNoise.zero(raw.cfa.n_channels)
    return ChannelNoise.from_metadata(md, raw.pass1_gains())
