"""RI Bayer demosaic (one-pass adaptive residual interpolation): the float64 NumPy reference.

The definition of correct for the device stage (stage.py, demosaic_ri.cl). It is the fast member of
the residual-interpolation family studied for issue 27 (docs/RESULTS.md, "A fast residual
interpolation"): the parts of ARI and MLRI that carry their accuracy inside our pipeline, and none
of the iterations, criteria or wide windows that carry their cost.

- G, per direction d (rows, columns): residual interpolation on the lines as in ARI's step 1
  (Monno, Kiku, Tanaka, Okutomi, "Adaptive residual interpolation for color and multispectral
  image demosaicking", Sensors 17(12) 2787, 2017), one iteration, the RI kind only, on a 1-D
  window of 2 LINE_RADIUS + 1 pixels along the line: the G line (G samples, the mean of the two
  neighbours along d at chroma sites) and the chroma line (the converse) are fitted to each other
  by guided filters whose local coefficients are averaged with ARI's 1 / RMSE weights; the
  residual at the samples is interpolated linearly along d and added back. This gives the colour
  difference G - C along d at every pixel.
- G merge: the two colour differences are merged as GBTF does (Pekkucuksen & Altunbasak, ICASSP
  2010) with MLRI's parameters (Kiku, Monno, Tanaka, Okutomi, "Beyond color difference: residual
  interpolation for color image demosaicking", IEEE TIP 25(3), 2016): weights 1 / (D^2 + reg) of the
  3 x 3 sums D of colour-difference gradients one pixel to the W, E, N, S, each side's difference
  smoothed by a one-sided 5-tap Gaussian (sigma 1.4) towards it.
- R and B: MLRI's chroma step (Kiku et al. 2016) with the full G as guide, on a 5 x 5 window
  (CHROMA_RADIUS 2) over the R (B) sites, the slope fitted on the 2-D Laplacians, the coefficients
  averaged with ARI's 1 / RMSE weights (the "weighted MLRI"); the residual at the samples is
  interpolated bilinearly.

Measured samples stay at their sites. Nothing is clipped. Input: a white-balanced Bayer mosaic
window (H x W, linear, nominally [0, 1]) whose pixel (0, 0) is image pixel ``origin``; output: the
window less ``HALO`` on every side, (H - 2 HALO) x (W - 2 HALO) x 3 RGB. The functions are
valid-only (every step shrinks its input by its radius, ``STEP_RADII``), so a tile computes exactly
what the whole image computes. Inside, data are in 8-bit units (x 255) so that the published
constants (ARI's EPS, RMSE_FLOOR, WEIGHT_REG; MLRI's Laplacian floor and merge) apply unchanged.

Example: a flat mosaic stays flat::

    >>> import numpy as np
    >>> out = demosaic(np.full((45, 46), 0.25), "RGGB", (0, 0))
    >>> out.shape, bool(np.allclose(out, 0.25))
    ((7, 8, 3), True)
"""
from __future__ import annotations

import numpy as np

from ..demosaic_ari.reference import EPS, MLRI_FLOOR, MLRI_MERGE, RMSE_FLOOR, SCALE, WEIGHT_REG

Array = np.ndarray

LINE_RADIUS = 3
"""G step: the guided filters' window along the line, 2 LINE_RADIUS + 1 = 7 pixels (ARI's RI window
is 5 x 3 growing with the iterations; 1-D, 7 long scores the same in the pipeline, docs/RESULTS.md)."""
CHROMA_RADIUS = 2
"""R / B step: the guided filter's (2 CHROMA_RADIUS + 1)^2 = 5 x 5 window (MLRI's is 11 x 11; 3 x 3
loses 8 dB, docs/RESULTS.md)."""
MERGE_RADIUS, MERGE_REG, MERGE_SIGMA = MLRI_MERGE
"""GBTF merge: gradient sums over (2 r + 1)^2 pixels, r pixels away; 1 / (D^2 + reg) (8-bit units^2);
one-sided Gaussian of sigma (pixels)."""
CHROMA_NOISE_K = 4.0
"""Noise regularisation of the chroma slope: the mean squared Laplacian of G is floored by adding
CHROMA_NOISE_K times the Laplacian's noise variance (20 sigma^2: taps 4 and four -1 on i.i.d. noise of
variance sigma^2 at the window's mean G), so that where the Laplacian is mostly noise the slope
shrinks towards 0 and the chroma fit towards the window mean. 4 from issue 27's study (first 6 Kodak
and McMaster images, 4 dead-leaves charts, gains 16 and 64: +0.45 to +1.1 dB over no regularisation;
16 gained less, and regularising the G fits the same way lost 0.05-0.2 dB), docs/RESULTS.md."""
SMOOTH_TAPS = 5
"""The one-sided smoothing of each side's colour difference: taps 0..4 towards the side."""

STEP_RADII = {
    "green_fit": 1 + LINE_RADIUS,          # the lines' neighbour means (1), the fit window
    "green_apply": LINE_RADIUS,            # the coefficients' average
    "green_residual": 1,                   # the residual's interpolation
    "green_merge": max(SMOOTH_TAPS - 1, 2 * MERGE_RADIUS + 1),
    "chroma_laplacians": 2,                # the Laplacians of G and of the mosaic
    "chroma_fit": CHROMA_RADIUS,           # the window
    "chroma_apply": CHROMA_RADIUS,         # the coefficients' average
    "complete_rgb": 1,                     # the residual's bilinear interpolation
}
"""Halo of each step (pixels read around an output pixel, along its direction for the G steps)."""
HALO = sum(STEP_RADII.values())
R, G, B = 0, 1, 2


def smooth_taps() -> Array:
    """The one-sided Gaussian's SMOOTH_TAPS weights, offsets 0..4 towards the side, normalised."""
    k = np.exp(-np.arange(SMOOTH_TAPS) ** 2 / (2.0 * MERGE_SIGMA * MERGE_SIGMA))
    return k / k.sum()


def view(a: Array, r: int, dy: int = 0, dx: int = 0) -> Array:
    """``a`` shrunk by r on every side and moved by (dy, dx): view(a, r, dy, dx)[i, j] = a[r + i + dy, r + j + dx]."""
    h, w = a.shape[:2]
    return a[r + dy:h - r + dy, r + dx:w - r + dx]


def weighted_fit(a: Array, mean_x: Array, mean_y: Array, var_x: Array, var_y: Array, cov: Array
                 ) -> tuple[Array, Array, Array]:
    """ARI's weighted fit y ~ a x + b of one window: (a w, b w, w), w = 1 / max(RMSE, RMSE_FLOOR),
    RMSE^2 = a^2 var_x - 2 a cov + var_y (b makes the mean residual zero)."""
    b = mean_y - a * mean_x
    mse = a * a * var_x - 2.0 * a * cov + var_y
    w = 1.0 / np.maximum(np.sqrt(np.maximum(mse, 0.0)), RMSE_FLOOR)
    return a * w, b * w, w


# ----------------------------------------------------------------------------------- G

def line_start(raw: Array, green: Array, d: int) -> tuple[Array, Array]:
    """(g0, c0) along direction d (0: rows, 1: columns); halo 1: the G line (G samples, the mean of
    the two neighbours along d elsewhere) and the chroma line (the converse)."""
    step = (0, 1) if d == 0 else (1, 0)
    mean = 0.5 * (view(raw, 1, -step[0], -step[1]) + view(raw, 1, *step))
    centre, is_g = view(raw, 1), view(green, 1)
    return np.where(is_g, centre, mean), np.where(is_g, mean, centre)


def _along(a: Array, d: int, k: int, r: int) -> Array:
    """a shrunk by r on every side, moved by k along direction d."""
    return view(a, r, 0, k) if d == 0 else view(a, r, k, 0)


def green_fit(g0: Array, c0: Array, d: int) -> Array:
    """The two weighted line fits of every window of 2 LINE_RADIUS + 1 pixels along d; halo
    LINE_RADIUS. Returns 6 planes: (a w, b w, w) of G from the chroma line, then of the chroma line
    from G."""
    r = LINE_RADIUS
    xs = [_along(c0, d, k, r) for k in range(-r, r + 1)]
    ys = [_along(g0, d, k, r) for k in range(-r, r + 1)]
    n = 2 * r + 1
    mx, my = sum(xs) / n, sum(ys) / n
    vx = sum((x - mx) ** 2 for x in xs) / n
    vy = sum((y - my) ** 2 for y in ys) / n
    cov = sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / n
    fit_g = weighted_fit(cov / (vx + EPS), mx, my, vx, vy, cov)
    fit_c = weighted_fit(cov / (vy + EPS), my, mx, vy, vx, cov)
    return np.stack(fit_g + fit_c)


def green_apply(fits: Array, g0: Array, c0: Array, d: int) -> Array:
    """The tentatives along d (2 planes): t_g = A_g c0 + B_g and t_c = A_c g0 + B_c, with A, B the
    1 / RMSE-weighted means of the window coefficients along d (sum a w / (sum w + WEIGHT_REG));
    halo LINE_RADIUS. ``g0``, ``c0`` on the grid of ``fits``."""
    r = LINE_RADIUS

    def tentative(base: int, guide: Array) -> Array:
        aw, bw, w = (sum(_along(fits[base + i], d, k, r) for k in range(-r, r + 1)) for i in range(3))
        total = w + WEIGHT_REG
        return aw / total * view(guide, r) + bw / total

    return np.stack([tentative(0, c0), tentative(3, g0)])


def green_residual(tent: Array, raw: Array, green: Array, d: int) -> Array:
    """The colour difference G - C along d at every pixel; halo 1: the residual raw - t at the
    samples, interpolated along d ([1/2, 0, 1/2]) at the other sites and added to t there.
    ``raw``, ``green`` on the grid of ``tent``."""
    t_g, t_c = tent
    res_g = np.where(green, raw - t_g, 0.0)
    res_c = np.where(green, 0.0, raw - t_c)
    g_est = view(t_g, 1) + 0.5 * (_along(res_g, d, -1, 1) + _along(res_g, d, 1, 1))
    c_est = view(t_c, 1) + 0.5 * (_along(res_c, d, -1, 1) + _along(res_c, d, 1, 1))
    centre, g_site = view(raw, 1), view(green, 1)
    return np.where(g_site, centre - c_est, g_est - centre)


def green_merge(dif_h: Array, dif_v: Array, raw: Array, green: Array) -> Array:
    """G everywhere: the samples at G sites, raw + the GBTF merge of G - C at chroma sites; halo
    STEP_RADII["green_merge"] (4). ``raw``, ``green`` on the grid of the differences."""
    h = STEP_RADII["green_merge"]
    m = MERGE_RADIUS
    grad_h = np.abs(view(dif_h, 1, 0, 1) - view(dif_h, 1, 0, -1))          # margin 1
    grad_v = np.abs(view(dif_v, 1, 1, 0) - view(dif_v, 1, -1, 0))
    box = lambda a: sum(view(a, m, i, j) for i in range(-m, m + 1) for j in range(-m, m + 1))  # noqa: E731
    sum_h, sum_v = box(grad_h), box(grad_v)                                   # margin 1 + m
    k = smooth_taps()
    num = den = 0.0
    for (dy, dx), dif, sums in (((0, -1), dif_h, sum_h), ((0, 1), dif_h, sum_h),
                                ((-1, 0), dif_v, sum_v), ((1, 0), dif_v, sum_v)):
        weight = 1.0 / (view(sums, h - 1 - m, m * dy, m * dx) ** 2 + MERGE_REG)
        smooth = sum(k[i] * view(dif, h, i * dy, i * dx) for i in range(SMOOTH_TAPS))
        num, den = num + weight * smooth, den + weight
    centre = view(raw, h)
    return np.where(view(green, h), centre, centre + num / den)


# ----------------------------------------------------------------------------------- R, B

LAPLACIAN_2D = ((0, 0, 4.0), (-2, 0, -1.0), (2, 0, -1.0), (0, -2, -1.0), (0, 2, -1.0))
"""MLRI's chroma Laplacian (dy, dx, weight): on the R (B) lattice, 2 px apart."""


def laplacian(a: Array) -> Array:
    """The 2-D Laplacian LAPLACIAN_2D, valid part (halo 2)."""
    return sum(w * view(a, 2, dy, dx) for dy, dx, w in LAPLACIAN_2D)


def chroma_laplacians(g: Array, raw: Array) -> Array:
    """The Laplacians (LAPLACIAN_2D) of G and of the mosaic (2 planes); halo 2. ``raw`` on the grid
    of ``g``. On the R (B) sites the mosaic's is the Laplacian of the R (B) samples alone."""
    return np.stack([laplacian(g), laplacian(raw)])


def chroma_fit(g: Array, raw: Array, laps: Array, sites: Array, noise: tuple[float, float] = (0.0, 0.0)) -> Array:
    """Weighted MLRI fits of R (sites == R) and B (sites == B) from G over every 5 x 5 window; halo
    CHROMA_RADIUS. ``g``, ``raw``, ``sites`` on the grid of ``laps``. Returns 6 planes: (a w, b w, w)
    of R, then of B. Slope a = sum(L g L x) / max(sum (L g)^2, n MLRI_FLOOR) over the channel's sites
    of the window (L the Laplacian, n their count), b = mean x - a mean g, weight from the RMSE of
    that fit (weighted_fit). ``noise``: (shot, floor) of G's noise variance shot * level + floor in
    8-bit units (level in 8-bit units too); the mean squared Laplacian of G gains CHROMA_NOISE_K * 20
    times that variance at the window's mean G."""
    r = CHROMA_RADIUS
    offs = [(i, j) for i in range(-r, r + 1) for j in range(-r, r + 1)]
    gs = [view(g, r, i, j) for i, j in offs]
    lgs = [view(laps[0], r, i, j) for i, j in offs]
    lxs = [view(laps[1], r, i, j) for i, j in offs]
    out = []
    for channel in (R, B):
        m = (sites == channel).astype(np.float64)
        ms = [view(m, r, i, j) for i, j in offs]
        xs = [view(m * raw, r, i, j) for i, j in offs]
        n = sum(ms)
        mg, mx = sum(mm * gg for mm, gg in zip(ms, gs)) / n, sum(xs) / n
        vg = sum(mm * (gg - mg) ** 2 for mm, gg in zip(ms, gs)) / n
        vx = sum(mm * (xx - mx) ** 2 for mm, xx in zip(ms, xs)) / n
        cov = sum(mm * (gg - mg) * (xx - mx) for mm, gg, xx in zip(ms, gs, xs)) / n
        s_gx = sum(mm * a * b for mm, a, b in zip(ms, lgs, lxs))
        s_gg = sum(mm * a * a for mm, a in zip(ms, lgs))
        noise_var = noise[0] * np.maximum(mg, 0.0) + noise[1]
        a = (s_gx / n) / (np.maximum(s_gg / n, MLRI_FLOOR) + CHROMA_NOISE_K * 20.0 * noise_var)
        out.extend(weighted_fit(a, mg, mx, vg, vx, cov))
    return np.stack(out)


def chroma_apply(fits: Array, g: Array) -> Array:
    """Tentative R and B, A g + B with A, B the 1 / RMSE-weighted window means of the coefficients;
    halo CHROMA_RADIUS. ``g`` on the grid of ``fits``. Returns 2 planes."""
    r = CHROMA_RADIUS
    offs = [(i, j) for i in range(-r, r + 1) for j in range(-r, r + 1)]
    out = []
    for base in (0, 3):
        aw, bw, w = (sum(view(fits[base + p], r, i, j) for i, j in offs) for p in range(3))
        total = w + WEIGHT_REG
        out.append(aw / total * view(g, r) + bw / total)
    return np.stack(out)


def complete_rgb(tent: Array, g: Array, raw: Array, sites: Array) -> Array:
    """R, G, B: the samples at their sites, elsewhere the tentative plus the bilinear interpolation
    of the residual raw - tentative at the channel's sites; halo 1. Inputs on one grid; returns
    (h - 2) x (w - 2) x 3."""
    bilinear = ((0, 0, 1.0), (0, -1, 0.5), (0, 1, 0.5), (-1, 0, 0.5), (1, 0, 0.5),
                (-1, -1, 0.25), (-1, 1, 0.25), (1, -1, 0.25), (1, 1, 0.25))
    planes = []
    for t, channel in ((tent[0], R), (tent[1], B)):
        res = np.where(sites == channel, raw - t, 0.0)
        planes.append(view(t, 1) + sum(w * view(res, 1, dy, dx) for dy, dx, w in bilinear))
    return np.stack([planes[0], view(g, 1), planes[1]], axis=-1)


# ----------------------------------------------------------------------------------- chain

def demosaic(mosaic: Array, pattern: str | Array, origin: tuple[int, int] = (0, 0),
             noise: tuple[float, float] = (0.0, 0.0)) -> Array:
    """H x W Bayer mosaic -> (H - 2 HALO) x (W - 2 HALO) x 3 (module doc). ``pattern``: a phase name
    ("RGGB", ...) or a 2 x 2 array of channel indices (0 R, 1 G, 2 B) of image pixels (0..1, 0..1);
    ``origin``: the image position of mosaic pixel (0, 0); ``noise``: (shot, floor) of the G samples'
    noise variance shot * level + floor in the mosaic's units (clisp.sim.noise.ChannelNoise; zeros:
    noiseless, no regularisation)."""
    if isinstance(pattern, str):
        names = pattern.upper()
        pattern = np.array([["RGB".index(c) for c in names[:2]], ["RGB".index(c) for c in names[2:]]])
    raw = np.asarray(mosaic, dtype=np.float64) * SCALE
    h, w = raw.shape
    ys, xs = (np.arange(h) + origin[0]) % 2, (np.arange(w) + origin[1]) % 2
    sites = np.asarray(pattern)[ys[:, None], xs[None, :]]
    is_g = sites == G
    difs = []
    r1, r2 = STEP_RADII["green_fit"], STEP_RADII["green_apply"]
    for d in (0, 1):
        g0, c0 = line_start(raw, is_g, d)
        fits = green_fit(g0, c0, d)
        tent = green_apply(fits, view(g0, LINE_RADIUS), view(c0, LINE_RADIUS), d)
        difs.append(green_residual(tent, view(raw, r1 + r2), view(is_g, r1 + r2), d))
    m = r1 + r2 + STEP_RADII["green_residual"]
    g = green_merge(difs[0], difs[1], view(raw, m), view(is_g, m))
    m += STEP_RADII["green_merge"]
    laps = chroma_laplacians(g, view(raw, m))
    c = STEP_RADII["chroma_laplacians"]
    noise8 = (noise[0] * SCALE, noise[1] * SCALE * SCALE)         # variance in 8-bit units at 8-bit levels
    fits = chroma_fit(view(g, c), view(raw, m + c), laps, view(sites, m + c), noise8)
    c += STEP_RADII["chroma_fit"]
    tent = chroma_apply(fits, view(g, c))
    c += STEP_RADII["chroma_apply"]
    rgb = complete_rgb(tent, view(g, c), view(raw, m + c), view(sites, m + c))
    return rgb / SCALE
