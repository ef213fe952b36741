"""LMS demosaic by residual interpolation (issue 12 study): NumPy float64 reference, no OpenCL.

Input: the normalised, white-balanced LMS mosaic (H x W, float, white ~ 1; black-subtracted) and its
:class:`clisp.cfa.CFA` (kind "lms": L on one quincunx, M on the other but for S at 1/4 of its sites,
S on the 45-degree lattice of spacing 2 sqrt 2). Output: H x W x 3 float64 white-balanced L, M, S in
the mosaic's units (measured samples kept at their own sites), for paper eq. (1) downstream.

Why residual interpolation. Every row and column of the LMS CFA alternates L and M (or S in place of
M): the L/M problem is Bayer's G / chroma problem along the lines, with both colours dense. RI
(Kiku et al. 2013), MLRI (2014) and ARI (Monno et al. 2015/2017; clisp.modules.demosaic_ari.reference) estimate a
colour difference far better than colour-difference interpolation because they interpolate the
residual of a local linear fit (smooth) instead of the difference itself; on the LMS CFA the
difference L - M reaches red amplified 8.6x (R = 0.86 Y + 8.6 C + 0.14 S, C = (L - M) / 2).

Method (all filters from clisp.modules.demosaic_ari.reference, 8-bit working units: data x 255 inside). Default
``lm="2d"``; ``lm="ari"`` is the directional alternative, measured worse (below):

1. L and M, ``lm="2d"`` (default; ``_lm_2d``): guide Y0 = 9 x 9 diamond half-band of the mosaic (M at
   S sites first the mean of the four diagonal M). ``iterations`` (11) times: L and M each by RI
   against the guide (masked guided filter over the channel's own sites, ARI's 1 / RMSE-weighted
   coefficients, box radius ``radius2d`` (2) + iteration), residual at the samples interpolated over
   the four axial neighbours (L: always L; M: normalised over the M among them, at S sites the four
   diagonal M), added back; the next guide is (L + M) / 2. ``select``: ARI's criterion in 2-D
   (5 x 5 Gaussian of |previous - tentative| squared times that of its x and y gradients) picks per
   pixel the iteration kept.
1'. ``lm="ari"`` (``_lm_lines``): ARI step 1 on the L/M lines. Per direction d in {h, v} and kind k
   in {RI, MLRI}: the L line is the L samples with the mean of the two L neighbours along d
   elsewhere; the M line is the M samples with the mean of the M neighbours along d elsewhere (at an
   L site next to an S site, the one M neighbour; at an S site, the M two pixels away along d).
   ``iterations`` times each line is re-estimated from the other by RI along d (ARI's windows,
   weights and criterion, residual [1/2, 1, 1/2] along d, normalised over the M samples for M).
2. Merge of 1' only: ``merge="criterion"`` (ARI): the four (d, k) lines weighted by
   1 / (criterion + 1e-10); ``"gbtf"``: the per-direction differences L - M merged by GBTF's
   gradient weights; ``"mean"``: both averaged.
3. M at S sites from the S sample (``s_detail``, off by default: +1.4 dB on kodim01, -0.8 on
   McMaster, -1.6 on dead leaves, where M and S are not correlated): the S sample's detail is M's detail (M and S
   cones correlate, and on the lattice of S sites M is otherwise only interpolated): M = S + RI of
   (M - S) where (M - S) at the S sites is fitted by a guided filter of M (over the M sites) and of
   S (over the S sites) against the completed L (``s_radius``), i.e. M_S = S + (fit_M - fit_S);
   L at S sites then follows as M_S + D.
4. S by RI over the S lattice: a masked guided filter of the S samples against the completed M
   (``s_guide``: "m" or "y" = (L + M) / 2; box window radius ``s_radius``; weighted ARI
   coefficients; MLRI slope on the S lattice's Laplacian (``S_LAPLACIAN``) when ``s_mlri``), the
   residual at the S sites interpolated by the S lattice's bilinear tent (normalised) and added.

Borders: the mosaic and its channel map are mirror-extended together by PAD (16) px (the 4 x 4 CFA
is not mirror-symmetric, so the masks come from the reflected channel map, not from the CFA's
period); every filter is masked or a fixed-tap correlation, so the extension is consistent.

Optional: ``c_smooth`` = (radius, eps) re-estimates C = (L - M) / 2 by a guided filter against
Y = (L + M) / 2 (a chroma low-pass; helps Kodak, hurts dead leaves).

No noise model and no alias suppression: this is the noiseless study. Measured inside the LMS
pipeline (tools/bench_demosaic_quality.py --lms-numpy, first 6 Kodak / 6 McMaster / 4 dead leaves,
noiseless Airy; dB): default guided 37.03 / 35.76 / 21.60, this 34.83 / 36.59 / 24.78, Bayer ARI
41.02 / 40.19 / 29.71; neutral zone plate 12.06 (default 43.06). docs/RESULTS.md, "LMS demosaic by
residual interpolation (issue 12, study)". Speed: about 1.5 s for 768 x 512 on one core.
"""
from __future__ import annotations

import numpy as np

from clisp.cfa import CFA
from clisp.modules.demosaic_ari.reference import (LAPLACIAN, MLRI_MERGE, NEIGHBOUR_MEAN, RESIDUAL_LINEAR, _adaptive, _along,
                       _criterion, _gbtf_merge, _taps, guided_filter, guided_pair)
from clisp.modules.common.lms import check_lms_structure

SCALE = 255.0
"""Working scale (8-bit code values, the units of bayer_ri's constants)."""
PAD = 16
"""Mirror extension on every side (px)."""
KINDS = {"ri": (2, 1), "mlri": (4, 0)}
"""Step 1: initial (along, across) window radii of each guided-filter kind (ARI's)."""
MERGES = ("criterion", "gbtf", "mean")
S_LAPLACIAN = {(0, 0): 4.0, (2, 2): -1.0, (2, -2): -1.0, (-2, 2): -1.0, (-2, -2): -1.0}
"""2-D Laplacian on the S lattice (its four nearest sites)."""
Array = np.ndarray


def s_tent() -> dict[tuple[int, int], float]:
    """Bilinear tent of the S lattice (basis (2, 2), (2, -2)) as taps: (1 - |dy + dx| / 4)+ (1 - |dy - dx| / 4)+."""
    taps = {}
    for dy in range(-3, 4):
        for dx in range(-3, 4):
            w = max(0.0, 1 - abs(dy + dx) / 4.0) * max(0.0, 1 - abs(dy - dx) / 4.0)
            if w > 0:
                taps[dy, dx] = w
    return taps


def _masked_interp(values: Array, mask: Array, taps: dict, fallback: dict | None = None) -> Array:
    """sum w v mask / sum w mask over ``taps`` (a normalised interpolation of the samples in mask);
    where no tap hits a sample, the same over ``fallback`` (0 if none)."""
    mf = mask.astype(np.float64)
    num, den = _taps(values * mf, taps), _taps(mf, taps)
    out = np.where(den > 1e-12, num / np.maximum(den, 1e-12), 0.0)
    if fallback is not None:
        num2, den2 = _taps(values * mf, fallback), _taps(mf, fallback)
        out = np.where(den > 1e-12, out, num2 / np.maximum(den2, 1e-12))
    return out


def _lm_lines(raw: Array, l: Array, m: Array, iterations: int, kinds: tuple[str, ...]
              ) -> dict[tuple[str, str], tuple[Array, Array, Array]]:
    """Step 1: {(d, kind): (L line, M line, criterion)} of the iteration each pixel kept."""
    out = {}
    for d in ("h", "v"):
        near, far = _along(d, NEIGHBOUR_MEAN), _along(d, [0.5, 0, 0, 0, 0.5])
        l0 = np.where(l, raw, _masked_interp(raw, l, near))
        m0 = np.where(m, raw, _masked_interp(raw, m, near, far))
        res_l = _along(d, RESIDUAL_LINEAR)
        for kind in kinds:
            along, across = KINDS[kind]
            lap = _along(d, LAPLACIAN) if kind == "mlri" else None
            lcur, mcur = l0, m0
            best, est_l, est_m = np.full(raw.shape, np.inf), l0, m0
            for _ in range(iterations):
                window = ("box", across, along) if d == "h" else ("box", along, across)
                t_l, t_m = guided_pair(mcur, lcur, None, window, lap, (l, m))
                r_l = _taps(np.where(l, raw - t_l, 0.0), res_l)
                r_m = _masked_interp(np.where(m, raw - t_m, 0.0), m, res_l, far)
                crit = _criterion([lcur - t_l, mcur - t_m], d, None)
                lcur, mcur = np.where(l, raw, t_l + r_l), np.where(m, raw, t_m + r_m)
                better = crit < best
                est_l, est_m = np.where(better, lcur, est_l), np.where(better, mcur, est_m)
                best = np.where(better, crit, best)
                along, across = along + 1, across + 1
            out[d, kind] = (est_l, est_m, best)
    return out


QUINCUNX = {(0, 1): 0.25, (0, -1): 0.25, (1, 0): 0.25, (-1, 0): 0.25}
DIAGONAL = {(1, 1): 0.25, (1, -1): 0.25, (-1, 1): 0.25, (-1, -1): 0.25}


def _criterion_2d(err: list[Array]) -> Array:
    """ARI's criterion c^2 g in 2-D: c = sum |err|, g = sum of |[-1, 0, 1]| gradients of err along x
    and y, both 5 x 5 Gaussian-smoothed (sigma 2)."""
    from clisp.modules.demosaic_ari.reference import GRADIENT, _gauss
    c = sum(np.abs(e) for e in err)
    g = sum(np.abs(_taps(e, _along(d, GRADIENT))) for e in err for d in ("h", "v"))
    return _gauss(c, 2, 2.0) ** 2 * _gauss(g, 2, 2.0)


def _lm_2d(raw: Array, l: Array, m: Array, s: Array, iterations: int, radius: int, weighted: bool,
           select: bool = False) -> tuple[Array, Array]:
    """Step 1, 2-D variant: guide Y0 = diamond half-band of the mosaic (M at S sites first the mean of
    its four diagonal M neighbours); per iteration L and M by RI against the guide (masked guided
    filter over their own sites, box radius ``radius`` growing by 1, residual interpolated over the
    four axial neighbours, at S sites over the four diagonal M), guide = (L + M) / 2 of the result."""
    from scipy.ndimage import correlate
    from clisp.modules.common.lms import diamond_halfband
    filled = np.where(s, _taps(raw, DIAGONAL), raw)
    guide = correlate(filled, diamond_halfband(4), mode="mirror")
    lp, mp = guide, guide
    best, est_l, est_m = np.full(raw.shape, np.inf), lp, mp
    for it in range(iterations):
        window = ("box", radius + it, radius + it)
        t_l = guided_filter(guide, np.where(l, raw, 0.0), l, window, weighted=weighted)
        t_m = guided_filter(guide, np.where(m, raw, 0.0), m, window, weighted=weighted)
        crit = _criterion_2d([lp - t_l, mp - t_m])
        lp = np.where(l, raw, t_l + _masked_interp(np.where(l, raw - t_l, 0.0), l, QUINCUNX))
        mp = np.where(m, raw, t_m + _masked_interp(np.where(m, raw - t_m, 0.0), m, QUINCUNX, DIAGONAL))
        guide = 0.5 * (lp + mp)
        if select and it > 0:           # iteration 0's "previous estimate" is the guide itself: no criterion
            better = crit < best
            est_l, est_m = np.where(better, lp, est_l), np.where(better, mp, est_m)
            best = np.where(better, crit, best)
    return (est_l, est_m) if select else (lp, mp)


def _merge(raw: Array, l: Array, m: Array, lines: dict, how: str) -> tuple[Array, Array]:
    """Step 2: L and M everywhere (samples kept)."""
    results = []
    if how in ("criterion", "mean"):
        lm = _adaptive([(a, c) for a, _, c in lines.values()])
        mm = _adaptive([(b, c) for _, b, c in lines.values()])
        results.append((lm, mm))
    if how in ("gbtf", "mean"):
        difs, mlev = [], []
        for d in ("h", "v"):
            per_d = [v for (dd, _), v in lines.items() if dd == d]
            ld = _adaptive([(a, c) for a, _, c in per_d])
            md = _adaptive([(b, c) for _, b, c in per_d])
            difs.append(ld - md)
            mlev.append((md, per_d))
        dif = _gbtf_merge(difs[0], difs[1], *MLRI_MERGE)
        crit_m = _adaptive([(b, c) for b, c in ((mlev[0][0], sum(v[2] for v in mlev[0][1])),
                                                (mlev[1][0], sum(v[2] for v in mlev[1][1])))])
        mm = np.where(m, raw, np.where(l, raw - dif, crit_m))
        lm = np.where(l, raw, mm + dif)
        results.append((lm, mm))
    lo = np.mean([r[0] for r in results], axis=0)
    mo = np.mean([r[1] for r in results], axis=0)
    return np.where(l, raw, lo), np.where(m, raw, mo)


def demosaic_lms_ri(mosaic: Array, cfa: CFA, iterations: int = 11, kinds: tuple[str, ...] = ("ri", "mlri"),
                    merge: str = "criterion", s_detail: bool = False, s_radius: int = 4, s_guide: str = "m",
                    s_mlri: bool = False, lm: str = "2d", radius2d: int = 2, weighted2d: bool = True,
                    c_smooth: tuple[int, float] | None = None, select: bool = True) -> Array:
    """LMS RI demosaic (module doc): H x W white-balanced LMS mosaic -> H x W x 3 L, M, S (float64)."""
    if merge not in MERGES:
        raise ValueError(f"merge must be one of {MERGES}, got {merge!r}")
    ch_l, ch_m, ch_s = check_lms_structure(cfa, "LMS RI demosaic")
    x = np.asarray(mosaic, dtype=np.float64)
    h, w = x.shape
    ch = np.pad(cfa.channel_map(h, w), PAD, mode="reflect")
    raw = np.pad(x, PAD, mode="reflect") * SCALE
    l, m, s = ch == ch_l, ch == ch_m, ch == ch_s
    if lm == "ari":
        lp, mp = _merge(raw, l, m, _lm_lines(raw, l, m, iterations, kinds), merge)
    else:
        lp, mp = _lm_2d(raw, l, m, s, iterations, radius2d, weighted2d, select)
    if c_smooth is not None:
        # chroma C = (L - M) / 2 re-estimated by a guided filter against Y (box radius, eps in 8-bit units^2)
        y, c = 0.5 * (lp + mp), 0.5 * (lp - mp)
        c = guided_filter(y, c, None, ("box", c_smooth[0], c_smooth[0]), eps=c_smooth[1])
        lp, mp = np.where(l, raw, np.where(m, raw + 2 * c, y + c)), np.where(m, raw, np.where(l, raw - 2 * c, y - c))
    if s_detail:
        # M at S from the S sample: M = S + (fit of M - fit of S) against L, both fits over their own sites
        fit_m = guided_filter(lp, np.where(m, raw, 0.0), m, ("box", s_radius, s_radius), weighted=True)
        fit_s = guided_filter(lp, np.where(s, raw, 0.0), s, ("box", s_radius, s_radius), weighted=True)
        m_at_s = raw + fit_m - fit_s
        dif = lp - mp
        mp = np.where(s, m_at_s, mp)
        lp = np.where(s, m_at_s + dif, lp)
    guide = mp if s_guide == "m" else 0.5 * (lp + mp)
    window = ("box", s_radius, s_radius)
    if s_mlri:
        tent_s = guided_filter(guide, np.where(s, raw, 0.0), s, window, eps=0.0, laplacian=S_LAPLACIAN,
                               lap_mask=s, weighted=True, lap_floor=1e-5 * SCALE ** 2)
    else:
        tent_s = guided_filter(guide, np.where(s, raw, 0.0), s, window, weighted=True)
    sp = np.where(s, raw, tent_s + _masked_interp(np.where(s, raw - tent_s, 0.0), s, s_tent()))
    out = np.stack([lp, mp, sp], axis=-1)[PAD:PAD + h, PAD:PAD + w]
    return out / SCALE


def guided_reference(mosaic: Array, cfa: CFA) -> Array:
    """The default LMS demosaic's NumPy reference (DemosaicLMSGuided, noiseless, neutral of P_LMS) on
    a whole H x W mosaic, mirror-padded by its halo rounded up to the CFA period: H x W x 3."""
    from clisp.sim.colorimetry import P_LMS
    from clisp.modules.demosaic_lms_guided.stage import DemosaicLMSGuided, neutral_of
    stage = DemosaicLMSGuided(cfa, neutral=neutral_of(P_LMS))
    pad = -(-stage.halo // 4) * 4
    out = stage.reference(np.pad(np.asarray(mosaic, np.float64), pad, mode="reflect"), (-pad, -pad))
    off = pad - stage.halo
    return out[off:off + mosaic.shape[0], off:off + mosaic.shape[1]].astype(np.float64)


def demosaic_lms_ri_mix(mosaic: Array, cfa: CFA, weight: float = 0.5) -> Array:
    """(1 - weight) x the default guided demosaic (noiseless reference) + weight x demosaic_lms_ri:
    the two estimators' errors are partly independent (RI wins on saturated colour edges, the
    default's low-passed chroma on low-chroma texture)."""
    return (1.0 - weight) * guided_reference(mosaic, cfa) + weight * demosaic_lms_ri(mosaic, cfa)
