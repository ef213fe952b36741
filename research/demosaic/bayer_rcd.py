"""RCD, Ratio Corrected Demosaicing (Luis Sanz Rodríguez, release 2.3, 2017), in plain NumPy.

The algorithm is the one of darktable's default demosaic, RawTherapee and librtprocess
(https://github.com/LuisSR/RCD-Demosaicing), written here from its description, vectorised over
the whole image, float64. Notation: ``c`` is the mosaic, ``c[dy, dx]`` its sample at offset
(dy, dx) from the pixel being computed, N/S/W/E/NW/... the neighbours; eps = 1e-5.

1. Vertical / horizontal discrimination, at every pixel. A 7-tap high-pass
   [1, -3, -1, 6, -1, -3, 1] along the column (resp. the row), squared, summed over the pixel and
   its two neighbours along the same column (row): V_stat, H_stat (floored at eps^2).
   VH_dir = V_stat / (V_stat + H_stat): 1 = structure across rows (interpolate horizontally).
2. Low-pass ``lpf`` = c + (N + S + W + E) / 2 + (NW + NE + SW + SE) / 4 (a 3 x 3 binomial,
   unnormalised: a local mean that mixes all three colours in the same proportions at every
   R / B site).
3. Green at R and B sites. Per cardinal direction, a gradient (N shown)
   N_grad = eps + |c[-1,0] - c[1,0]| + |c[0,0] - c[-2,0]| + |c[-1,0] - c[-3,0]| + |c[-2,0] - c[-4,0]|
   and a ratio-corrected estimate N_est = c[-1,0] (1 + (lpf - lpf[-2,0]) / (eps + lpf + lpf[-2,0])),
   i.e. the neighbouring green scaled by the ratio of the low-pass at the pixel to the low-pass
   two pixels away. V_est = (S_grad N_est + N_grad S_est) / (N_grad + S_grad), H_est likewise;
   G = VH_disc H_est + (1 - VH_disc) V_est, where VH_disc is VH_dir or, when the mean of VH_dir
   over the 4 diagonal neighbours is further from 0.5 (more decided), that mean.
4. Red at blue sites and blue at red sites. P (NW-SE) / Q (NE-SW) discrimination PQ_dir from the
   same squared high-pass along the diagonals, summed over the pixel and its two neighbours along
   the diagonal; PQ_disc refined from the 4 diagonal neighbours as in step 3. Per diagonal,
   gradient NW_grad = eps + |X[-1,-1] - X[1,1]| + |X[-1,-1] - X[-3,-3]| + |G - G[-2,-2]| (X the
   colour being interpolated, known at the diagonal neighbours) and colour difference
   NW_est = X[-1,-1] - G[-1,-1]; P_est = (NW_grad SE_est + SE_grad NW_est) / (NW_grad + SE_grad),
   Q_est likewise; X = G + (1 - PQ_disc) P_est + PQ_disc Q_est.
5. Red and blue at green sites: the cardinal version of step 4 with VH_disc: gradient
   N_grad = eps + |G - G[-2,0]| + |X[-1,0] - X[1,0]| + |X[-1,0] - X[-3,0]|, colour difference
   N_est = X[-1,0] - G[-1,0] (X is now known at all R and B sites), X = G + VH_disc H_est +
   (1 - VH_disc) V_est.

Measured samples are kept exactly (R at R sites, G at G sites, B at B sites). With ``clip`` (the
default, as in the release-2.2 code) the interpolated greens and the reds / blues of step 4 are
clipped to [0, 1] before they are used further; pass ``clip=False`` for data not normalised to a
white level of 1.

Units and shapes: ``mosaic`` is H x W, any float (the eps constants assume white = 1), one Bayer
phase ``pattern`` (RGGB, GRBG, GBRG, BGGR); the result is H x W x 3 float64 (R, G, B).

Halo: an output pixel depends on mosaic pixels up to HALO = 10 px away (Chebyshev): R / B at a
green site read X 3 px away, which at an R / B site was interpolated from G 2 px further (diagonal),
which reads c 4 px away and VH_disc, whose diagonal refinement (1 px) of VH_dir (high-pass 3 px,
summed over 1 px) reaches 5 px: 3 + 2 + 5 = 10 (checked by tests/test_bayer_candidates.py).
Borders: the mosaic is mirror-padded by HALO + 2 px keeping the CFA phase
(``bayer_numpy.rggb_window``).
"""
from __future__ import annotations

import numpy as np

from research.demosaic.bayer_numpy import at, crop, rggb_masks, rggb_window

EPS = 1e-5
EPS_SQ = 1e-10
HALO = 10
MARGIN = HALO + 2          # even (keeps the CFA phase) and more than the halo


def high_pass_energy(c: np.ndarray, dy: int, dx: int) -> np.ndarray:
    """Squared 7-tap high-pass [1, -3, -1, 6, -1, -3, 1] along the direction (dy, dx), summed over
    the pixel and its two neighbours along that direction, floored at EPS_SQ."""
    def tap(k: int) -> np.ndarray:
        return at(c, k * dy, k * dx)
    hp = (tap(-3) - tap(-1) - tap(1) + tap(3)) - 3.0 * (tap(-2) + tap(2)) + 6.0 * c
    hp2 = hp * hp
    return np.maximum(EPS_SQ, at(hp2, -dy, -dx) + hp2 + at(hp2, dy, dx))


def refine_discrimination(direction: np.ndarray) -> np.ndarray:
    """The direction weight, or the mean of its 4 diagonal neighbours where that is more decided."""
    neighbours = 0.25 * (at(direction, -1, -1) + at(direction, -1, 1)
                         + at(direction, 1, -1) + at(direction, 1, 1))
    return np.where(np.abs(0.5 - direction) < np.abs(0.5 - neighbours), neighbours, direction)


def pairwise(grad_a: np.ndarray, est_a: np.ndarray, grad_b: np.ndarray, est_b: np.ndarray) -> np.ndarray:
    """Estimates from two opposite sides, each weighted by the OTHER side's gradient."""
    return (grad_b * est_a + grad_a * est_b) / (grad_a + grad_b)


CARDINAL = {"N": (-1, 0), "S": (1, 0), "W": (0, -1), "E": (0, 1)}


def cardinal_gradients(c: np.ndarray) -> dict[str, np.ndarray]:
    """Step 3's gradient towards each cardinal neighbour (N shown):
    eps + |c[-1,0] - c[1,0]| + |c - c[-2,0]| + |c[-1,0] - c[-3,0]| + |c[-2,0] - c[-4,0]|."""
    gradients = {}
    for name, (dy, dx) in CARDINAL.items():
        def tap(k: int) -> np.ndarray:
            return at(c, k * dy, k * dx)
        gradients[name] = (EPS + np.abs(tap(1) - tap(-1)) + np.abs(c - tap(2))
                           + np.abs(tap(1) - tap(3)) + np.abs(tap(2) - tap(4)))
    return gradients


def low_pass(c: np.ndarray) -> np.ndarray:
    """Step 2: c + (N + S + W + E) / 2 + (NW + NE + SW + SE) / 4 (3 x 3 binomial times 4)."""
    return c + 0.5 * (at(c, -1, 0) + at(c, 1, 0) + at(c, 0, -1) + at(c, 0, 1)) \
        + 0.25 * (at(c, -1, -1) + at(c, -1, 1) + at(c, 1, -1) + at(c, 1, 1))


def ratio_estimates(c: np.ndarray) -> dict[str, np.ndarray]:
    """Step 3's ratio-corrected green from each cardinal neighbour (N shown):
    c[-1,0] (1 + (lpf - lpf[-2,0]) / (eps + lpf + lpf[-2,0]))."""
    lpf = low_pass(c)
    estimates = {}
    for name, (dy, dx) in CARDINAL.items():
        lpf2 = at(lpf, 2 * dy, 2 * dx)
        estimates[name] = at(c, dy, dx) * (1.0 + (lpf - lpf2) / (EPS + lpf + lpf2))
    return estimates


def fuse_cardinal(estimates: dict[str, np.ndarray], gradients: dict[str, np.ndarray],
                  vh_disc: np.ndarray) -> np.ndarray:
    """Step 3's fusion: opposite estimates weighted by each other's gradient, then V / H by VH_disc."""
    v_est = pairwise(gradients["N"], estimates["N"], gradients["S"], estimates["S"])
    h_est = pairwise(gradients["W"], estimates["W"], gradients["E"], estimates["E"])
    return vh_disc * h_est + (1.0 - vh_disc) * v_est


def rcd_green(c: np.ndarray, vh_disc: np.ndarray) -> np.ndarray:
    """Steps 2-3: green estimate at every pixel (meaningful at R / B sites)."""
    return fuse_cardinal(ratio_estimates(c), cardinal_gradients(c), vh_disc)


def discriminations(c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Steps 1 and 4.1: (VH_disc, PQ_disc), both refined from their 4 diagonal neighbours."""
    v_stat = high_pass_energy(c, 1, 0)
    h_stat = high_pass_energy(c, 0, 1)
    p_stat = high_pass_energy(c, 1, 1)
    q_stat = high_pass_energy(c, 1, -1)
    return (refine_discrimination(v_stat / (v_stat + h_stat)),
            refine_discrimination(p_stat / (p_stat + q_stat)))


def rcd_diagonal(x: np.ndarray, g: np.ndarray, pq_disc: np.ndarray) -> np.ndarray:
    """Step 4: colour X at the sites diagonal to its own (X known at the 4 diagonal neighbours)."""
    estimates = {}
    gradients = {}
    for name, (dy, dx) in {"NW": (-1, -1), "SE": (1, 1), "NE": (-1, 1), "SW": (1, -1)}.items():
        x1 = at(x, dy, dx)
        gradients[name] = (EPS + np.abs(x1 - at(x, -dy, -dx)) + np.abs(x1 - at(x, 3 * dy, 3 * dx))
                           + np.abs(g - at(g, 2 * dy, 2 * dx)))
        estimates[name] = x1 - at(g, dy, dx)
    p_est = pairwise(gradients["NW"], estimates["NW"], gradients["SE"], estimates["SE"])
    q_est = pairwise(gradients["NE"], estimates["NE"], gradients["SW"], estimates["SW"])
    return g + (1.0 - pq_disc) * p_est + pq_disc * q_est


def rcd_cardinal(x: np.ndarray, g: np.ndarray, vh_disc: np.ndarray) -> np.ndarray:
    """Step 5: colour X at green sites (X known at the 4 cardinal neighbours)."""
    estimates = {}
    gradients = {}
    for name, (dy, dx) in CARDINAL.items():
        x1 = at(x, dy, dx)
        gradients[name] = (EPS + np.abs(g - at(g, 2 * dy, 2 * dx)) + np.abs(x1 - at(x, -dy, -dx))
                           + np.abs(x1 - at(x, 3 * dy, 3 * dx)))
        estimates[name] = x1 - at(g, dy, dx)
    v_est = pairwise(gradients["N"], estimates["N"], gradients["S"], estimates["S"])
    h_est = pairwise(gradients["W"], estimates["W"], gradients["E"], estimates["E"])
    return g + vh_disc * h_est + (1.0 - vh_disc) * v_est


def rcd_red_blue(c: np.ndarray, g: np.ndarray, vh_disc: np.ndarray, pq_disc: np.ndarray,
                 clip: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Steps 4-5 on an RGGB window with green ``g`` complete: (R, B) at every pixel."""
    red, green, blue = rggb_masks(c.shape)
    limit = (lambda v: np.clip(v, 0.0, 1.0)) if clip else (lambda v: v)
    r = np.where(red, c, 0.0)
    b = np.where(blue, c, 0.0)
    r = np.where(blue, limit(rcd_diagonal(r, g, pq_disc)), r)
    b = np.where(red, limit(rcd_diagonal(b, g, pq_disc)), b)
    r = np.where(green, rcd_cardinal(r, g, vh_disc), r)
    b = np.where(green, rcd_cardinal(b, g, vh_disc), b)
    return r, b


def rcd_rggb(c: np.ndarray, clip: bool = True) -> np.ndarray:
    """RCD on an RGGB window (pixel (0, 0) red), H x W -> H x W x 3; the outer HALO px are invalid."""
    green = rggb_masks(c.shape)[1]
    vh_disc, pq_disc = discriminations(c)
    g = rcd_green(c, vh_disc)
    g = np.where(green, c, np.clip(g, 0.0, 1.0) if clip else g)
    r, b = rcd_red_blue(c, g, vh_disc, pq_disc, clip)
    return np.stack([r, g, b], axis=-1)


def demosaic_rcd(mosaic: np.ndarray, pattern: str = "RGGB", clip: bool = True) -> np.ndarray:
    """RCD demosaic of an H x W Bayer ``mosaic`` (phase ``pattern``) -> H x W x 3 float64 RGB."""
    window, origin = rggb_window(mosaic, pattern, MARGIN)
    return crop(rcd_rggb(window, clip=clip), origin, np.shape(mosaic))
