"""Scene analysis: what the skip planner needs to know of a scene, from its statistics.

:func:`analyse` reads the statistics pass's tables (clisp.scene.statistics: the block table and the
noise strips, measured once per raw) and summarises the scene on their grid of BLOCK x BLOCK pixel
blocks (fixed image coordinates, so any tile plan can be mapped onto them):

* per CFA channel, the noise of the white-balanced, normalised samples (ChannelNoise units,
  var = shot * s + floor): Immerkaer's 3 x 3 residual on each phase's lattice (the operator of
  clisp.scene.noise), taken on the noise strips (3 lattice rows at the top of a block row) of every
  n-th block row (NOISE_STRIPS strips or a few more), fitted by noise_estimate's robust binned line
  (flattest 30 % per level bin, MAD). When the raw carries a sensor model, the measured sigma at
  each channel's median level is compared with the model's (``noise_ratio``);
* the clipped fraction (samples at or above CLIP_FRACTION of the white level);
* per block: mean luminance Y (the denoiser's Y, from per-channel block means), luminance detail
  and chroma activity (energy of a 4-neighbour Laplacian of the per-cell (CELL x CELL) means, divided
  by what the noise alone would give there: ~1 flat, >> 1 textured), colour saturation (chroma
  magnitude / Y), clipped fraction, and uniform (every phase exactly constant in the block).

The table is white-balance free (DN sums, and the products of the channels' Laplacians), so the
white balance and the denoiser's colour space are applied here: the luma and chroma Laplacians'
energies are quadratic forms of the table's products (BlockTable.energy). Clipped and uniform are
exact sample tests; the products are exact integers for integer raws, so only the weighting rounds
(float64). Cost history: clisp/scene/README.md.
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
from .noise import fit_affine_variance, MAD_TO_STD, median, strip_samples
from .statistics import BLOCK, CELL, STRIP_PERIODS, SceneStatistics, reference_statistics
from ..io.rawimage import RawImage
from ..modules.chroma_denoise.stage import space_for

FLAT_FRACTION = 0.3
"""Share of each level bin (flattest by Sobel gradient) whose residuals give the noise."""

NOISE_MODEL_TOLERANCE = 4.0
"""Measured / model noise std above which the model is distrusted (see SceneAnalysis.noise_excess)."""

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
"""Threads of the noise measurement: the samples and each channel's fit are tasks shared among
them (NumPy releases the GIL in its loops)."""


@dataclass(frozen=True)
class _Layout:
    """The grid and the per-channel constants the analysis applies to the statistics' table.

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
    black: np.ndarray           # (nch,) DN
    scale: np.ndarray           # (nch,) DN -> WB'd normalised
    gains: np.ndarray           # (nch,) pass-1 gains (a WB'd sample at CLIP_FRACTION * gain is clipped)
    counts: np.ndarray          # (nch,) samples of each channel in a cell
    luma_w: np.ndarray          # (nch,) luma weights on WB'd channels
    chroma_w: np.ndarray        # (k, nch) chroma weights
    planes: np.ndarray          # (1 + k, nch) luma, chroma of WB'd cell means per DN of a channel's cell sum


def _layout(raw: RawImage, block: int = BLOCK) -> _Layout:
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
    luma_w, chroma_w = _luma_chroma(raw)
    pattern = cfa.pattern
    scale = gains / (float(raw.white_level) - black)
    counts = np.array([np.count_nonzero(pattern == c) for c in range(nch)], dtype=np.float64) * (CELL // p) ** 2
    return _Layout(
        h=h, w=w, block=block, p=p, nch=nch, pattern=pattern, rows=-(-h // block), cols=-(-w // block),
        black=black, scale=scale, gains=gains, counts=counts, luma_w=luma_w, chroma_w=chroma_w,
        planes=np.concatenate([luma_w[None], chroma_w]).astype(np.float32).astype(np.float64)
        * (scale.astype(np.float32) / counts)[None, :])


def analyse(raw: RawImage, strip_every: int | None = None, statistics: SceneStatistics | None = None) -> SceneAnalysis:
    """Analyse ``raw`` (see the module docstring) from its statistics (clisp.scene.statistics:
    ``statistics``, else measured here by the NumPy reference).

    ``strip_every``: measure noise on the strip of every n-th block row only (None: as many as
    give NOISE_STRIPS strips, 1 = all)."""
    start = time.perf_counter()
    lay = _layout(raw)
    stats = statistics if statistics is not None else reference_statistics(raw)
    table = stats.table
    if table is None or stats.block != lay.block or stats.shape != (lay.h, lay.w):
        raise ClispError(f"{raw.source}: the scene statistics do not serve the analysis's blocks")
    h, w, nch = lay.h, lay.w, lay.nch
    if strip_every is None:
        strip_every = max(1, lay.rows // NOISE_STRIPS)
    strips = [stats.strips[r][:STRIP_PERIODS * lay.p] for r in range(0, lay.rows, strip_every) if r in stats.strips]
    model = _model_noise(raw)
    with ThreadPoolExecutor(THREADS, thread_name_prefix="clisp-analysis") as pool:
        sampled = strip_samples(strips, lay.pattern, lay.black, lay.scale, lay.gains, lay.w)
        fits = [pool.submit(_channel_noise, one, c, model) for c, one in enumerate(sampled)]
        noise, sigma, sigma_model, levels = _noise(model, [f.result() for f in fits])
    px_per_block = np.outer(np.diff(np.append(np.arange(0, h, lay.block), h)),
                            np.diff(np.append(np.arange(0, w, lay.block), w)))
    clipped_count = table.clipped.sum(axis=0)
    clipped_fraction = float(clipped_count.sum() / float(h * w))
    clipped = clipped_count / px_per_block
    shape = (-1, 1, 1)                           # black and scale rounded to float32, as the cell means always were
    with np.errstate(divide="ignore", invalid="ignore"):
        means = np.where(table.cells > 0, (table.sums / (lay.counts.reshape(shape) * table.cells)
                                           - lay.black.astype(np.float32).reshape(shape))
                         * lay.scale.astype(np.float32).reshape(shape), 0.0)
    energy = table.energy(lay.planes)                                 # (1 + k, rows, cols)
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
    detail = energy[0] / (LAPLACIAN_NOISE_GAIN * var_y + tiny)
    chroma = (energy[1:] / (LAPLACIAN_NOISE_GAIN * var_c + tiny)).max(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        saturation = np.sqrt((chroma_means ** 2).sum(axis=0)) / np.maximum(np.abs(luma), 1e-6)
    cfa = raw.cfa
    return SceneAnalysis(
        shape=(h, w), cfa=cfa.name, block=lay.block, noise=noise, model=model, sigma=sigma,
        sigma_model=sigma_model, levels=levels, clipped_fraction=clipped_fraction, luma=luma,
        detail=detail, chroma=chroma, saturation=saturation, clipped=clipped, uniform=table.uniform.copy(),
        means=means, seconds=time.perf_counter() - start + stats.seconds,
        channel_names=tuple(getattr(cfa, "channels", ()) or ()))


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
