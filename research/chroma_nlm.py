"""A chroma denoiser of another class than clisp's bilateral one: luminance-guided non-local means on
patches, in the same multiresolution frame (issue 45, item 2; study, NumPy float64, no OpenCL).

clisp's chroma denoiser (clisp.modules.chroma_denoise) weighs each neighbour q of a pixel p by the
differences of the two *pixels* (a joint bilateral: luminance Y and chroma c). Non-local means
(A. Buades, B. Coll, J.-M. Morel, "A non-local algorithm for image denoising", CVPR 2005) weighs
them by the differences of the two *patches* around them, so a neighbour counts when its
surroundings look alike, not only its value: where an edge runs through the search window, the
pixels beyond it on the same side of a similar structure still count, and noise in a single pixel
does not decide the weight. Here the patch distance is taken on the luminance guide and the chroma
together (the guide has the most signal; the paper's argument for a luminance-guided denoiser), so
the class is the luminance-guided patch-based one the issue asks for beside the bilateral.

Everything but the filter is the bilateral denoiser's, so the two differ in their class only: the
same chroma space (clisp.modules.chroma_denoise.stage.space_for_cfa), the same noise table
measured through the demosaic (calibrate_noise), the same decimated Haar pyramid with BayesShrink on
the detail subbands, and at every level j = J .. 0 the approximation's chroma filtered, then::

    nlm(p) = sum_q w(p, q) c(q) / sum_q w(p, q)       over |q - p|_inf <= radius (level-j px)
    w(p, q) = exp(-|p - q|^2 / 2 sd^2 - D_Y(p, q) - D_c(p, q))
    D_Y     = max(P[(Y(p+t) - Y(q+t))^2] - 2 vY(p), 0) / (2 k_Y^2 vY(p))
    D_c     = sum_k max(P[(c_k(p+t) - c_k(q+t))^2] - 2 vk(p), 0) / (2 k_c^2 s_k^2 vk(p)) / rank

P[.] the mean over the (2 f + 1)^2 patch t (``patch``), v the table's noise variances at the level
and the local Y (the expected squared difference of two noisy samples, 2 v, is taken off, as
Buades et al. do), s_k the space's strengths, rank the chroma planes' rank (2 for the three LMS-style
planes, which share two noise sources). ``sigma_d`` None: no spatial term (plain NLM).

The images are processed whole (mirror padding at the image's edges, as the tiler's padding); it
tiles like the bilateral (the same pyramid and halos plus f per level) but no device port exists:
measured first (docs/RESULTS.md, issue 45).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clisp.modules.chroma_denoise.stage import (ChromaSpace, NoiseTable, _affine_var, bayes_shrink, chroma_merge,
                                                chroma_split, haar_pyramid, haar_synthesize)


@dataclass(frozen=True)
class NLMParams:
    """Parameters of :func:`chroma_nlm` (the bilateral's where they mean the same)."""

    levels: int = 3
    """Haar levels J (as ChromaDenoiseParams.levels)."""
    radius: int = 3
    """Search radius at every level (level-j px; the bilateral's window radius)."""
    patch: int = 1
    """Patch radius f of the chroma distance: (2 f + 1)^2 pixels of the level."""
    patch_luma: int | None = None
    """Patch radius of the luminance distance (None: ``patch``)."""
    sigma_d: float | None = None
    """Spatial sigma (level-j px), None: no spatial weight."""
    k_chroma: float = 2.0
    """Chroma range: k_c times the plane's noise std (times its strength)."""
    k_luma: float = 2.0
    """Luminance range: k_Y times the Y noise std; 0 drops the guide."""
    shrink_radius: int = 2
    """BayesShrink's local window radius (as the bilateral's)."""
    strengths: tuple[float, ...] | None = None
    """Per-plane strengths (None: the space's)."""


def _pad(a: np.ndarray, r: int) -> np.ndarray:
    return np.pad(a, [(0, 0)] * (a.ndim - 2) + [(r, r), (r, r)], mode="reflect")


def _box(a: np.ndarray, f: int) -> np.ndarray:
    """Mean over the (2 f + 1)^2 window, valid region (shrinks by f on every side)."""
    if f == 0:
        return a
    c = np.cumsum(np.cumsum(np.pad(a, [(0, 0)] * (a.ndim - 2) + [(1, 0), (1, 0)]), axis=-1), axis=-2)
    k = 2 * f + 1
    s = c[..., k:, k:] - c[..., :-k, k:] - c[..., k:, :-k] + c[..., :-k, :-k]
    return s / (k * k)


def joint_nlm(c: np.ndarray, y: np.ndarray, var_y: np.ndarray, var_c: np.ndarray, prm: NLMParams,
              strengths: np.ndarray, rank: int) -> np.ndarray:
    """Chroma planes (n, h, w) with guide y (h, w) -> (n, h, w) by the weights of the module doc;
    var_y (2,), var_c (n, 2): affine noise variances at this level. Mirror-padded."""
    r, f = prm.radius, max(prm.patch, prm.patch if prm.patch_luma is None else prm.patch_luma)
    fc, fy = prm.patch, prm.patch if prm.patch_luma is None else prm.patch_luma
    m = r + f
    cp, yp = _pad(c, m), _pad(y, m)
    h, w = y.shape
    floor = 1e-12
    vy = np.maximum(_affine_var(var_y, y), floor)
    vc = np.stack([np.maximum(_affine_var(var_c[k], y), floor) for k in range(c.shape[0])])
    inv_y = 0.0 if prm.k_luma == 0 else 1.0 / (2.0 * prm.k_luma ** 2 * vy)
    inv_c = 1.0 / (2.0 * prm.k_chroma ** 2 * strengths[:, None, None] ** 2 * vc) / max(rank, 1)
    centre_c = cp[:, r:r + h + 2 * f, r:r + w + 2 * f]
    centre_y = yp[r:r + h + 2 * f, r:r + w + 2 * f]
    num = np.zeros_like(c)
    den = np.zeros((h, w))
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            qc = cp[:, r + dy:r + dy + h + 2 * f, r + dx:r + dx + w + 2 * f]
            qy = yp[r + dy:r + dy + h + 2 * f, r + dx:r + dx + w + 2 * f]
            e = np.zeros((h, w))
            if prm.sigma_d is not None:
                e += (dy * dy + dx * dx) / (2.0 * prm.sigma_d ** 2)
            if prm.k_luma > 0:
                e += np.maximum(_box((qy - centre_y) ** 2, fy)[f - fy:f - fy + h, f - fy:f - fy + w]
                                - 2.0 * vy, 0.0) * inv_y
            dc = _box((qc - centre_c) ** 2, fc)[:, f - fc:f - fc + h, f - fc:f - fc + w]
            e += np.sum(np.maximum(dc - 2.0 * vc, 0.0) * inv_c, axis=0)
            wgt = np.exp(-e)
            num += wgt * qc[:, f:f + h, f:f + w]
            den += wgt
    return num / den


def chroma_nlm(cam: np.ndarray, space: ChromaSpace, table: NoiseTable, prm: NLMParams = NLMParams()) -> np.ndarray:
    """White-balanced camera image (H x W x 3) -> linear sRGB (H x W x 3), chroma denoised by the
    pyramid of the module doc. ``table``: the noise table of ``space`` after the raw's demosaic
    (clisp.modules.chroma_denoise.stage.calibrate_noise, with prm.levels levels)."""
    h0, w0 = cam.shape[:2]
    align = 2 ** prm.levels
    ph, pw = -h0 % align, -w0 % align
    x = np.pad(np.moveaxis(np.asarray(cam, dtype=np.float64), -1, 0), ((0, 0), (0, ph), (0, pw)), mode="reflect")
    strengths = np.asarray(space.strengths if prm.strengths is None else prm.strengths, dtype=np.float64)
    rank = int(np.linalg.matrix_rank(space.chroma, tol=1e-9))
    a, ys, details = haar_pyramid(chroma_split(x, space.split_matrix), prm.levels)
    c = a[1:]
    rw = prm.shrink_radius
    for j in range(prm.levels, -1, -1):
        c = joint_nlm(c, ys[j], table.approx[j, 0], table.approx[j, 1:], prm, strengths, rank)
        if j == 0:
            break
        d = details[j]
        shrunk = bayes_shrink(_pad(d, rw), _pad(ys[j], rw), table.detail[j], strengths, rw)
        c = haar_synthesize(c, shrunk)
    rgb = chroma_merge(ys[0], c, space.merge_matrix)
    return np.moveaxis(rgb, 0, -1)[:h0, :w0]
