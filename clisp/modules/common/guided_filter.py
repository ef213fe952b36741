"""The masked guided filter of both LMS demosaics: NumPy reference and host side of clisp/modules/common/guided_filter.cl.

He et al.'s guided filter of a target v against a guide I with box windows of radius r, the statistics
taken only over the pixels of one CFA channel (chi = 1 there, 0 elsewhere; or every pixel), box = mean
over the (2r+1)^2 window (``guided_filter_spec`` writes it out)::

    n = box(chi); muI = box(chi I)/n; muv = box(chi v)/n
    a = (box(chi I v)/n - muI muv) / (box(chi I^2)/n - muI^2 + eps); b = muv - a muI
    q = box(a) I + box(b)        eps = eps0 + shot max(level, 0) + floor, level = muI or muv

eps0 is the regulariser (signal units^2), shot and floor the affine noise variance of the level's
quantity. Computed separably, one function and one kernel per step (same names): ``gf_row_moments``
(masked moments summed along rows, the guide centred on the row's centre value), ``gf_coefficients``
(column sums moved to the output pixel's centre value: exact algebra that keeps the variance free of
float32 cancellation; then a, b), ``box_rows`` (row sums of a, b) and ``gf_apply`` (their column sums,
applied). The output is the window shrunk by 2r on every side.

Users: ``demosaic_lms`` (the hybrid, step C: S over the S sites against lum, level muS) and
``demosaic_lms_guided`` (M at S, chroma and S passes). On the device the CFA membership is a closed form
(``clisp.modules.common.lms.LATTICE``), the CFA phase folded into the image coordinates by ``lattice_shift``.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from ...errors import ClispError
from ...engine.runtime import DeviceImage, Runtime
from .lms import LATTICE, correlate_valid, valid

MASK_ALL, MASK_M, MASK_S, MASK_PAIR = 0, 1, 2, 3
"""``mask`` of the host functions (the kernels' GF_MASK): statistics over every pixel, the M sites or
the S sites; MASK_PAIR: the M and the S fit in one pass (``enqueue_guided_pair``)."""
i32, f32 = np.int32, np.float32
"""Kernel argument types."""


# ---------------------------------------------------------------------------------- reference
# Float64 windows; ``mask`` (bool, the window's shape) selects the pixels of the statistics, None: all.

def guided_filter_spec(guide: np.ndarray, v: np.ndarray, mask: np.ndarray | None, r: int, eps0: float,
                       shot: float, floor: float, level_from_guide: bool) -> np.ndarray:
    """The filter written with window means (module doc); guide, v, mask on one H x W window, output
    (H - 4r) x (W - 4r). :func:`guided_filter` computes the same separably."""
    chi = np.ones(guide.shape) if mask is None else mask.astype(np.float64)

    def box(a: np.ndarray) -> np.ndarray:
        return correlate_valid(a, np.full((2 * r + 1, 2 * r + 1), 1.0 / (2 * r + 1) ** 2))

    n = box(chi)
    mu_i, mu_v = box(chi * guide) / n, box(chi * v) / n
    cov = box(chi * guide * v) / n - mu_i * mu_v
    var = box(chi * guide * guide) / n - mu_i * mu_i
    level = mu_i if level_from_guide else mu_v
    a = cov / (var + eps0 + shot * np.maximum(level, 0.0) + floor)
    b = mu_v - a * mu_i
    return box(a) * valid(guide, 2 * r) + box(b)


def gf_row_moments(guide: np.ndarray, v: np.ndarray, mask: np.ndarray | None, r: int) -> np.ndarray:
    """Row sums over x - r .. x + r of the masked moments, the guide centred on the row centre value
    c = guide(y, x): (n, sum d, sum d^2, sum v, sum d v), d = guide - c; H x (W - 2r) x 5 for H x W
    inputs. ``mask`` None: every pixel."""
    c = guide[:, r:guide.shape[1] - r]
    out = np.zeros(c.shape + (5,))
    for k in range(-r, r + 1):
        chi = (np.ones_like(c) if mask is None else mask[:, r + k:mask.shape[1] - r + k].astype(np.float64))
        d = chi * (guide[:, r + k:guide.shape[1] - r + k] - c)
        s = chi * v[:, r + k:v.shape[1] - r + k]
        out += np.stack([chi, d, d * d, s, d * s], axis=-1)
    return out


def gf_coefficients(rows: np.ndarray, guide: np.ndarray, r: int, eps0: float, shot: float, floor: float,
                    level_from_guide: bool) -> tuple[np.ndarray, np.ndarray]:
    """Column sums over y - r .. y + r of the row moments, each moved from its row centre c_j to the
    output's c = guide(y, x) (exact algebra); ``guide`` holds the row centres (rows.shape[:2]).
    a = cov / (var + eps), b = mu_v - a mu_I, eps = eps0 + shot max(level, 0) + floor, level = mu_I
    (``level_from_guide``) or mu_v. Returns a, b, (H - 2r) x W' for rows H x W' x 5."""
    h = rows.shape[0] - 2 * r
    c = guide[r:r + h]
    n = s1 = s2 = sv = sdv = 0.0
    for j in range(-r, r + 1):
        nj, s1j, s2j, svj, sdvj = (rows[r + j:r + j + h, :, q] for q in range(5))
        delta = guide[r + j:r + j + h] - c
        n = n + nj
        s1 = s1 + s1j + nj * delta
        s2 = s2 + s2j + 2.0 * delta * s1j + nj * delta * delta
        sv = sv + svj
        sdv = sdv + sdvj + delta * svj
    mean_d, mu_v = s1 / n, sv / n
    var = s2 / n - mean_d * mean_d
    cov = sdv / n - mean_d * mu_v
    mu_i = c + mean_d
    level = mu_i if level_from_guide else mu_v
    a = cov / (var + eps0 + shot * np.maximum(level, 0.0) + floor)
    return a, mu_v - a * mu_i


def box_rows(x: np.ndarray, r: int) -> np.ndarray:
    """Sum over x - r .. x + r (along the second axis): H x W -> H x (W - 2r); x may have a trailing
    channel axis."""
    return sum(x[:, r + k:x.shape[1] - r + k] for k in range(-r, r + 1))


def gf_apply(guide: np.ndarray, rows_a: np.ndarray, rows_b: np.ndarray, r: int) -> np.ndarray:
    """Mean a and b over the (2r+1)^2 windows covering the pixel (column sums of the row sums, H x W ->
    (H - 2r) x W), applied: q = mean(a) I + mean(b); ``guide`` at the output pixels."""
    def cols(x: np.ndarray) -> np.ndarray:
        return sum(x[r + k:x.shape[0] - r + k] for k in range(-r, r + 1)) / (2 * r + 1) ** 2
    return cols(rows_a) * guide + cols(rows_b)


def guided_filter(guide: np.ndarray, v: np.ndarray, mask: np.ndarray | None, r: int, eps0: float,
                  shot: float, floor: float, level_from_guide: bool) -> np.ndarray:
    """The four GF steps in a row: guide and v (and mask) on one H x W window; output (H - 4r) x (W - 4r)."""
    rows = gf_row_moments(guide, v, mask, r)
    a, b = gf_coefficients(rows, guide[:, r:guide.shape[1] - r], r, eps0, shot, floor, level_from_guide)
    return gf_apply(valid(guide, 2 * r), box_rows(a, r), box_rows(b, r), r)


# ---------------------------------------------------------------------------------- OpenCL
# The filter runs on an "own" window (h, w); the guide (plane g_plane) and v live on device images whose
# pixel (g_off, g_off), resp. (v_off, v_off), is own-window pixel (0, 0). ``origin``: image coordinates
# of own-window pixel (0, 0); ``shift``: clisp.modules.common.lms.lattice_shift of the CFA.

def _plane_base(image: DeviceImage, plane: int) -> np.int32:
    """Element offset of plane ``plane`` of a planar device image."""
    return i32(plane * image.height * image.width)


GF_STRIP = 8
"""Output rows per work-item of gf_ab_strip (GF_STRIP): each strip recomputes 2r rows of sums along
x, so longer strips save work but cost registers."""


@lru_cache(maxsize=64)
def chi_rows(w: int, ox: int, mask: int, rows: int, r: int = 0) -> np.ndarray:
    """The mask table of gf_ab_strip, 2 (4 + rows) x w float32: row t < 4 + rows, column x = 1 where
    image pixel (iy, x + ox) with iy & 3 == t & 3 is in ``mask`` (LATTICE's closed form, ox with the
    CFA shift folded in), else 0; row 4 + rows + t: the sum of row t over x - r .. x + r (a row window's
    count). A strip starting at image row iy0 reads rows (iy0 & 3) + i, i < rows: a distinct row for
    each of its rows (with 4 rows read over and over, PoCL did not vectorise). MASK_ALL: one unread
    element."""
    if mask == MASK_ALL:
        return np.zeros(1, np.float32)
    iy, ix = np.mgrid[0:4 + rows, ox - r:ox + w + r]
    at_l = (ix + iy + LATTICE["L_PAR"]) % 2 == 0
    at_s = ((iy + LATTICE["S_Y"]) % 2 == 0) & ((ix - iy + LATTICE["S_D"]) % 4 == 0)
    chi = (at_s if mask == MASK_S else ~at_s & ~at_l).astype(np.float32)
    count = sum(chi[:, r + k:chi.shape[1] - r + k] for k in range(-r, r + 1))
    table = np.concatenate([chi[:, r:chi.shape[1] - r], count]).astype(np.float32)
    table.flags.writeable = False          # cached (every tile of a run asks for the same tables)
    return table


APPLY_STRIP = 16
"""Output rows per work-item of gf_apply_strip (GF_APPLY_STRIP; two sums per row: registers allow
longer strips)."""


def _strip(h: int, strip: int = GF_STRIP) -> int:
    """Strip height for an output h rows high: ``strip``, or the largest power of two <= h below it."""
    return min(strip, 1 << (max(h, 1).bit_length() - 1))


def enqueue_guided_filter(rt: Runtime, own: tuple[int, int], origin: tuple[int, int], shift: tuple[int, int],
                          guide: DeviceImage, g_off: int, v: DeviceImage, v_off: int, r: int, mask: int,
                          eps0: float, noise: tuple[float, float], level_from_guide: bool, g_plane: int = 0,
                          out: tuple[DeviceImage, int] | None = None) -> DeviceImage:
    """The guided filter of v against plane ``g_plane`` of guide over the own window, statistics over
    ``mask`` (MASK_ALL, MASK_M, MASK_S); eps = eps0 + noise[0] max(level, 0) + noise[1]. Output: the own
    window shrunk by 2r, (h - 4r) x (w - 4r), a new image or plane out[1] of out[0]. Two fused kernels
    (gf_ab_strip: row moments and coefficients; gf_apply_strip: box sums of a, b and q), the same sums
    as the NumPy steps; the a, b planes come from the pool and go back to it."""
    return _enqueue_fits(rt, own, origin, shift, guide, g_off, v, v_off, r, mask, eps0, [noise], level_from_guide,
                         g_plane, [out])[0]


def enqueue_guided_pair(rt: Runtime, own: tuple[int, int], origin: tuple[int, int], shift: tuple[int, int],
                        guide: DeviceImage, g_off: int, v: DeviceImage, v_off: int, r: int, eps0: float,
                        noise_m: tuple[float, float], noise_s: tuple[float, float],
                        level_from_guide: bool) -> tuple[DeviceImage, DeviceImage]:
    """The two guided filters of v against guide over the M sites and over the S sites (eps noise terms
    noise_m, noise_s), as two enqueue_guided_filter calls with MASK_M and MASK_S, in one pass of each
    kernel (GF_MASK 3): guide and target are read once. Returns (M fit, S fit), new images."""
    fm, fs = _enqueue_fits(rt, own, origin, shift, guide, g_off, v, v_off, r, MASK_PAIR, eps0, [noise_m, noise_s],
                           level_from_guide, 0, [None, None])
    return fm, fs


def _enqueue_fits(rt: Runtime, own: tuple[int, int], origin: tuple[int, int], shift: tuple[int, int],
                  guide: DeviceImage, g_off: int, v: DeviceImage, v_off: int, r: int, mask: int, eps0: float,
                  noises: list[tuple[float, float]], level_from_guide: bool, g_plane: int,
                  outs: list[tuple[DeviceImage, int] | None]) -> list[DeviceImage]:
    """gf_ab_strip then gf_apply_strip for one fit (mask MASK_ALL, MASK_M, MASK_S) or the M and S pair
    (MASK_PAIR: noises and outs for M, then S)."""
    h, w = own
    ab_h, ab_w = h - 2 * r, w - 2 * r
    fits = len(noises)
    ab = rt.acquire(2 * fits, ab_h, ab_w)
    q_h, q_w = ab_h - 2 * r, ab_w - 2 * r
    strip, apply_strip = _strip(ab_h), _strip(q_h, APPLY_STRIP)
    ox = origin[1] + shift[1]
    masks = [MASK_M, MASK_S] if mask == MASK_PAIR else [mask]
    chi = rt.constant(np.concatenate([chi_rows(w, ox, m, strip + 2 * r, r).ravel() for m in masks]))
    defines = {**LATTICE, "GF_R": int(r), "GF_MASK": int(mask), "GF_LEVEL_GUIDE": int(level_from_guide),
               "GF_STRIP": strip, "GF_APPLY_STRIP": apply_strip}      # one program for both kernels
    n2 = noises[-1]
    rt.launch_named("guided_filter", "gf_ab_strip", ab_w, -(-ab_h // strip), dict(
        guide=guide, v=v, ab=ab, chi_rows=chi, chi_w=w, g_base=_plane_base(guide, g_plane), g_w=guide.width,
        g_off=g_off, v_w=v.width, v_off=v_off, out_w=ab_w, out_h=ab_h, oy=origin[0] + shift[0], ox=ox, eps0=eps0,
        shot=noises[0][0], floor_=noises[0][1], shot2=n2[0], floor2=n2[1]), defines, inward=True)
    dsts = []
    for out in outs:
        dst, plane = (rt.acquire(1, q_h, q_w), 0) if out is None else out
        if (dst.height, dst.width) != (q_h, q_w) or not 0 <= plane < dst.channels:
            raise ClispError(f"guided filter output: plane {plane} of {dst.channels} x {dst.height} x {dst.width} "
                             f"cannot take {q_h} x {q_w}")
        dsts.append((dst, plane))
    (d1, p1), (d2, p2) = dsts[0], dsts[-1]
    rt.launch_named("guided_filter", "gf_apply_strip", q_w, -(-q_h // apply_strip), dict(
        ab=ab, guide=guide, dst=d1, dst2=d2, ab_w=ab_w, ab_h=ab_h, g_base=_plane_base(guide, g_plane),
        g_w=guide.width, g_off=g_off, out_w=q_w, out_h=q_h, d_base=_plane_base(d1, p1), d_base2=_plane_base(d2, p2)),
        defines, inward=True)
    rt.release(ab)
    return [d for d, _ in dsts]
