"""GBTF, gradient-based threshold-free demosaicking (I. Pekkucuksen and Y. Altunbasak, "Gradient
based threshold free color filter array interpolation", IEEE ICIP 2010, 137-140), in plain NumPy.

Written from the paper's description, vectorised over the whole image, float64. ``c`` is the
mosaic, X stands for the R or B of the current row / column, eps = 1e-10 keeps divisions finite.

1. Directional colour differences at every pixel. Hamilton-Adams 1-D interpolation along the row,
   F_H = c * [-1, 2, 2, 2, -1] / 4 (neighbour mean plus half the second difference of the centre
   colour), and along the column, F_V. Differences G - X: D_H = c - F_H at green sites,
   F_H - c at R / B sites (likewise D_V).
2. Gradients of the differences: grad_H = |D_H[0, +1] - D_H[0, -1]|, grad_V = |D_V[+1, 0] - D_V[-1, 0]|.
3. Directional weights at R / B sites: w_N = 1 / (eps + sum of grad_V over the 5 x 5 window
   rows -4..0, columns -2..2)^2 (the window "north" of the pixel, including it); w_S, w_W, w_E
   likewise (w_W, w_E from grad_H over columns -4..0 / 0..4, rows -2..2).
4. Green at R / B sites: per direction a smoothed difference, Delta_N = sum_k f_k D_V[-k, 0] for
   k = 0..4 (``taps`` f, from the pixel outwards), Delta_S, Delta_W, Delta_E likewise; the fused
   Delta = (w_N Delta_N + w_S Delta_S + w_W Delta_W + w_E Delta_E) / (w_N + w_S + w_W + w_E);
   G = X + Delta.
5. Red at blue sites and blue at red sites: the G - X difference, known at X's own sites, is
   filtered by the paper's 7 x 7 kernel (10/32 on the 4 diagonal neighbours, -1/32 on the 8 samples
   at (+-1, +-3) and (+-3, +-1)) and subtracted from G.
6. Red and blue at green sites: the G - X difference of the 4 cardinal neighbours (X is known at
   all R / B sites after step 5), weighted by the directional weights of step 3 computed at the
   green site (``rb_at_green="weighted"``, the default) or averaged (``"mean"``); X = G - that
   difference. On the classic protocol (tools/demosaic_study.py) the weighted form is +0.06 dB on
   Kodak and +0.23 dB on McMaster.

The smoothing ``taps`` f of step 4 are the one detail written from memory of the paper rather
than checked against it: PAPER_TAPS = [0.56, 0.35, 0.08, 0.01, 0]; SLOW_TAPS is the alternative
measured beside it.

Measured samples are kept exactly. Units and shapes: ``mosaic`` is H x W, any float (linear or
encoded), one Bayer phase ``pattern`` (RGGB, GRBG, GBRG, BGGR); the result is H x W x 3 float64.

Halo: green at an R / B site reads D_V up to 4 rows away for Delta_N and grad_V up to 4 rows
(and 2 columns) away for w_N, grad_V reads D_V 1 px further, D_V reads c 2 px further: 4 + 1 + 2
= 7 px (Chebyshev). Red / blue at a blue / red site read G 3 px away (the 7 x 7 kernel): 10; at a
green site, the difference 1 px away, itself from G 3 px further: HALO = 11 (the weights at a
green site read only 7 px). Checked by tests/test_bayer_candidates.py. Borders: the mosaic is
mirror-padded keeping the CFA phase (``bayer_numpy.rggb_window``).
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from research.demosaic.bayer_numpy import at, box_sum, crop, rggb_masks, rggb_window

EPS = 1e-10
HALO = 11
MARGIN = HALO + 3          # even (keeps the CFA phase) and more than the halo

HAMILTON_ADAMS = np.array([-1.0, 2.0, 2.0, 2.0, -1.0]) / 4.0
"""1-D interpolation of the missing colour along a row or column: neighbour mean + half the
second difference of the centre colour."""

PAPER_TAPS = np.array([0.56, 0.35, 0.08, 0.01, 0.0])
"""Smoothing of the directional differences in step 4 (from the pixel outwards), as we recall the
paper's; not verified against the authors' code."""

SLOW_TAPS = np.array([26.0, 24.0, 21.0, 17.0, 12.0]) / 100.0
"""A slower-decaying alternative (about a Gaussian of sigma 3 px), the one used by the public Python
reimplementation of GBTF in the IPOL study of residual interpolation (Jin, Guo, Facciolo and Morel,
2020); measured here: Kodak +0.6 dB, McMaster -1 dB against PAPER_TAPS."""

RB_KERNEL_TAPS = [((dy, dx), 10.0 / 32.0) for dy in (-1, 1) for dx in (-1, 1)] + \
    [((dy, dx), -1.0 / 32.0) for dy, dx in [(-1, -3), (-1, 3), (1, -3), (1, 3), (-3, -1), (-3, 1), (3, -1), (3, 1)]]
"""The paper's 7 x 7 filter of the G - X difference for X at the sites diagonal to its own."""


def directional_differences(c: np.ndarray, green: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Step 1: (D_H, D_V) = G - X from Hamilton-Adams interpolation along rows / columns."""
    f_h = ndimage.correlate1d(c, HAMILTON_ADAMS, axis=1, mode="wrap")
    f_v = ndimage.correlate1d(c, HAMILTON_ADAMS, axis=0, mode="wrap")
    sign = np.where(green, 1.0, -1.0)
    return sign * (c - f_h), sign * (c - f_v)


def directional_weights(d_h: np.ndarray, d_v: np.ndarray) -> dict[str, np.ndarray]:
    """Steps 2-3: w_N, w_S, w_W, w_E at every pixel."""
    grad_h = np.abs(at(d_h, 0, 1) - at(d_h, 0, -1))
    grad_v = np.abs(at(d_v, 1, 0) - at(d_v, -1, 0))
    box_h = box_sum(grad_h, 5)
    box_v = box_sum(grad_v, 5)
    # the 5 x 5 window north of the pixel (rows -4..0) is the centred window of the pixel 2 rows up
    return {"N": 1.0 / (EPS + at(box_v, -2, 0)) ** 2, "S": 1.0 / (EPS + at(box_v, 2, 0)) ** 2,
            "W": 1.0 / (EPS + at(box_h, 0, -2)) ** 2, "E": 1.0 / (EPS + at(box_h, 0, 2)) ** 2}


def green_estimates(c: np.ndarray, d_h: np.ndarray, d_v: np.ndarray, taps: np.ndarray) -> dict[str, np.ndarray]:
    """Step 4's per-direction green at every pixel: c + the difference smoothed from the pixel
    outwards (meaningful at R / B sites, where c is X)."""
    return {
        "N": c + sum(f * at(d_v, -k, 0) for k, f in enumerate(taps)),
        "S": c + sum(f * at(d_v, k, 0) for k, f in enumerate(taps)),
        "W": c + sum(f * at(d_h, 0, -k) for k, f in enumerate(taps)),
        "E": c + sum(f * at(d_h, 0, k) for k, f in enumerate(taps)),
    }


def fuse(weights: dict[str, np.ndarray], estimates: dict[str, np.ndarray]) -> np.ndarray:
    total = sum(weights[k] for k in estimates)
    return sum(weights[k] * estimates[k] for k in estimates) / total


def gbtf_rggb(c: np.ndarray, taps: np.ndarray = PAPER_TAPS, rb_at_green: str = "weighted") -> np.ndarray:
    """GBTF on an RGGB window (pixel (0, 0) red), H x W -> H x W x 3; the outer HALO px are invalid."""
    red, green, blue = rggb_masks(c.shape)
    d_h, d_v = directional_differences(c, green)
    weights = directional_weights(d_h, d_v)
    g = np.where(green, c, fuse(weights, green_estimates(c, d_h, d_v, taps)))

    # G - R known at red sites, G - B at blue sites: fill the diagonal sites, then the green ones
    planes = []
    for own, other in ((red, blue), (blue, red)):
        diff = np.where(own, g - c, 0.0)
        diagonal = sum(w * at(diff, dy, dx) for (dy, dx), w in RB_KERNEL_TAPS)
        diff = np.where(other, diagonal, diff)
        neighbours = {"N": at(diff, -1, 0), "S": at(diff, 1, 0), "W": at(diff, 0, -1), "E": at(diff, 0, 1)}
        if rb_at_green == "mean":
            at_green = 0.25 * sum(neighbours.values())
        elif rb_at_green == "weighted":
            at_green = fuse(weights, neighbours)
        else:
            raise ValueError(f"rb_at_green must be 'mean' or 'weighted', got {rb_at_green!r}")
        diff = np.where(green, at_green, diff)
        planes.append(np.where(own, c, g - diff))
    return np.stack([planes[0], g, planes[1]], axis=-1)


def demosaic_gbtf(mosaic: np.ndarray, pattern: str = "RGGB", taps: np.ndarray = PAPER_TAPS,
                  rb_at_green: str = "weighted") -> np.ndarray:
    """GBTF demosaic of an H x W Bayer ``mosaic`` (phase ``pattern``) -> H x W x 3 float64 RGB."""
    window, origin = rggb_window(mosaic, pattern, MARGIN)
    return crop(gbtf_rggb(window, np.asarray(taps, dtype=np.float64), rb_at_green), origin, np.shape(mosaic))
