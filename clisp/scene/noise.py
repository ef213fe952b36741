"""Per-channel noise of the white-balanced raw: from the sensor model, or estimated from the raw.

Both give a :class:`ChannelNoise`, the affine variance of one white-balanced, normalised sample of
CFA channel c at expected level s (docs/model.md section 3)::

    var_c(s) = shot[c] * max(s, 0) + floor[c]          units: (white-balanced normalised raw)^2

From the model (simulated raws, whose metadata carries the gain and the noise model):
shot = w / N_fs, floor = w^2 (read^2 + step^2 / 12) / N_fs^2 with w the pass-1 multiplier
(``RawImage.pass1_gains()``), i.e. exactly ``NoiseModel.variance``.

From the raw itself (camera raws, no noise metadata), :func:`estimate_raw_noise`: for every CFA
phase, the sub-image of that phase (a regular lattice, period p) is high-passed with Immerkaer's
3 x 3 Laplacian difference ``[[1,-2,1],[-2,4,-2],[1,-2,1]] / 6`` (unit noise gain for white noise,
zero response to planes), paired with the 3 x 3 mean as the local level; pixels whose 3 x 3
neighbourhood is clipped are dropped. The samples are pooled per channel and sorted by level into
bins of equal count; in each bin only the flattest 30 % by Sobel gradient are kept (the odd Sobel
response is independent of the even residual for Gaussian noise, so this rejects texture without
biasing the noise), and the bin's noise std is the robust 1.4826 median |residual|. A weighted least-squares line through (level, variance) gives
shot and floor, both clamped at 0.

J. Immerkaer, "Fast noise variance estimation", CVIU 64(2), 300-302, 1996 (the operator);
A. Foi et al., "Practical Poissonian-Gaussian noise modeling and fitting for single-image raw-data",
IEEE TIP 17(10), 2008 (the affine model and the level-binned fit).
"""
from __future__ import annotations

from typing import Any

import numpy as np

from ..cfa import CFA
from ..errors import ClispError
from ..sim.noise import ChannelNoise, NoiseModel
from ..io.rawimage import RawImage
from ..engine.streaming import window_source


class NoiseEstimateError(ClispError):
    """The raw holds too few flat samples to estimate its noise (small or heavily textured)."""

IMMERKAER = np.array([[1.0, -2.0, 1.0], [-2.0, 4.0, -2.0], [1.0, -2.0, 1.0]]) / 6.0
"""High-pass with sum of squared taps 1: a white-noise residual keeps the pixel's std."""
SOBEL = np.array([[1.0, 0.0, -1.0], [2.0, 0.0, -2.0], [1.0, 0.0, -1.0]])
"""Odd (antisymmetric) gradient: for Gaussian noise it is independent of the even IMMERKAER
residual at the same pixel, so selecting pixels by low gradient does not bias the noise estimate."""
FLAT_FRACTION = 0.3
"""Share of each level bin (the flattest by Sobel gradient) whose residuals estimate the noise."""
MAD_TO_STD = 1.4826
"""std of a zero-mean Gaussian = 1.4826 * median |x|."""
CLIP_FRACTION = 0.98
"""A normalised sample at or above this (before WB) counts as clipped."""


def median(values: np.ndarray) -> float:
    """``float(np.median(values))`` of a non-empty 1-D array, the same value bit for bit (the mean
    of the middle one or two order statistics; NaN if any value is NaN), without np.median's first
    call importing numpy.ma (about 10 ms of every ``clisp process``, which imports it nowhere else)."""
    n = values.size
    middle = [n // 2 - 1, n // 2] if n % 2 == 0 else [n // 2]
    part = np.partition(values, middle + [n - 1])                    # NaN sorts last
    if np.isnan(part[-1]):
        return float("nan")
    return float(np.mean(part[middle[0]:middle[-1] + 1]))


def _phase_residuals(plane: np.ndarray, clipped: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(level, residual, texture) of every interior pixel of one phase sub-image whose 3 x 3 is
    unclipped; texture = squared Sobel gradient magnitude."""
    if min(plane.shape) < 3:
        return np.empty(0), np.empty(0), np.empty(0)
    resid = _correlate3_interior(plane, IMMERKAER)
    level = _correlate3_interior(plane, np.full((3, 3), 1.0 / 9.0))
    texture = _correlate3_interior(plane, SOBEL) ** 2 + _correlate3_interior(plane, SOBEL.T) ** 2
    bad = np.zeros(resid.shape, dtype=bool)
    for dy in range(3):
        for dx in range(3):
            bad |= clipped[dy:dy + bad.shape[0], dx:dx + bad.shape[1]]
    keep = ~bad
    return level[keep].ravel(), resid[keep].ravel(), texture[keep].ravel()


def _correlate3_interior(plane: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """sum_t kernel[t] plane[. + t] on the interior (H-2 x W-2) of an H x W plane: the pixels whose
    3 x 3 lies inside, so no border rule is needed (plain NumPy: no scipy import on this path)."""
    h, w = plane.shape
    out = np.zeros((h - 2, w - 2))
    for dy in range(3):
        for dx in range(3):
            if kernel[dy, dx] != 0:
                out += kernel[dy, dx] * plane[dy:dy + h - 2, dx:dx + w - 2]
    return out


def fit_affine_variance(level: np.ndarray, resid: np.ndarray, texture: np.ndarray, bins: int = 16,
                        min_per_bin: int = 600, flat_fraction: float | None = None) -> tuple[float, float]:
    """(shot, floor) of var = shot * level + floor from pooled (level, residual, texture) samples.

    Samples are split by level into ``bins`` bins of equal count (at least ``min_per_bin`` each;
    by partition, O(n), not a full sort: ties at a bin edge fall on either side);
    in each bin the ``flat_fraction`` (None: FLAT_FRACTION) with the lowest texture give (median level,
    (1.4826 median |residual|)^2); the line is fitted by weighted least squares with weights
    count / var^2 (the variance of a variance estimate). Clamped at 0.
    """
    n = level.size
    if n < 2 * min_per_bin:
        raise NoiseEstimateError(f"noise estimate: only {n} usable samples in a channel (need {2 * min_per_bin})")
    edges = np.linspace(0, n, min(bins, n // min_per_bin) + 1).astype(int)
    order = np.argpartition(level, edges[1:-1]) if len(edges) > 2 else np.arange(n)
    xs, vs, ws = [], [], []
    for a, b in zip(edges[:-1], edges[1:]):
        idx = order[a:b]
        keep = max(1, int((FLAT_FRACTION if flat_fraction is None else flat_fraction) * (b - a)))
        flat = np.argpartition(texture[idx], keep - 1)[:keep] if keep < b - a else slice(None)
        idx = idx[flat]
        sigma = MAD_TO_STD * median(np.abs(resid[idx]))
        xs.append(median(level[idx]))
        vs.append(sigma * sigma)
        ws.append(idx.size / max(sigma ** 4, 1e-30))
    x, v, w = np.array(xs), np.array(vs), np.array(ws)
    design = np.stack([x, np.ones_like(x)], axis=1) * np.sqrt(w)[:, None]
    (shot, floor), *_ = np.linalg.lstsq(design, v * np.sqrt(w), rcond=None)
    if shot < 0:                                   # no measurable shot noise: constant variance
        shot, floor = 0.0, float(np.sum(w * v) / np.sum(w))
    if floor < 0:                                  # line through the origin instead
        shot, floor = float(np.sum(w * x * v) / np.sum(w * x * x)), 0.0
    return float(max(shot, 0.0)), float(max(floor, 0.0))


SAMPLE_CROP = 512
"""Side of the crops the estimate reads from large raws (px, a multiple of every CFA period)."""
SAMPLE_PIXELS = 4_000_000
"""Raws larger than this are sampled by a grid of SAMPLE_CROP crops totalling about this many pixels."""


def sample_crops(height: int, width: int, max_pixels: int = SAMPLE_PIXELS,
                 crop: int = SAMPLE_CROP) -> list[tuple[int, int, int, int]]:
    """(y0, y1, x0, x1) boxes to read: the whole image if small, else an evenly spaced grid of
    crop x crop boxes (origins multiples of ``crop``, so every box starts on CFA phase (0, 0))."""
    if height * width <= max_pixels or height < crop or width < crop:
        return [(0, height, 0, width)]
    per_side = max(1, int(np.sqrt(max_pixels / crop ** 2)))
    ys = np.unique(np.linspace(0, height // crop - 1, min(per_side, height // crop)).astype(int)) * crop
    xs = np.unique(np.linspace(0, width // crop - 1, min(per_side, width // crop)).astype(int)) * crop
    return [(int(y), int(y) + crop, int(x), int(x) + crop) for y in ys for x in xs]


def estimate_raw_noise(data: np.ndarray, cfa: CFA, black_level: np.ndarray, white_level: float,
                       pass1_gains: np.ndarray, bins: int = 16) -> ChannelNoise:
    """Estimate :class:`ChannelNoise` (WB'd normalised units) from the mosaic ``data`` (H x W DN).

    See the module docstring for the method. ``pass1_gains``: the multipliers that take the
    normalised raw to white-balanced values (``RawImage.pass1_gains()``). Raws above
    SAMPLE_PIXELS are read as a grid of crops (:func:`sample_crops`), so a memory-mapped raw of any
    size costs about SAMPLE_PIXELS of reading.
    """
    p = cfa.period
    black = np.broadcast_to(np.asarray(black_level, dtype=np.float64), (cfa.n_channels,))
    gains = np.asarray(pass1_gains, dtype=np.float64)
    levels: list[list[np.ndarray]] = [[] for _ in range(cfa.n_channels)]
    resids: list[list[np.ndarray]] = [[] for _ in range(cfa.n_channels)]
    textures: list[list[np.ndarray]] = [[] for _ in range(cfa.n_channels)]
    source = window_source(data)     # a mapped raw file is read with pread: a file truncated
    try:                              # meanwhile raises ClispError instead of a bus error
        blocks = [(y0, x0, source.read(y0, x0, y1 - y0, x1 - x0, p))
                  for y0, y1, x0, x1 in sample_crops(data.shape[0], data.shape[1])]
    finally:
        source.close()
    for y0, x0, block in blocks:
        for py in range(p):
            for px in range(p):
                c = int(cfa.pattern[(y0 + py) % p, (x0 + px) % p])
                sub = block[py::p, px::p].astype(np.float64)
                norm = (sub - black[c]) / (float(white_level) - black[c])
                lv, rs, tx = _phase_residuals(norm * gains[c], norm >= CLIP_FRACTION)
                levels[c].append(lv)
                resids[c].append(rs)
                textures[c].append(tx)
    shot, floor = [], []
    for c in range(cfa.n_channels):
        s, f = fit_affine_variance(np.concatenate(levels[c]), np.concatenate(resids[c]),
                                   np.concatenate(textures[c]), bins)
        shot.append(s)
        floor.append(f)
    least = quantisation_floor(data.dtype, black, white_level, gains)
    return ChannelNoise(tuple(shot), tuple(max(f, q) for f, q in zip(floor, least)), "estimate")


def quantisation_floor(dtype: np.dtype, black_level: np.ndarray, white_level: float,
                       gains: np.ndarray) -> np.ndarray:
    """(nch,) the least variance floor an estimate may give (WB'd normalised units^2): the
    quantisation of an integer raw's samples, step^2 / 12 with step = gain / (white - black); 0 for
    a float raw. A line fitted through bright bins alone can extrapolate to a floor below it (the
    D30's blue: 0), which no sensor has, and which would make dark pixels look noiseless.

    >>> quantisation_floor(np.dtype(np.uint16), np.array([0.0]), 1024.0, np.array([2.0])).round(10).tolist()
    [3.179e-07]
    """
    if np.dtype(dtype).kind not in "ui":
        return np.zeros(len(gains))
    step = np.asarray(gains, dtype=np.float64) / (float(white_level) - np.asarray(black_level, dtype=np.float64))
    return step * step / 12.0


Samples = list[tuple[np.ndarray, np.ndarray, np.ndarray]]
"""Per channel, the noise samples of every strip: (level, Immerkaer residual, squared Sobel
gradient), each (n,) float64 in WB'd normalised units, in the order strip, phase row, phase column,
position."""


def strip_samples(strips: list[np.ndarray], pattern: np.ndarray, black_level: np.ndarray, scale: np.ndarray,
                  gains: np.ndarray, w: int) -> Samples:
    """Noise samples of the strips (each (k p, ``w``) DN with k >= 3, starting on CFA phase row 0:
    the statistics pass's noise strips, clisp.scene.statistics): on each phase's lattice, the 3 x 3
    residual, level and texture of every position whose 3 x 3 holds no clipped sample, in WB'd
    normalised units (``(DN - black_level[c]) * scale[c]``; a sample at or above CLIP_FRACTION *
    gains[c] there is clipped). ``pattern``: the CFA's (p, p) channel of each phase. A strip of k
    lattice rows is read as its k - 2 windows of 3 (one residual row each)."""
    p = pattern.shape[0]
    strips = [strip[k * p:(k + 3) * p] for strip in strips for k in range(strip.shape[0] // p - 2)]
    s = len(strips)
    nch = int(pattern.max()) + 1
    black_level, scale, gains = (np.asarray(a, dtype=np.float64) for a in (black_level, scale, gains))
    n = -(-w // p)                                                   # lattice columns, the last padded
    if n < 3 or not strips:              # no 3 x 3 window on any lattice (a raw under 3 CFA tiles wide)
        return [(np.empty(0), np.empty(0), np.empty(0)) for _ in range(nch)]
    # the phases (py, px) sorted by channel (row-major within one), so each channel's are a slice
    py, px = np.divmod(np.argsort(pattern.ravel(), kind="stable"), p)
    ends = np.cumsum([np.count_nonzero(pattern == c) for c in range(nch)])
    chan = pattern[py, px]
    black, scl = black_level[chan][:, None, None], scale[chan][:, None, None]
    clip = (CLIP_FRACTION * gains[chan])[:, None, None]
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
        lat *= scl
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


def strip_noise(raw: RawImage, statistics: Any, bins: int = 16) -> ChannelNoise:
    """:class:`ChannelNoise` of ``raw`` (WB'd normalised units) from the noise strips of its
    statistics (clisp.scene.statistics.SceneStatistics): :func:`strip_samples` of every strip, then
    :func:`fit_affine_variance` per channel, as :func:`estimate_raw_noise` does on its crops.
    NoiseEstimateError when a channel has too few samples."""
    cfa = raw.cfa
    black = np.broadcast_to(np.asarray(raw.black_level, dtype=np.float64), (cfa.n_channels,))
    gains = raw.pass1_gains()
    strips = [statistics.strips[r] for r in sorted(statistics.strips)]
    samples = strip_samples(strips, cfa.pattern, black, gains / (float(raw.white_level) - black), gains,
                            raw.shape[1])
    lines = [fit_affine_variance(*one, bins=bins) for one in samples]
    least = quantisation_floor(raw.data.dtype, black, raw.white_level, gains)
    return ChannelNoise(tuple(shot for shot, _ in lines), tuple(max(floor, q) for (_, floor), q in zip(lines, least)),
                        "estimate")


def has_noise_model(raw: RawImage) -> bool:
    """Whether ``raw``'s metadata carries its sensor's noise model (clisp simulations)."""
    md: dict[str, Any] = raw.metadata or {}
    return "noise" in md and "gain" in md


def raw_noise(raw: RawImage, estimate: bool | None = None, statistics: Any = None) -> ChannelNoise:
    """The noise of ``raw``'s white-balanced channels.

    ``estimate=None`` (default): from the metadata when it carries the sensor model (clisp
    simulations: ``metadata['noise']`` and ``metadata['gain']``; gain None = noiseless, zero
    noise), else estimated from the data (camera raws). True / False force one or the other. The
    estimate reads the noise strips of ``statistics`` (clisp.scene.statistics.SceneStatistics:
    :func:`strip_noise`) where given, else crops of the mosaic (:func:`estimate_raw_noise`).
    """
    md: dict[str, Any] = raw.metadata or {}
    has_model = has_noise_model(raw)
    if estimate is None:
        estimate = not has_model
    if not estimate:
        if not has_model:
            raise ClispError(f"{raw.source}: no noise model in the metadata; estimate it instead")
        if md["gain"] is None:
            return ChannelNoise.zero(raw.cfa.n_channels)
        return ChannelNoise.from_model(NoiseModel.from_dict(md["noise"]), float(md["gain"]), raw.pass1_gains())
    if statistics is not None:
        return strip_noise(raw, statistics)
    return estimate_raw_noise(raw.data, raw.cfa, raw.black_level, raw.white_level, raw.pass1_gains())
