"""Residual-interpolation Bayer demosaics (RI, MLRI, ARI and an ARI hybrid): NumPy float64 references.

The definitions of correct: ``demosaic_ari`` is what the device stage (stage.py, demosaic_ari.cl)
ports; the others are the candidates of issue 12's study. Every function takes an H x W mosaic (float, values
normally in [0, 1], linear or sRGB-encoded: the algorithms do not care) and a Bayer phase name
("RGGB", "GRBG", "GBRG", "BGGR": the colours of the top-left 2 x 2 block, row by row) and returns
H x W x 3 float64 RGB. The sampled CFA values stay at their own sites; interpolated values are
clipped to ``clip`` ([0, 1] by default, None: not clipped), inside the algorithms where the
published code clips and at the end.

Residual interpolation (RI) in one line: to interpolate a sparse channel X with a dense guide Y,
fit X ~ a Y + b locally by a guided filter over the X sites (the "tentative" estimate), take the
residual X - tentative at the X sites, interpolate that residual linearly, and add it back. The
residual is much smoother than the colour difference X - Y that classic methods interpolate.

Methods
-------
``demosaic_ri``  (Kiku et al., ICIP 2013) and ``demosaic_mlri`` (Kiku et al., ICIP 2014 /
TIP 2016 "minimized-Laplacian RI"):

1. Directional G: along each direction d (horizontal, vertical) the missing values of every line
   are first the mean of the two neighbours along d ([1/2, 0, 1/2]); then G at the chroma sites and
   the chroma (R or B) at the G sites of that line are each re-estimated by RI with the other as
   guide: a masked guided filter over the target's sites gives the tentative estimate, the residual
   is interpolated along d with [1/2, 0, 1/2]. This yields the colour difference G - C along d at
   every pixel.
   RI: plain guided filter, window 1 x 11 along d (radius 5), eps 1e-10 (8-bit units^2).
   MLRI: the slope a is fitted on Laplacians ([-1, 0, 2, 0, -1] along d) instead of on values,
   a = sum(lap Y lap X) / sum(lap Y^2) over the X sites of the window (mean of lap Y^2 floored at
   1e-5 * 255^2), b from the plain means; window 7 x 7.
2. The two colour differences are merged as in GBTF (Pekkucuksen & Altunbasak 2010): weights
   1 / (D^2 + c) of the summed colour-difference gradients D of the neighbour 2 (RI; 5 x 5 sums,
   c = 1e-32) or 1 (MLRI; 3 x 3 sums, c = 1e-2 in 8-bit units) pixels to the N, S, W, E; each
   direction's difference is smoothed by a one-sided 5-tap Gaussian (sigma 1 for RI, 1.4 for MLRI)
   towards that side. G = C + merged difference at the chroma sites.
3. R and B by RI with the full G as guide over the R (B) sites, window 11 x 11 (radius 5); MLRI
   fits the slope on the 2-D Laplacian (taps 4 at the centre, -1 at distance 2 along the axes).
   The residual is interpolated bilinearly.
   ``weighted=True`` averages the guided filters' a, b with ARI's 1 / RMSE weights (below).

``demosaic_ari`` (Monno, Kiku, Tanaka, Okutomi, ICIP 2015 / Sensors 2017, "adaptive RI"):

1. G: per direction d and per guided-filter kind k (RI and MLRI), ``green_iterations`` (11)
   iterations: both the G line and the chroma line of every row (column) are re-estimated from each
   other by RI (tentative by a guided filter over the whole line, residual at the samples,
   interpolated along d with [1/2, 1, 1/2]), and the new estimates become the guides of the next
   iteration. The windows grow by one pixel in each direction per iteration: RI from 5 along x 3
   across, MLRI from 9 along x 1 across. The iteration criterion of a pixel is
   c^2 * g, with c the |guide - tentative| (summed over G and chroma, both lines) and g its
   |[-1, 0, 1]| gradient along d, each smoothed by a 5 x 5 Gaussian (sigma 2); a pixel keeps the
   estimate of the iteration with the smallest criterion. The four (d, k) estimates are averaged
   with weights 1 / (criterion + 1e-10).
   Guided filters of ARI average the local coefficients a, b weighted by 1 / RMSE of each window's
   fit (RMSE floored at 1e-3 in 8-bit units) instead of uniformly; eps 1e-10.
2. R at B and B at R: the same adaptive scheme along the two diagonals with the full G as guide
   over the R and B sites (diagonal windows on that lattice; RI 5 x 5 sites, MLRI 5 sites along
   the diagonal, growing by 1), ``chroma_iterations`` (2) iterations, residuals interpolated with
   [1/2, 0, 1/2] along the diagonal; R and B share one criterion.
3. R and B at the G sites: the same along the rows and columns, the R (B) plane of step 2 being
   complete at the R and B sites; 2 iterations (RI 5 x 5, MLRI 5 x 1 windows).

``demosaic_ari_hybrid`` (this study; ``demosaic_ari(green_merge="mean", chroma="mean")``):
ARI's step 1 iterations, then G = the mean of (a) ARI's criterion-weighted merge and (b) a GBTF
merge (MLRI's step 2 parameters) of ARI's directional colour differences, each direction's G and
chroma lines being ARI's two kinds weighted by 1 / (criterion + 1e-10); R and B = the mean of
ARI's steps 2-3 and weighted MLRI's step 3, both on that G. The GBTF merge (directional weights and
one-sided smoothing of the colour difference) is what Kodak needs, ARI's merge and chroma what
McMaster needs; their means keep most of both (tools/demosaic_study.py).

Units and constants
-------------------
The mosaic is multiplied by ``SCALE`` (255) inside, so the published constants, given for 8-bit
data, apply to data in [0, 1] unchanged (a linear raw normalised to white = 1 is in the same units);
the output is scaled back. ARI's constants are named once here (``ARI_EPS``, ``ARI_RMSE_FLOOR``,
``WEIGHT_REG``, ``CRIT_REG``, ``CRIT_FLOOR``, ``CRITERION_RADIUS``, ``CRITERION_SIGMA``) and the
device stage takes them from here; ``ARI_EPS``, ``ARI_RMSE_FLOOR`` and ``CRIT_FLOOR`` are not the
paper's (the published ``EPS`` and ``RMSE_FLOOR`` left the stage ill-conditioned beside clipped
lights: README.md), and RI and MLRI keep ``EPS`` and ``RMSE_FLOOR``.

Borders
-------
The image is mirror-extended by ``PAD`` (16) pixels on every side (reflection about the edge pixel,
which keeps the CFA phase; the phase is moved to RGGB by one more mirrored row / column where
needed) and every filter also mirrors at the array's edge. Box sums are running sums
(scipy.ndimage.uniform_filter1d), so their rounding depends on the position along a row.

Measured halos, rounding, speed and CPSNR of the study: README.md.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

SCALE = 255.0
"""Working scale: data in [0, 1] become 8-bit code values, the units of the published constants."""
PAD = 16
"""Mirror padding on every side (even: keeps the CFA phase)."""
EPS = 1e-10
"""Guided filters' regulariser of the slope, a = cov / (var + EPS) (8-bit units^2; MLRI's slope too)."""
ARI_EPS = 1e-2
"""ARI's regulariser of the slope (8-bit units^2), in place of the published EPS: a window whose
guide is flat to within rounding (a clipped light, a flat estimate of an earlier iteration) has
var and cov of that rounding, about 1e-9 for float32 values of a few hundred, and EPS = 1e-10 made
its slope their ratio, any value, in the windows that fit best. 1e-2 (a tenth of a level, squared)
puts those slopes at 0 (README: the measurements)."""
RMSE_FLOOR = 1e-3
"""The weighted guided filter (ARI's, weighted MLRI's): a window's fit weighs 1 / max(RMSE,
RMSE_FLOOR) (8-bit units); ARI itself uses ARI_RMSE_FLOOR."""
ARI_RMSE_FLOOR = 1.0
"""ARI's RMSE floor (8-bit units), in place of the published RMSE_FLOOR: a window's mse is a
difference of its variances, and across a clipped light's edge (variances of 1e4-1e5) float32 leaves
it uncertain by about 1e-2, so the weights of fits better than a level were rounding, fed from one
iteration to the next. With the floor at a level they weigh alike (README: on a clipped raw the
device followed the reference to 0.16 of `best`'s output before, 0.0043 after; PSNR on 10 Kodak and
McMaster crops 0.03 dB higher)."""
WEIGHT_REG = 1e-4
"""ARI's weighted guided filter divides by the window's sum of those weights + WEIGHT_REG."""
CRIT_REG = 1e-10
"""ARI's merges: each estimate weighs 1 / (criterion + CRIT_REG)."""
CRIT_FLOOR = 1e-6
"""The least criterion (8-bit units^3): below it two criteria are rounding, and ARI's selection of
an iteration (the smallest criterion, the earlier on a tie) and its merges treat them as equal. On a
flat patch (a clipped light) every iteration's criterion is rounding, about 1e-15 in float32, and
its order, which differs between devices, chose the estimate (README)."""
CRITERION_RADIUS, CRITERION_SIGMA = 2, 2.0
"""ARI's criterion smooths its terms by a (2 CRITERION_RADIUS + 1)^2 Gaussian of this sigma (pixels)."""
PHASES = {"RGGB": (0, 0), "GRBG": (0, 1), "GBRG": (1, 0), "BGGR": (1, 1)}
"""Bayer phase -> (row, column) of the R site in the top-left 2 x 2 block."""

Array = np.ndarray
Window = tuple[str, int, int]
"""("box", ry, rx): the (2ry+1) x (2rx+1) rectangle; ("diag", p, q): the sites (i + j, i - j),
|i| <= p, |j| <= q, of the centre's quincunx lattice (p along the main diagonal, q along the other)."""


# ----------------------------------------------------------------------------------- layout

class Sites:
    """Boolean site masks of an RGGB mosaic (R at even rows and columns)."""

    def __init__(self, shape: tuple[int, int]):
        y, x = np.indices(shape)
        even_y, even_x = y % 2 == 0, x % 2 == 0
        self.r = even_y & even_x
        self.gr = even_y & ~even_x          # G in the R rows (R columns: below them, B)
        self.gb = ~even_y & even_x          # G in the B rows
        self.b = ~even_y & ~even_x
        self.g = self.gr | self.gb
        self.c = self.r | self.b            # chroma (R or B) sites
        self._lines = {"h": [(self.r | self.gr, self.r, self.gr), (self.b | self.gb, self.b, self.gb)],
                       "v": [(self.r | self.gb, self.r, self.gb), (self.b | self.gr, self.b, self.gr)]}

    def lines(self, direction: str) -> list[tuple[Array, Array, Array]]:
        """(line, chroma sites, G sites) of the R lines and of the B lines along ``direction``."""
        return self._lines[direction]


def _to_rggb(mosaic: Array, pattern: str) -> tuple[Array, tuple[int, int]]:
    """Mirror-pad by PAD (one more row / column before where the phase needs it) so that the padded
    array is RGGB; returns it and the padded position of the original pixel (0, 0)."""
    try:
        oy, ox = PHASES[pattern.upper()]
    except KeyError:
        raise ValueError(f"Bayer pattern must be one of {sorted(PHASES)}, got {pattern!r}") from None
    m = np.asarray(mosaic, dtype=np.float64)
    if m.ndim != 2:
        raise ValueError(f"mosaic must be H x W, got shape {m.shape}")
    if not np.all(np.isfinite(m)):
        raise ValueError("mosaic holds non-finite values")
    return np.pad(m, ((PAD + oy, PAD), (PAD + ox, PAD)), mode="reflect"), (PAD + oy, PAD + ox)


Clip = tuple[float, float] | None
"""Range (in the mosaic's units) that interpolated values are clipped to, inside the algorithms
as in the published code and at the end; None: no clipping."""


def _run(mosaic: Array, pattern: str, clip: Clip,
         core: Callable[[Array, Sites, float, float], tuple[Array, Array, Array]]) -> Array:
    """Pad to RGGB, scale to 8-bit units, run ``core`` (raw, sites, lo, hi) -> (R, G, B), clip to
    [lo, hi], crop, scale back."""
    padded, (y0, x0) = _to_rggb(mosaic, pattern)
    raw = padded * SCALE
    lo, hi = (-np.inf, np.inf) if clip is None else (clip[0] * SCALE, clip[1] * SCALE)
    sites = Sites(raw.shape)
    planes = core(raw, sites, lo, hi)
    h, w = np.shape(mosaic)
    out = np.stack([np.clip(p, lo, hi)[y0:y0 + h, x0:x0 + w] for p in planes], axis=-1)
    return out / SCALE


# ----------------------------------------------------------------------------------- filters

def _taps(x: Array, taps: dict[tuple[int, int], float]) -> Array:
    """sum_k w_k x(i + dy_k, j + dx_k) (a correlation) with mirrored borders."""
    from scipy.ndimage import correlate1d       # here: scipy.ndimage costs 0.16 s of CLI start-up
    for axis in (0, 1):
        if all(off[1 - axis] == 0 for off in taps):       # one axis: scipy's 1-D correlation
            r = max(abs(off[axis]) for off in taps)
            kernel = np.zeros(2 * r + 1)
            for off, weight in taps.items():
                kernel[r + off[axis]] += weight
            return correlate1d(x, kernel, axis=axis, mode="mirror")
    r = max(max(abs(dy), abs(dx)) for dy, dx in taps)
    xp = np.pad(x, r, mode="reflect")
    h, w = x.shape
    out = np.zeros_like(x)
    for (dy, dx), weight in taps.items():
        out += weight * xp[r + dy:r + dy + h, r + dx:r + dx + w]
    return out


STEPS = {"h": (0, 1), "v": (1, 0), "d1": (1, 1), "d2": (1, -1)}
"""Direction -> its (dy, dx) step: "h" (x), "v" (y), "d1" (y = x), "d2" (y = -x)."""


def _along(d: str, weights: list[float]) -> dict[tuple[int, int], float]:
    """A centred 1-D kernel as taps along d (STEPS)."""
    step = STEPS[d]
    r = len(weights) // 2
    return {(k * step[0], k * step[1]): w for k, w in zip(range(-r, r + 1), weights) if w != 0}


NEIGHBOUR_MEAN = [0.5, 0.0, 0.5]
RESIDUAL_LINEAR = [0.5, 1.0, 0.5]
GRADIENT = [-1.0, 0.0, 1.0]
LAPLACIAN = [-1.0, 0.0, 2.0, 0.0, -1.0]
LAPLACIAN_2D = {(0, 0): 4.0, (-2, 0): -1.0, (2, 0): -1.0, (0, -2): -1.0, (0, 2): -1.0}
BILINEAR = {(dy, dx): (1.0 if dy == 0 else 0.5) * (1.0 if dx == 0 else 0.5)
            for dy in (-1, 0, 1) for dx in (-1, 0, 1)}


def _box(x: Array, window: Window) -> Array:
    """Sum of x over ``window`` around every pixel (mirrored borders)."""
    from scipy.ndimage import uniform_filter1d   # deferred: the CLI imports this module, scipy costs start-up
    kind, ry, rx = window
    if kind == "diag":
        along = _taps(x, _along("d1", [1.0] * (2 * ry + 1)))
        return _taps(along, _along("d2", [1.0] * (2 * rx + 1)))
    if ry:
        x = uniform_filter1d(x, 2 * ry + 1, axis=0, mode="mirror") * (2 * ry + 1)
    if rx:
        x = uniform_filter1d(x, 2 * rx + 1, axis=1, mode="mirror") * (2 * rx + 1)
    return x


def _window_size(window: Window) -> int:
    return (2 * window[1] + 1) * (2 * window[2] + 1)


def gaussian_taps(radius: int, sigma: float) -> Array:
    """The 2 radius + 1 taps (offsets -radius..radius) of a normalised 1-D Gaussian of ``sigma`` pixels."""
    k = np.exp(-np.arange(-radius, radius + 1) ** 2 / (2.0 * sigma * sigma))
    return k / k.sum()


def _gauss(x: Array, radius: int, sigma: float) -> Array:
    """Separable normalised Gaussian smoothing, (2 radius + 1)^2 taps."""
    k = list(gaussian_taps(radius, sigma))
    return _taps(_taps(x, _along("h", k)), _along("v", k))


class WindowStats:
    """Window statistics of two images x, y over a mask: count n, means, variances, covariance
    (8-bit units), the sums shared by the fits of y from x and of x from y."""

    def __init__(self, x: Array, y: Array, mask: Array | None, window: Window):
        m = np.ones_like(x) if mask is None else mask.astype(np.float64)
        self.m, self.window = m, window
        self.n = np.maximum(_box(m, window), 1.0)
        mx, my = m * x, m * y
        self.mean_x, self.mean_y = _box(mx, window) / self.n, _box(my, window) / self.n
        self.var_x = _box(mx * x, window) / self.n - self.mean_x ** 2
        self.var_y = _box(my * y, window) / self.n - self.mean_y ** 2
        self.cov = _box(mx * y, window) / self.n - self.mean_x * self.mean_y

    def swapped(self) -> "WindowStats":
        other = object.__new__(WindowStats)
        other.__dict__.update(self.__dict__, mean_x=self.mean_y, mean_y=self.mean_x, var_x=self.var_y,
                              var_y=self.var_x)
        return other


def _fit(stats: WindowStats, guide: Array, target: Array, eps: float, laplacian: dict | None,
         lap_mask: Array | None, weighted: bool, lap_floor: float, rmse_floor: float = RMSE_FLOOR) -> Array:
    """The guided filter of ``target`` (y of ``stats``) against ``guide`` (x): see guided_filter."""
    window = stats.window
    if laplacian is None:
        a = stats.cov / (stats.var_x + eps)
    else:
        lm = stats.m if lap_mask is None else lap_mask.astype(np.float64)
        nl = np.maximum(_box(lm, window), 1.0)
        lap_i, lap_p = _taps(guide, laplacian), _taps(target, laplacian)
        lm_lap_i = lm * lap_i
        a = (_box(lm_lap_i * lap_p, window) / nl) / (np.maximum(_box(lm_lap_i * lap_i, window) / nl,
                                                               lap_floor) + eps)
    b = stats.mean_y - a * stats.mean_x
    if not weighted:
        count = float(_window_size(window))
        return _box(a, window) / count * guide + _box(b, window) / count
    # mean squared residual of a x + b ~ y over the window (b makes the mean residual zero)
    mse = a * a * stats.var_x - 2.0 * a * stats.cov + stats.var_y
    weight = 1.0 / np.maximum(np.sqrt(np.maximum(mse, 0.0)), rmse_floor)
    total = _box(weight, window) + WEIGHT_REG
    return _box(a * weight, window) / total * guide + _box(b * weight, window) / total


def guided_filter(guide: Array, target: Array, mask: Array | None, window: Window, eps: float = EPS,
                  laplacian: dict | None = None, lap_mask: Array | None = None, weighted: bool = False,
                  lap_floor: float = 0.0, rmse_floor: float = RMSE_FLOOR) -> Array:
    """Masked guided filter q = mean(a) guide + mean(b) (He et al.), statistics over ``mask`` (None:
    every pixel) in ``window`` (8-bit units).

    Plain (RI): a = cov(guide, target) / (var(guide) + eps), b = mean(target) - a mean(guide).
    ``laplacian`` (MLRI): a = sum(lap guide * lap target) / (sum((lap guide)^2) + eps) over the
    ``lap_mask`` sites of the window (the mean of (lap guide)^2 floored at ``lap_floor``); b as above.
    ``weighted`` (ARI): mean(a), mean(b) weighted by 1 / RMSE of each window's fit a guide + b ~ target
    over the mask (RMSE floored at ``rmse_floor``); else the plain window means (over every pixel).
    """
    stats = WindowStats(guide, target, mask, window)
    return _fit(stats, guide, target, eps, laplacian, lap_mask, weighted, lap_floor, rmse_floor)


def guided_pair(x: Array, y: Array, mask: Array | None, window: Window, laplacian: dict | None = None,
                lap_masks: tuple[Array | None, Array | None] = (None, None), weighted: bool = True,
                eps: float = EPS, rmse_floor: float = RMSE_FLOOR) -> tuple[Array, Array]:
    """(guided_filter of y against x, of x against y) sharing the window sums; lap_masks: the
    Laplacian masks of the two fits."""
    stats = WindowStats(x, y, mask, window)
    return (_fit(stats, x, y, eps, laplacian, lap_masks[0], weighted, 0.0, rmse_floor),
            _fit(stats.swapped(), y, x, eps, laplacian, lap_masks[1], weighted, 0.0, rmse_floor))


# ----------------------------------------------------------------------------------- RI / MLRI

def _gbtf_merge(dif_h: Array, dif_v: Array, radius: int, reg: float, sigma: float) -> Array:
    """GBTF merge of the horizontal and vertical colour differences G - C (step 2 of RI / MLRI)."""
    grad_h = np.abs(_taps(dif_h, _along("h", GRADIENT)))
    grad_v = np.abs(_taps(dif_v, _along("v", GRADIENT)))
    sq = ("box", radius, radius)
    sum_h, sum_v = _box(grad_h, sq), _box(grad_v, sq)
    k = np.exp(-np.arange(5) ** 2 / (2.0 * sigma * sigma))
    k /= k.sum()
    num = den = 0.0
    for (dy, dx), dif, sums in (((0, -1), dif_h, sum_h), ((0, 1), dif_h, sum_h),
                                ((-1, 0), dif_v, sum_v), ((1, 0), dif_v, sum_v)):
        weight = 1.0 / (_taps(sums, {(radius * dy, radius * dx): 1.0}) ** 2 + reg)
        smooth = _taps(dif, {(i * dy, i * dx): k[i] for i in range(5)})   # one-sided, towards the side
        num, den = num + weight * smooth, den + weight
    return num / den


def _directional_differences(raw: Array, sites: Sites, d: str, gf: Callable[..., Array], lo: float,
                             hi: float) -> Array:
    """Colour difference G - C along d at every pixel, by RI of G and C on each line (step 1)."""
    mean_d = _taps(raw, _along(d, NEIGHBOUR_MEAN))
    g_line = np.where(sites.g, raw, mean_d)         # G along d: samples, neighbour means at C sites
    c_line = np.where(sites.g, mean_d, raw)         # C along d: samples, neighbour means at G sites
    g_est = np.zeros_like(raw)
    c_est = np.zeros_like(raw)
    for _, c_sites, g_sites in sites.lines(d):
        t_c = np.clip(gf(g_line, np.where(c_sites, raw, 0.0), c_sites, d), lo, hi)
        t_g = np.clip(gf(c_line, np.where(g_sites, raw, 0.0), g_sites, d), lo, hi)
        r_c = _taps(np.where(c_sites, raw - t_c, 0.0), _along(d, NEIGHBOUR_MEAN))
        r_g = _taps(np.where(g_sites, raw - t_g, 0.0), _along(d, NEIGHBOUR_MEAN))
        c_est += np.where(g_sites, np.clip(t_c + r_c, lo, hi), 0.0)
        g_est += np.where(c_sites, np.clip(t_g + r_g, lo, hi), 0.0)
    return np.where(sites.g, raw - c_est, g_est - raw)


def _rb_by_ri(raw: Array, sites: Sites, green: Array, lo: float, hi: float,
              gf_chroma: Callable[[Array, Array, Array], Array]) -> tuple[Array, Array]:
    """RI / MLRI step 3: R and B by a guided filter against G over their sites, residual bilinear."""
    planes = []
    for c_sites in (sites.r, sites.b):
        tentative = np.clip(gf_chroma(green, np.where(c_sites, raw, 0.0), c_sites), lo, hi)
        planes.append(tentative + _taps(np.where(c_sites, raw - tentative, 0.0), BILINEAR))
    return planes[0], planes[1]


def _ri_like(raw: Array, sites: Sites, lo: float, hi: float, gf_green: Callable[..., Array],
             merge: tuple[int, float, float], gf_chroma: Callable[[Array, Array, Array], Array]
             ) -> tuple[Array, Array, Array]:
    dif_h = _directional_differences(raw, sites, "h", gf_green, lo, hi)
    dif_v = _directional_differences(raw, sites, "v", gf_green, lo, hi)
    green = np.clip(np.where(sites.g, raw, raw + _gbtf_merge(dif_h, dif_v, *merge)), lo, hi)
    red, blue = _rb_by_ri(raw, sites, green, lo, hi, gf_chroma)
    return red, green, blue


MLRI_FLOOR = 1e-5 * 255.0 ** 2
"""MLRI's floor of the mean squared Laplacian of the guide (8-bit units)."""


def demosaic_ri(mosaic: Array, pattern: str = "RGGB", clip: Clip = (0.0, 1.0)) -> Array:
    """RI (Kiku et al. 2013): H x W mosaic -> H x W x 3 (module doc)."""
    def gf_green(guide, target, mask, d):
        return guided_filter(guide, target, mask, ("box", 0, 5) if d == "h" else ("box", 5, 0), eps=1e-10)

    def gf_chroma(guide, target, mask):
        return guided_filter(guide, target, mask, ("box", 5, 5), eps=1e-10)
    return _run(mosaic, pattern, clip,
                lambda raw, sites, lo, hi: _ri_like(raw, sites, lo, hi, gf_green, (2, 1e-32, 1.0), gf_chroma))


def _mlri_chroma_filter(weighted: bool) -> Callable[[Array, Array, Array], Array]:
    def gf_chroma(guide: Array, target: Array, mask: Array) -> Array:
        return guided_filter(guide, target, mask, ("box", 5, 5), eps=0.0, laplacian=LAPLACIAN_2D,
                             lap_mask=mask, weighted=weighted, lap_floor=MLRI_FLOOR)
    return gf_chroma


def demosaic_mlri(mosaic: Array, pattern: str = "RGGB", weighted: bool = False, clip: Clip = (0.0, 1.0)) -> Array:
    """MLRI (Kiku et al. 2014): H x W mosaic -> H x W x 3 (module doc). ``weighted``: the guided
    filters average a, b with ARI's 1 / RMSE weights (the "weighted MLRI" of Kiku et al. 2016)."""
    def gf_green(guide, target, mask, d):
        return guided_filter(guide, target, mask, ("box", 3, 3), eps=0.0, laplacian=_along(d, LAPLACIAN),
                             lap_mask=mask, weighted=weighted, lap_floor=MLRI_FLOOR)

    gf_chroma = _mlri_chroma_filter(weighted)
    return _run(mosaic, pattern, clip,
                lambda raw, sites, lo, hi: _ri_like(raw, sites, lo, hi, gf_green, (1, 1e-2, 1.4), gf_chroma))


# ----------------------------------------------------------------------------------- ARI

def _criterion(err: list[Array], d: str, region: Array | None) -> Array:
    """ARI's iteration criterion c^2 g: c = sum |err|, g = sum |gradient of err along d|, both
    Gaussian-smoothed (5 x 5, sigma 2; normalised over ``region`` when given)."""
    c = sum(np.abs(e) for e in err)
    g = sum(np.abs(_taps(e, _along(d, GRADIENT))) for e in err)
    if region is None:
        c, g = _gauss(c, CRITERION_RADIUS, CRITERION_SIGMA), _gauss(g, CRITERION_RADIUS, CRITERION_SIGMA)
    else:
        norm = _gauss(region.astype(np.float64), CRITERION_RADIUS, CRITERION_SIGMA)
        c = _gauss(c, CRITERION_RADIUS, CRITERION_SIGMA) / norm * region
        g = _gauss(g, CRITERION_RADIUS, CRITERION_SIGMA) / norm * region
    return np.maximum(c * c * g, CRIT_FLOOR)


def _adaptive(estimates: list[tuple[Array, Array]]) -> Array:
    """Weighted mean of (estimate, criterion) pairs, weights 1 / (criterion + CRIT_REG)."""
    num = den = 0.0
    for est, crit in estimates:
        w = 1.0 / (crit + CRIT_REG)
        num, den = num + w * est, den + w
    return num / den


def ari_window(kind: str, d: str, along: int, across: int) -> Window:
    """The window of ARI's guided filters along direction ``d`` ("h", "v", "d1", "d2") with radii
    ``along`` and ``across`` it (pixels for a box, lattice steps for a diagonal window; ``kind`` does
    not change the shape). Shared with the device stage, which derives its margins from it."""
    if d in ("d1", "d2"):
        return ("diag", along, across) if d == "d1" else ("diag", across, along)
    return ("box", across, along) if d == "h" else ("box", along, across)


KINDS = {"ri": (2, 1), "mlri": (4, 0)}
"""ARI G step: initial (along, across) window radii of each guided-filter kind."""


def _ari_green(raw: Array, sites: Sites, iterations: int, kinds: tuple[str, ...]
               ) -> dict[tuple[str, str], tuple[Array, Array, Array]]:
    """ARI step 1 before the merge: {(direction, kind): (G line, chroma line, criterion)}, the lines
    of the iteration each pixel selected (G line: G samples and estimates at the chroma sites;
    chroma line: chroma samples and estimates at the G sites)."""
    out = {}
    for d in ("h", "v"):
        mean_d = _taps(raw, _along(d, NEIGHBOUR_MEAN))
        g0, c0 = np.where(sites.g, raw, mean_d), np.where(sites.g, mean_d, raw)
        for kind in kinds:
            along, across = KINDS[kind]
            g, c = g0, c0
            best, est_g, est_c = np.full(raw.shape, np.inf), g0, c0
            for _ in range(iterations):
                window = ari_window(kind, d, along, across)
                lap = _along(d, LAPLACIAN) if kind == "mlri" else None
                t_g, t_c = np.zeros_like(raw), np.zeros_like(raw)
                for line, c_sites, g_sites in sites.lines(d):
                    fit_g, fit_c = guided_pair(c, g, line, window, lap, (g_sites, c_sites), eps=ARI_EPS,
                                               rmse_floor=ARI_RMSE_FLOOR)
                    t_g += line * fit_g
                    t_c += line * fit_c
                r_g = _taps(np.where(sites.g, raw - t_g, 0.0), _along(d, RESIDUAL_LINEAR))
                r_c = _taps(np.where(sites.c, raw - t_c, 0.0), _along(d, RESIDUAL_LINEAR))
                crit = _criterion([g - t_g, c - t_c], d, None)
                g, c = np.where(sites.g, raw, t_g + r_g), np.where(sites.g, t_c + r_c, raw)
                better = crit < best
                est_g, est_c = np.where(better, g, est_g), np.where(better, c, est_c)
                best = np.where(better, crit, best)
                along, across = along + 1, across + 1
            out[d, kind] = (est_g, est_c, best)
    return out


RB_KINDS = {"ri": (2, 2), "mlri": (2, 0)}
"""ARI steps 2 and 3: initial (along, across) window radii of each guided-filter kind."""


def _ari_chroma(guide: Array, planes: list[tuple[Array, Array, Array]], directions: tuple[str, str],
                mask: Array | None, iterations: int, kinds: tuple[str, ...]) -> list[Array]:
    """ARI steps 2 / 3. ``planes``: (values at the known sites, zero elsewhere; known sites; target
    sites) of R and of B, interpolated jointly (one criterion) along ``directions`` with ``guide``,
    statistics over ``mask`` (None: every pixel). Returns each plane's estimate (valid at its targets)."""
    results: list[list[tuple[Array, Array]]] = [[] for _ in planes]
    for d in directions:
        mean_d = _along(d, NEIGHBOUR_MEAN)
        starts = [np.where(targets, _taps(values, mean_d), values) for values, _, targets in planes]
        for kind in kinds:
            along, across = RB_KINDS[kind]
            lap = _along(d, LAPLACIAN) if kind == "mlri" else None
            cur, ests, best = starts, starts, np.full(guide.shape, np.inf)
            for _ in range(iterations):
                window = ari_window(kind, d, along, across)
                new, errs = [], []
                for (values, known, targets), x in zip(planes, cur):
                    t = guided_filter(guide, x, mask, window, eps=ARI_EPS, laplacian=lap, lap_mask=known,
                                      weighted=True, rmse_floor=ARI_RMSE_FLOOR)
                    residual = _taps(np.where(known, values - t, 0.0), mean_d)
                    new.append(np.where(targets, t + residual, values))
                    errs.append(x - t if mask is None else (x - t) * mask)
                crit = _criterion(errs, d, mask)
                better = crit < best
                ests = [np.where(better, n, e) for n, e in zip(new, ests)]
                best = np.where(better, crit, best)
                cur = new
                along, across = along + 1, across + 1
            for i in range(len(planes)):
                results[i].append((ests[i], best))
    return [_adaptive(r) for r in results]


def _ari_rb(raw: Array, sites: Sites, green: Array, lo: float, hi: float, iterations: int,
            kinds: tuple[str, ...]) -> tuple[Array, Array]:
    """ARI steps 2 and 3: R and B everywhere given the complete G."""
    # step 2: R at B and B at R along the diagonals, statistics over the R and B sites
    r_at_b, b_at_r = _ari_chroma(green, [(np.where(sites.r, raw, 0.0), sites.r, sites.b),
                                         (np.where(sites.b, raw, 0.0), sites.b, sites.r)],
                                 ("d1", "d2"), sites.c, iterations, kinds)
    red = np.where(sites.r, raw, np.where(sites.b, np.clip(r_at_b, lo, hi), 0.0))
    blue = np.where(sites.b, raw, np.where(sites.r, np.clip(b_at_r, lo, hi), 0.0))
    # step 3: R and B at the G sites along rows and columns, statistics over every pixel
    r_at_g, b_at_g = _ari_chroma(green, [(red, sites.c, sites.g), (blue, sites.c, sites.g)],
                                 ("h", "v"), None, iterations, kinds)
    return np.where(sites.g, np.clip(r_at_g, lo, hi), red), np.where(sites.g, np.clip(b_at_g, lo, hi), blue)


GREEN_MERGES = ("criterion", "gbtf", "mean")
CHROMAS = ("ari", "mlri", "mean")


def _merge_green(raw: Array, sites: Sites, lines: dict[tuple[str, str], tuple[Array, Array, Array]],
                 how: str) -> Array:
    """G at the chroma sites from ARI's directional lines: "criterion" (ARI: the four (direction,
    kind) G estimates weighted by 1 / (criterion + 1e-10)), "gbtf" (per direction the kinds weighted
    so, G line and chroma line alike; the two colour differences G - C merged as MLRI does), "mean"
    (the mean of the two)."""
    if how not in GREEN_MERGES:
        raise ValueError(f"green_merge must be one of {GREEN_MERGES}, got {how!r}")
    merged = {}
    if how in ("criterion", "mean"):
        merged["criterion"] = _adaptive([(g, crit) for g, _, crit in lines.values()])
    if how in ("gbtf", "mean"):
        difs = []
        for d in ("h", "v"):
            per_d = [v for (dd, _), v in lines.items() if dd == d]
            g = _adaptive([(gl, crit) for gl, _, crit in per_d])
            c = _adaptive([(cl, crit) for _, cl, crit in per_d])
            difs.append(np.where(sites.g, raw - c, g - raw))
        merged["gbtf"] = raw + _gbtf_merge(difs[0], difs[1], *MLRI_MERGE)
    return merged[how] if how in merged else 0.5 * (merged["criterion"] + merged["gbtf"])


MLRI_MERGE = (1, 1e-2, 1.4)
"""MLRI's GBTF merge: 3 x 3 gradient sums one pixel away, 1 / (D^2 + 1e-2), Gaussian sigma 1.4."""


def demosaic_ari(mosaic: Array, pattern: str = "RGGB", green_iterations: int = 11, chroma_iterations: int = 2,
                 kinds: tuple[str, ...] = ("ri", "mlri"), green_merge: str = "criterion", chroma: str = "ari",
                 clip: Clip = (0.0, 1.0)) -> Array:
    """ARI (Monno et al. 2015/2017): H x W mosaic -> H x W x 3 (module doc). ``kinds``: the guided
    filters whose estimates compete (("ri", "mlri") is ARI; one of them alone is an iterative RI).
    ``green_merge`` (see _merge_green) and ``chroma`` ("ari": ARI's steps 2-3, "mlri": weighted
    MLRI's step 3 on ARI's G, "mean": the mean of both) select the hybrids; the defaults are ARI."""
    if chroma not in CHROMAS:
        raise ValueError(f"chroma must be one of {CHROMAS}, got {chroma!r}")

    def core(raw: Array, sites: Sites, lo: float, hi: float) -> tuple[Array, Array, Array]:
        lines = _ari_green(raw, sites, green_iterations, kinds)
        green = np.where(sites.g, raw, np.clip(_merge_green(raw, sites, lines, green_merge), lo, hi))
        planes = []
        if chroma in ("ari", "mean"):
            planes.append(_ari_rb(raw, sites, green, lo, hi, chroma_iterations, kinds))
        if chroma in ("mlri", "mean"):
            planes.append(_rb_by_ri(raw, sites, green, lo, hi, _mlri_chroma_filter(True)))
        red, blue = (np.mean([p[i] for p in planes], axis=0) for i in range(2))
        return red, green, blue
    return _run(mosaic, pattern, clip, core)


def demosaic_ari_hybrid(mosaic: Array, pattern: str = "RGGB", clip: Clip = (0.0, 1.0)) -> Array:
    """ARI hybrid (this study): G = mean of ARI's merge and the GBTF merge of ARI's directional
    lines, R and B = mean of ARI's and weighted MLRI's chroma on that G (module doc)."""
    return demosaic_ari(mosaic, pattern, green_merge="mean", chroma="mean", clip=clip)
