"""Guided LMS demosaic: guided-filter residuals for M at S sites, guided chroma, and a noise-driven
LMMSE luminance blend (issue 3; default candidate for LMS raws).

Why: with paper eq. (1), R = 4.73 L - 3.87 M + 0.14 S = 0.86 Y + 8.6 C + 0.14 S (Y = (L+M)/2, C = (L-M)/2),
so every L/M separation error reaches red amplified 8.6x. The hybrid of Fig. 5 (``demosaic_lms``)
low-passes the luminance and keeps the chroma within a 9 x 9 binomial; this stage instead keeps every
measured L/M sample, estimates the chroma by a guided filter (edges of the chroma follow edges of the
luminance), estimates M at S sites from the S sample itself, and falls back to the low-passed
luminance only where the noise model says the detail is noise. Input: the white-balanced LMS mosaic p
(H x W); output L, M, S, (H - 2 halo) x (W - 2 halo) x 3. ``mod`` = +1 at L sites, -1 elsewhere (the
(pi, pi) carrier of C). GF = He et al.'s guided filter with box windows of radius r (mean of the
per-window coefficients a, b over the windows that cover a pixel), statistics over the sites of one
CFA channel where "masked"; it lives in ``guided_filter`` (reference and host) and
clisp/modules/common/guided_filter.cl, shared with the hybrid.

Steps (one function per kernel below, the GF's in ``guided_filter``; radius = halo the step consumes)::

    l_guide           r 4   I0 = L at L sites, 2 (D * L-samples) elsewhere (D: 9 x 9 diamond half-band)
    M at S, pass 1    r 8   GF of the M samples and of the S samples against I0 (radius r1 = 3):
                            Mfit, Sfit; at S sites M = Mfit + gamma (S - Sfit)
                            (gamma = 1 noiseless: the S sample's own detail is M's detail)
    chroma, pass 1    r 10  ylp = D * m; cin = B5 * ((m - ylp) mod); c = GF(ylp, cin) (radius 2),
                            y = m - c mod (every sample kept: y = L - c at L, M + c at M sites)
    M at S, pass 2    r 6   as pass 1 with guide y (radius r2 = 2), fused with an edge-directed
                            estimate yd - c where its prediction error is small (below)
    chroma, pass 2    r 10  as pass 1 on the new m
    luminance blend   r 2   Y = ybl + w (y - ybl), w = max(E - k vn, 0) / E (LMMSE-style),
                            E = 5 x 5 mean of (y - ylp)^2, vn its noise variance from the noise
                            model; ybl = m / 2 + (4 axial neighbours of m) / 8, the flat-field
                            target (zero at (pi, pi), noise gain 0.3125 against 0.405 for ylp);
                            noiseless Y = ylp + (y - ylp) = y; L = Y + c, M = Y - c
    S                 r 11  g = GF over S sites of p against M (radius 4); residual interpolation:
                            S = g + gamma_S * tent-interpolation over the S lattice of (p - g)
    S alias           r 4   S toward the neutral s_from_m M where luminance detail can alias (below)

Halo 4 + 6 + 2 + 10 + 6 + 10 + 2 + 11 + 4 = 55 px with the default radii (``halo``).

Alias suppression (in M at S pass 2, the L, M output and S alias; ``alias_*`` parameters). Where the luminance has strong
detail beyond the quincunx baseband (the diamond |wx| + |wy| < pi), its harmonics and the S-lattice
aliases land on the chroma carriers ((pi, pi) for L - M; (0, pi), (pi, 0), (pi/2, pi/2) for S), and
there a grey pattern and a colour give the same samples: no local estimate separates them (a neutral
zone plate turns green/magenta). Each chroma deviation from the neutral (``neutral``, the white-balanced
LMS of grey: C / Y = cn, S / M and M / S ratios) is then shrunk as an LMMSE estimate whose "noise" is
the expected alias, a fixed fraction alpha of the luminance detail energy E_sig = max(E - k vn, 0)
(E = 5 x 5 mean of (y - ylp)^2, the noise share removed): dev' = dev max(D - alpha E_sig, 0) / D, D the
deviation's energy (5 x 5 mean for L - M and S - M, the pixel's own for M at S sites). Saturated
colour (D >> alpha E_sig) and flat or noisy-flat regions (E_sig ~ 0) are untouched. The L - M alias
variance has a second, specific term alias_h E_h tau^2 (``tonal_energy``): a periodic luminance
pattern near (pi/2, pi/2) puts its 2nd harmonic exactly on (pi, pi), where the generic term would need
to be strong (and desaturate thin coloured detail everywhere) to remove it; tau, the share of the
local detail energy in that band, keeps broadband texture out. S has the same kind of second term,
alias_st E_ax tau^2 (``axial_tonal_energy``), for periodic luminance at the axial Nyquist carriers
(pi, 0), (0, pi) of the S lattice, where every S sample sees the same phase.

Edge-directed estimate (M at S, pass 2): for the four 2-tap predictors d in {h, v, d1, d2} of y from its
neighbours along d, err_d = mean squared error of the same predictor at the known (non-S) pixels of the
3 x 3 around the S site; yd = sum_d E_d / (eps + err_d) / sum_d 1 / (eps + err_d); the estimate is
mixed in with weight w = hf / (hf + min_d err_d), hf = kappa * 5 x 5 mean of (y - ylp)^2. It fixes the
S-lattice aliasing of the S-sample transfer on oriented detail at the S-lattice carriers (0, pi),
(pi, 0), (pi/2, pi/2) and helps colour edges (McMaster +0.2 dB, linear zone plate +2 dB).

Noise (``noise``, a :class:`ChannelNoise`, None = noiseless): every GF eps grows by the noise
variance of its target at the local level (chroma: of the guide ylp); gamma and gamma_S are LMMSE
gains of the S residuals (signal variance from the M residuals around, resp. the S residuals); the
luminance blend uses the noise variance of y - ylp, sum(D^2) var(L/M sample). On flat patches w -> 0,
Y = ylp (the diamond low-pass of the hybrid with alpha = 1), which is where the SNR lead over Bayer
comes from; on detail w -> 1 and every sample is kept.

Noiseless tone-mapped PSNR (2026-11-25): Kodak 37.59 dB, McMaster 34.74 dB against Bayer DLMMSE's
36.21 / 32.73; the measurements and their history are in README.md.

Pipeline use: ``DemosaicLMSGuided.for_raw(raw)`` (noise from RawImage.metadata, neutral from its
colour matrix); a raw without a gain in its metadata is treated as noiseless.

Example: a flat mosaic comes back flat::

    >>> from clisp.cfa import lms_cfa
    >>> stage = DemosaicLMSGuided(lms_cfa())
    >>> out = stage.reference(np.full((2 * stage.halo + 3, 2 * stage.halo + 4), 0.5), (0, 0))
    >>> out.shape, bool(np.allclose(out, 0.5))
    ((3, 4, 3), True)
"""
from __future__ import annotations

from dataclasses import dataclass, field

from functools import lru_cache

import numpy as np

from ...cfa import CFA
from ...errors import ClispError
from ...sim.noise import NOISELESS, ChannelNoise
from ...engine.runtime import DeviceImage, Runtime, launch_exact
from ...engine.stage import Stage, as_f32
from ..common.box import enqueue_box
from ..colour.stage import camera_neutral
from ..common.guided_filter import (MASK_ALL, MASK_S, enqueue_guided_filter, enqueue_guided_pair,
                                    guided_filter)
from ..common.lms import (LATTICE, NoiseFromRaw, binomial, check_lms_structure, correlate_valid,
                          diamond_halfband, lattice_shift, valid)

D_RADIUS = 4
"""Radius of the 9 x 9 diamond half-band filter D (l_guide and lum_lowpass)."""
PRE_RADIUS = 2
"""Radius of the 5 x 5 binomial B5 applied to the demodulated chroma before its guided filter."""
COMBINE_RADIUS = 2
"""Radius of m_at_s_combine (5 x 5 residual energy, 2-tap predictors around a 3 x 3) and of the
luminance blend (5 x 5 energy)."""
RI_RADIUS = 3
"""Radius of the residual interpolation over the S lattice: the support of the lattice's tent."""
DIRECTIONS = ((0, 1), (1, 0), (1, 1), (1, -1))
"""The 2-tap predictors of the edge-directed estimate: y(q - d) and y(q + d) for each d = (dy, dx)."""
i32, f32 = np.int32, np.float32


# ---------------------------------------------------------------------------------- filters

def ri_tent() -> np.ndarray:
    """7 x 7 bilinear tent of the 45-degree S lattice (spacing 2 sqrt 2, neighbours at (2, +-2)):
    (1 - |dy + dx| / 4)+ (1 - |dy - dx| / 4)+, zero at the next S along both lattice axes; its
    support is |dy| + |dx| <= 3, so it fits 7 x 7 (RI_RADIUS = 3)."""
    t = np.arange(-RI_RADIUS, RI_RADIUS + 1)
    dy, dx = np.meshgrid(t, t, indexing="ij")
    return np.clip(1 - np.abs(dy + dx) / 4.0, 0, None) * np.clip(1 - np.abs(dy - dx) / 4.0, 0, None)


BP_RADIUS = 4
"""Radius of the half-Nyquist diagonal band-pass of the tonal alias detector (``tonal_energy``)."""
TONE_POWER = 2
"""Exponent of the tonality (band share of the local detail energy) in ``tonal_energy``."""


HALF_NYQUIST_TAPS = np.array([1.0, -4.0, 6.0, -4.0, 1.0]) / 16.0
"""1-D weights of the band-pass at offsets -4, -2, 0, 2, 4 (response sin^4 w)."""


def half_nyquist_bandpass() -> np.ndarray:
    """9 x 9 band-pass k k^T, k = HALF_NYQUIST_TAPS on the even offsets: response sin^4(wx) sin^4(wy),
    1 at (+-pi/2, +-pi/2), whose 2nd harmonic lands exactly on the (pi, pi) L-M carrier; 1/16 at
    (pi/4, pi/4), 0 on both axes and at (pi, pi)."""
    k = np.zeros(2 * BP_RADIUS + 1)
    k[::2] = HALF_NYQUIST_TAPS
    return np.outer(k, k)


HALF_NYQUIST_BP = half_nyquist_bandpass()
AXIAL_HP = np.outer([1.0, 2.0, 1.0], [-1.0, 2.0, -1.0]) / 16.0
"""3 x 3 axial Nyquist detector: high-pass (1 - cos wx) / 2 across x times low-pass (1 + cos wy) / 2
along y; 1 at (0, pi) in (wy, wx), 0 at DC and at (pi, pi)."""
S_ALIAS_RADIUS = 4
"""Radius of s_alias: 5 x 5 means of energies of a 3 x 3 high-pass and of a 5 x 5 mean's residual."""
D9 = diamond_halfband()
B5 = np.outer(binomial(5), binomial(5))
TENT = ri_tent()
LUM_NOISE_GAIN = float(np.sum(D9 ** 2))
"""Flat-field noise variance of ylp = D * m relative to one sample (0.405): also that of y - ylp."""


# ---------------------------------------------------------------------------------- parameters



@dataclass(frozen=True)
class LMSGuidedParams:
    """Parameters of :class:`DemosaicLMSGuided` (signal units: white-balanced raw, white ~ 1)."""

    ms_radius1: int = 3
    """M at S, pass 1: guided-filter radius (px) against the L-only guide."""
    ms_radius2: int = 2
    """M at S, pass 2: guided-filter radius (px) against the pass-1 luminance y."""
    ms_eps: float = 1e-4
    """M at S: guided-filter regulariser (signal^2), plus the target's noise variance."""
    chroma_radius: int = 2
    """Chroma: guided-filter radius (px) of the demodulated chroma against ylp. 2 (was 3, issue 17):
    less colour spread across edges the luminance does not mark (noiseless ring shift, worst a*b*,
    2.60 -> 1.36; README.md)."""
    chroma_eps: float = 1e-5
    """Chroma: guided-filter regulariser (signal^2), plus the noise variance of ylp."""
    chroma_guide: float = 0.0
    """Chroma: weight lambda of the demodulated chroma cin in the filter's guide, ylp + lambda cin, so
    that colour edges the luminance does not mark guide the chroma too (issue 17; 0: ylp alone, the
    default). It applies in full up to the L/M noise std chroma_guide_sigma[0] at mid-grey and fades
    to 0 at chroma_guide_sigma[1] (:attr:`DemosaicLMSGuided.guide_lambda`): at high noise cin's noise
    enters the guide and costs PSNR for little gain. Off by default because cin also carries aliased
    luminance at (pi, pi): with lambda 4 the noiseless zone plate falls from over 40 to 25.6 dB (the
    guide makes the chroma follow the alias); see docs/RESULTS.md."""
    chroma_guide_sigma: tuple[float, float] = (0.011, 0.022)
    """(full, off): L/M noise std at mid-grey (0.18, white-balanced) where chroma_guide applies in
    full and where it is 0; linear in between. Simulated sensor: 0.011 at gain 4, 0.022 at gain 16."""
    chroma_guide_noise: float = 4.0
    """kappa: the guide's chroma noise, lambda^2 kappa sum(B5^2) times the L/M noise, is added to
    the chroma filter's regulariser (dimensionless)."""
    s_radius: int = 4
    """S: guided-filter radius (px) over the S sites against M."""
    s_eps: float = 1e-4
    """S: guided-filter regulariser (signal^2), plus the S noise variance."""
    dir_kappa: float = 0.1
    """M at S, pass 2: weight of the local detail energy against the edge-directed prediction error
    (0 disables the edge-directed estimate); dimensionless."""
    dir_eps: float = 1e-7
    """M at S, pass 2: floor of the predictor errors in the direction weights (signal^2)."""
    blend_k: float = 2.0
    """Luminance blend: noise over-subtraction factor k in w = max(E - k vn, 0) / E (dimensionless)."""
    alias_c: float = 0.03
    """Alias suppression of the L-M chroma: alias variance per unit luminance detail energy E_sig
    (dimensionless; 0 disables)."""
    alias_h: float = 1.0
    """Alias suppression of the L-M chroma: alias variance per unit tonal half-Nyquist energy
    (``tonal_energy``: periodic luminance at (pi/2, pi/2), whose 2nd harmonic sits on (pi, pi))."""
    alias_m: float = 0.5
    """Alias suppression of M at S sites (pass 2): the same for the S-M difference there."""
    alias_s: float = 1.0
    """Alias suppression of S: the same for S - M everywhere."""
    alias_st: float = 1.0
    """Alias suppression of S: alias variance per unit tonal axial-Nyquist energy
    (``axial_tonal_energy``: periodic luminance at (pi, 0), (0, pi), carriers of the S lattice)."""
    passes: int = 2
    """2: both passes (M at S and chroma refined against the pass-1 luminance); 1: the luminance
    blend, S and the alias suppression straight from pass 1 (halo 16 px less, a quarter less device
    time). Where noise hides what pass 2 refines, 1 costs nothing (clisp.pipeline.demosaic_choice)."""

    def __post_init__(self) -> None:
        if self.passes not in (1, 2):
            raise ClispError(f"passes must be 1 or 2, not {self.passes}")
        for name in ("ms_radius1", "ms_radius2", "chroma_radius", "s_radius"):
            if int(getattr(self, name)) < 2:
                raise ClispError(f"{name} must be >= 2 px (the S covering radius of the LMS CFA)")
        if min(self.ms_eps, self.chroma_eps, self.s_eps, self.dir_eps) <= 0:
            raise ClispError("the guided-filter regularisers and dir_eps must be > 0")
        if min(self.dir_kappa, self.blend_k, self.alias_c, self.alias_h, self.alias_m, self.alias_s,
               self.alias_st) < 0:
            raise ClispError("dir_kappa, blend_k and the alias_* strengths must be >= 0")


# ---------------------------------------------------------------------------------- helpers

def mean5(x: np.ndarray) -> np.ndarray:
    """5 x 5 box mean (valid region: shrinks by COMBINE_RADIUS)."""
    return correlate_valid(x, np.ones((5, 5)) / 25.0)


def tonal(e_band: np.ndarray, e_ac: np.ndarray) -> np.ndarray:
    """e_band tau^TONE_POWER with the tonality tau = min(e_band / e_ac, 1) (0 where e_ac == 0): the share
    of the local detail energy e_ac that one band holds; ~1 for a periodic pattern in the band."""
    pos = e_ac > 0
    tau = np.where(pos, np.minimum(e_band / np.where(pos, e_ac, 1.0), 1.0), 0.0)
    return e_band * tau ** TONE_POWER


def detail_energy(y: np.ndarray, ylp: np.ndarray, vn: np.ndarray | float, k: float) -> np.ndarray:
    """E_sig = max(E - k vn, 0), E = 5 x 5 mean of (y - ylp)^2: the luminance detail beyond the
    quincunx baseband (the diamond |wx| + |wy| < pi) with its noise share removed; vn on the output
    window (y, ylp on one window, shrunk by COMBINE_RADIUS)."""
    return np.maximum(mean5((y - ylp) ** 2) - k * vn, 0.0)


def alias_gain(energy: np.ndarray, alias: np.ndarray) -> np.ndarray:
    """The shrink max(energy - alias, 0) / energy of a chroma deviation whose energy is ``energy`` when
    ``alias`` of it is expected to be luminance aliased onto a chroma carrier (LMMSE-style, as the
    luminance blend); 1 where energy == 0."""
    pos = energy > 0
    return np.where(pos, np.maximum(energy - alias, 0.0) / np.where(pos, energy, 1.0), 1.0)


def tonal_energy(ylp: np.ndarray) -> np.ndarray:
    """E_h tau^TONE_POWER: the half-Nyquist diagonal band energy of the low-passed luminance, weighted
    by its tonality tau = min(E_h / E_ac, 1). E_h = 5 x 5 mean of (HALF_NYQUIST_BP * ylp)^2, E_ac = 5 x 5
    mean of (ylp - its 5 x 5 mean)^2. A periodic pattern near (pi/2, pi/2) (tau ~ 1) puts its 2nd
    harmonic on the L-M carrier; broadband texture (tau << 1) does not. ylp on a window grown by
    BP_RADIUS + COMBINE_RADIUS around the output."""
    bp = correlate_valid(ylp, HALF_NYQUIST_BP)
    ac = valid(ylp, BP_RADIUS) - mean5(valid(ylp, BP_RADIUS - COMBINE_RADIUS))
    return tonal(mean5(bp * bp), mean5(ac * ac))


def neutral_of(colour_matrix: np.ndarray) -> tuple[float, float, float]:
    """White-balanced L, M, S of a neutral: colour_matrix^-1 (1, 1, 1) (1.0106, 1.0153, 1.0654 for the
    paper's P: P is not white-preserving). (1, 1, 1) if the matrix gives no positive finite answer."""
    n = camera_neutral(colour_matrix)
    return (1.0, 1.0, 1.0) if n is None else tuple(float(v) for v in n)


# ---------------------------------------------------------------------------------- reference steps
# One function per kernel (same names). Arrays are float64 windows; ``ch`` is the CFA channel map of
# the function's input window. Every function returns its valid region (shrunk by its radius).

def l_guide(p: np.ndarray, ch: np.ndarray, ch_l: int) -> np.ndarray:
    """I0: L at L sites; elsewhere 2 sum_{t != 0} D[t] p(. + t) (off-centre taps of D fall on L sites
    only, so this interpolates the L quincunx). Shrinks by D_RADIUS."""
    off = D9.copy()
    off[D_RADIUS, D_RADIUS] = 0.0
    centre = valid(p, D_RADIUS)
    return np.where(valid(ch, D_RADIUS) == ch_l, centre, 2.0 * correlate_valid(p, off))


def m_at_s_combine(p: np.ndarray, ch: np.ndarray, mfit: np.ndarray, sfit: np.ndarray, ch_m: int, ch_s: int,
                   noise: ChannelNoise | None, directional: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
                   kappa: float, dir_eps: float,
                   alias: tuple[np.ndarray, float, float] | None = None) -> np.ndarray:
    """The L/M quincunx m (shrunk by COMBINE_RADIUS; all inputs on one window): p where not S; at S
    sites M = Mfit + gamma (S - Sfit), gamma = sig / (sig + var_S(Sfit)), sig = max(E_M - var_M(Mfit), 0),
    E_M = mean over the M sites of the 5 x 5 of (p - Mfit)^2; gamma = 1 when noiseless.
    ``directional`` = (y, c, ylp) mixes in the edge-directed estimate (module doc). ``alias`` =
    (E_sig on the output window, alias_m, m_from_s) then shrinks M toward the neutral m_from_s S:
    dev = M - m_from_s S, M = m_from_s S + alias_gain(dev^2, alias_m E_sig) dev."""
    r = COMBINE_RADIUS
    centre_p, centre_ch = valid(p, r), valid(ch, r)
    est = valid(mfit, r)
    if noise is None:
        est = est + (centre_p - valid(sfit, r))
    else:
        is_m = (ch == ch_m).astype(np.float64)
        e_m = correlate_valid(is_m * (p - mfit) ** 2, np.ones((5, 5))) / correlate_valid(is_m, np.ones((5, 5)))
        sig = np.maximum(e_m - noise.variance(ch_m, valid(mfit, r)), 0.0)
        gamma = sig / (sig + noise.variance(ch_s, valid(sfit, r)))
        est = est + gamma * (centre_p - valid(sfit, r))
    if directional is not None and kappa > 0:
        y, c, ylp = directional
        known = ch != ch_s
        num = den = 0.0
        err_min = np.full(centre_p.shape, np.inf)
        for dy, dx in DIRECTIONS:
            pred = (valid(y, 1, -dy, -dx) + valid(y, 1, dy, dx)) / 2          # on the window less 1
            ok = (valid(known, 1) & valid(known, 1, -dy, -dx) & valid(known, 1, dy, dx)).astype(np.float64)
            err = correlate_valid(ok * (pred - valid(y, 1)) ** 2, np.ones((3, 3))) \
                / correlate_valid(ok, np.ones((3, 3)))
            weight = 1.0 / (err + dir_eps)
            num = num + weight * valid(pred, 1)
            den = den + weight
            err_min = np.minimum(err_min, err)
        hf = kappa * mean5((y - ylp) ** 2)
        total = hf + err_min
        w = np.where(total > 0, hf / np.where(total > 0, total, 1.0), 0.0)
        est = w * (num / den - valid(c, r)) + (1.0 - w) * est
    if alias is not None:
        e_sig, strength, m_from_s = alias
        dev = est - m_from_s * centre_p
        est = m_from_s * centre_p + alias_gain(dev * dev, strength * e_sig) * dev
    return np.where(centre_ch == ch_s, est, centre_p)


def lum_lowpass(m: np.ndarray) -> np.ndarray:
    """ylp = D * m (the quincunx baseband, zero at the (pi, pi) chroma carrier). Shrinks by D_RADIUS."""
    return correlate_valid(m, D9)


def chroma_input(m: np.ndarray, ylp: np.ndarray, mod: np.ndarray) -> np.ndarray:
    """B5 * ((m - ylp) mod) on ylp's window (m, mod: ylp's window grown by D_RADIUS): the demodulated
    high band, ~ C plus luminance leaking near (pi, pi). Shrinks ylp's window by PRE_RADIUS."""
    return correlate_valid((valid(m, D_RADIUS) - ylp) * valid(mod, D_RADIUS), B5)


def lm_output(m: np.ndarray, c: np.ndarray, ylp: np.ndarray, mod: np.ndarray, noise: ChannelNoise | None,
              ch_l: int, ch_m: int, blend_k: float, chroma_neutral: float = 0.0,
              alias_c: float = 0.0, tone: np.ndarray | float = 0.0, alias_h: float = 0.0) -> np.ndarray:
    """L, M and E_sig (3 planes, shrunk by COMBINE_RADIUS; inputs on one window): y = m - c mod,
    d = y - ylp; noiseless Y = ylp + d (= y); noisy Y = ybl + w (y - ybl), ybl = B * m with
    B = delta / 2 + (4 axial taps) / 8 (the flat-field target: DC gain 1, zero at the (pi, pi) chroma
    carrier, noise gain 0.3125 against sum(D^2) = 0.405 for ylp), w = E_sig / E, E_sig = max(E - k vn, 0)
    (``detail_energy``), vn = sum(D^2) (var_L + var_M) / 2 at the level ylp (the noise of d).
    Alias suppression of the chroma: dev = c - cn ylp (cn = ``chroma_neutral``, c / Y of a neutral),
    c' = cn ylp + alias_gain(5 x 5 mean of dev^2, alias_c E_sig + alias_h tone) dev (``tone``: the
    ``tonal_energy`` on the output window); L = Y + c', M = Y - c'."""
    r = COMBINE_RADIUS
    y = m - c * mod
    centre_ylp = valid(ylp, r)
    vn = 0.0 if noise is None else \
        LUM_NOISE_GAIN * 0.5 * (noise.variance(ch_l, centre_ylp) + noise.variance(ch_m, centre_ylp))
    e = mean5((y - ylp) ** 2)
    e_sig = np.maximum(e - blend_k * vn, 0.0)
    if noise is None:
        lum = valid(y, r)
    else:
        w = np.where(e > 0, e_sig / np.where(e > 0, e, 1.0), 0.0)
        ybl = 0.5 * valid(m, r) + 0.125 * (valid(m, r, -1, 0) + valid(m, r, 1, 0)
                                            + valid(m, r, 0, -1) + valid(m, r, 0, 1))
        lum = ybl + w * (valid(y, r) - ybl)
    dev = c - chroma_neutral * ylp
    c2 = mean5(dev * dev)
    c_out = chroma_neutral * centre_ylp + alias_gain(c2, alias_c * e_sig + alias_h * tone) * valid(dev, r)
    return np.stack([lum + c_out, lum - c_out, e_sig], axis=-1)


def s_output(p: np.ndarray, ch: np.ndarray, g: np.ndarray, ch_s: int, noise: ChannelNoise | None) -> np.ndarray:
    """S = g + gamma_S * (tent interpolation over the S sites within RI_RADIUS of (p - g)), shrunk by
    RI_RADIUS (p, ch, g on one window); gamma_S = max(E - var_S(g), 0) / E, E = mean over the S sites
    of the 7 x 7 of (p - g)^2 (gamma_S = 1 noiseless). At an S site this keeps the sample (gamma_S = 1)."""
    is_s = (ch == ch_s).astype(np.float64)
    res = is_s * (p - g)
    interp = correlate_valid(res, TENT) / correlate_valid(is_s, TENT)
    centre_g = valid(g, RI_RADIUS)
    if noise is None:
        return centre_g + interp
    ones = np.ones((2 * RI_RADIUS + 1,) * 2)
    e = correlate_valid(res * res, ones) / correlate_valid(is_s, ones)
    gamma = np.where(e > 0, np.maximum(e - noise.variance(ch_s, centre_g), 0.0) / np.where(e > 0, e, 1.0), 0.0)
    return centre_g + gamma * interp


def axial_tonal_energy(lum: np.ndarray) -> np.ndarray:
    """E_ax tau^TONE_POWER for S: the energy of the luminance near the axial Nyquist carriers (pi, 0)
    and (0, pi) (S-lattice carriers: a periodic pattern there makes the S samples all see one phase),
    weighted by its tonality tau = min(E_ax / E_ac, 1). E_ax = 5 x 5 mean of hx^2 + hy^2, hx = AXIAL_HP *
    lum (high-pass (1 - cos wx) / 2 across, low-pass (1 + cos wy) / 2 along), hy its transpose; E_ac =
    5 x 5 mean of (lum - its 5 x 5 mean)^2. Shrinks by S_ALIAS_RADIUS."""
    hx = valid(correlate_valid(lum, AXIAL_HP), 1)
    hy = valid(correlate_valid(lum, AXIAL_HP.T), 1)
    ac = valid(lum, COMBINE_RADIUS) - mean5(lum)
    return tonal(mean5(hx * hx + hy * hy), mean5(ac * ac))


def s_alias(lms: np.ndarray, e_sig: np.ndarray, s_from_m: float, alias_s: float,
            alias_st: float = 0.0) -> np.ndarray:
    """Alias suppression of S: L, M, S (H x W x 3) and E_sig (H x W) on one window -> L, M, S shrunk by
    S_ALIAS_RADIUS, sd = S - s_from_m M, S' = s_from_m M + alias_gain(5 x 5 mean of sd^2, alias_s E_sig
    + alias_st axial_tonal_energy((L + M) / 2)) sd."""
    r = S_ALIAS_RADIUS
    sd = lms[..., 2] - s_from_m * lms[..., 1]
    s2 = valid(mean5(sd * sd), r - COMBINE_RADIUS)
    tone = axial_tonal_energy(0.5 * (lms[..., 0] + lms[..., 1]))
    centre = valid(lms, r)
    s = s_from_m * centre[..., 1] + alias_gain(s2, alias_s * valid(e_sig, r) + alias_st * tone) * valid(sd, r)
    return np.concatenate([centre[..., :2], s[..., None]], axis=-1)


# ---------------------------------------------------------------------------------- the stage

@dataclass
class DemosaicLMSGuided(NoiseFromRaw, Stage):
    """LMS mosaic (white-balanced, H x W) -> L, M, S ((H-2 halo) x (W-2 halo) x 3); see module doc.

    ``noise``: a :class:`ChannelNoise` (per-channel variance of a white-balanced sample) or None for a
    noiseless raw. From a RawImage: ``DemosaicLMSGuided.for_raw(raw)``.
    """

    cfa: CFA
    params: LMSGuidedParams = field(default_factory=LMSGuidedParams)
    noise: ChannelNoise | None = None
    neutral: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """White-balanced L, M, S of a neutral (``neutral_of(colour_matrix)``): what alias suppression
    shrinks toward."""
    name = "demosaic_lms_guided"
    cfa_kinds = ("lms",)
    in_channels = 1
    out_channels = 3

    def __post_init__(self) -> None:
        self.ch_l, self.ch_m, self.ch_s = check_lms_structure(self.cfa, "guided LMS demosaic")
        self.shift = lattice_shift(self.cfa, self.ch_l, self.ch_s)
        n_l, n_m, n_s = (float(v) for v in self.neutral)
        if not min(n_l, n_m, n_s) > 0:
            raise ClispError(f"neutral {self.neutral}: every channel must be > 0")
        self.chroma_neutral = (n_l - n_m) / (n_l + n_m)
        """C / Y = (L - M) / (L + M) of a neutral."""
        self.m_from_s, self.s_from_m = n_m / n_s, n_s / n_m

    @classmethod
    def for_raw(cls, raw, params=None):
        """As NoiseFromRaw.for_raw, with the neutral of the raw's colour matrix."""
        stage = super().for_raw(raw, params)
        return cls(stage.cfa, stage.params, stage.noise, neutral_of(raw.colour_matrix))

    # -- geometry ---------------------------------------------------------------------------------
    @property
    def radii(self) -> dict[str, int]:
        """Halo consumed by each step, in run order (sums to ``halo``)."""
        prm = self.params
        chroma = D_RADIUS + PRE_RADIUS + 2 * prm.chroma_radius
        second = {"ms2_fit": 2 * prm.ms_radius2, "ms2_combine": COMBINE_RADIUS, "chroma2": chroma} \
            if prm.passes == 2 else {}
        return {"l_guide": D_RADIUS, "ms1_fit": 2 * prm.ms_radius1, "ms1_combine": COMBINE_RADIUS,
                "chroma1": chroma, **second, "lm_output": COMBINE_RADIUS, "s_fit": 2 * prm.s_radius,
                "s_output": RI_RADIUS, "s_alias": S_ALIAS_RADIUS}

    @property
    def halo(self) -> int:
        return sum(self.radii.values())

    @property
    def bytes_per_pixel(self) -> float:
        """Device bytes per input pixel for the tile planner: at most about 14 float32 planes are alive
        at once (mosaic, y, c, ylp, m, two fits, five row moments, two coefficient planes); 20 planes
        leave room for the pool keeping released buffers of other sizes."""
        return 4.0 * 20

    # -- reference ------------------------------------------------------------------------------
    def _chroma(self, m: np.ndarray, mod: np.ndarray, noise: ChannelNoise,
                margin: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """(c, ylp): c on m's window shrunk by D + PRE + 2 chroma_radius, ylp on that window grown by
        ``margin`` (<= PRE + 2 chroma_radius); mod on m's window."""
        prm, r = self.params, self.params.chroma_radius
        ylp = lum_lowpass(m)
        cin = chroma_input(m, ylp, mod)
        ylp_c = valid(ylp, PRE_RADIUS)
        shot, floor = self._chroma_noise(noise)
        lam = self.guide_lambda
        guide = ylp_c + lam * cin if lam else ylp_c
        c = guided_filter(guide, cin, None, r, prm.chroma_eps, shot, floor, True)
        return c, valid(ylp_c, 2 * r - margin)

    def _chroma_noise(self, noise: ChannelNoise) -> tuple[float, float]:
        """(shot, floor) of the chroma filter's regulariser: ylp's noise, plus the guide's chroma
        noise lambda^2 kappa sum(B5^2) (var_L + var_M) / 2 when ``chroma_guide`` is set."""
        prm = self.params
        ms, mf = 0.5 * (noise.shot[self.ch_l] + noise.shot[self.ch_m]), 0.5 * (noise.floor[self.ch_l] + noise.floor[self.ch_m])
        k = LUM_NOISE_GAIN + self.guide_lambda ** 2 * prm.chroma_guide_noise * float((B5 ** 2).sum())
        return k * ms, k * mf

    @property
    def guide_lambda(self) -> float:
        """The chroma guide's lambda for this stage's noise: chroma_guide, faded linearly from the
        L/M noise std (at mid-grey) chroma_guide_sigma[0] to 0 at chroma_guide_sigma[1]."""
        prm = self.params
        if not prm.chroma_guide:
            return 0.0
        n = self.pixel_noise
        sigma = float(np.sqrt(max(0.5 * (n.variance(self.ch_l, 0.18) + n.variance(self.ch_m, 0.18)), 0.0)))
        lo, hi = prm.chroma_guide_sigma
        return float(prm.chroma_guide * np.clip((hi - sigma) / (hi - lo), 0.0, 1.0))

    def _m_at_s(self, p: np.ndarray, ch: np.ndarray, guide: np.ndarray, r: int,
                directional: tuple[np.ndarray, np.ndarray, np.ndarray] | None) -> np.ndarray:
        """m on guide's window shrunk by 2r + COMBINE_RADIUS; p, ch on guide's window; directional
        (y, c, ylp) on the window shrunk by 2r."""
        prm, noise = self.params, self.pixel_noise
        fits = [guided_filter(guide, p, ch == c, r, prm.ms_eps, noise.shot[c], noise.floor[c], False)
                for c in (self.ch_m, self.ch_s)]
        alias = None
        if directional is not None:
            y, _, ylp = directional
            e_sig = detail_energy(y, ylp, self._lum_variance(valid(ylp, COMBINE_RADIUS)), prm.blend_k)
            alias = (e_sig, prm.alias_m, self.m_from_s)
        return m_at_s_combine(valid(p, 2 * r), valid(ch, 2 * r), fits[0], fits[1], self.ch_m, self.ch_s,
                              self.noise, directional, prm.dir_kappa, prm.dir_eps, alias)

    def _lum_variance(self, level: np.ndarray) -> np.ndarray | float:
        """Noise variance of ylp (and of y - ylp) at ``level``: sum(D^2) (var_L + var_M) / 2; 0 noiseless."""
        if self.noise is None:
            return 0.0
        return LUM_NOISE_GAIN * 0.5 * (self.noise.variance(self.ch_l, level) + self.noise.variance(self.ch_m, level))

    @property
    def pixel_noise(self) -> ChannelNoise:
        return NOISELESS if self.noise is None else self.noise

    def reference(self, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
        prm, noise = self.params, self.pixel_noise
        p = x.astype(np.float64)
        ch = self.cfa.channel_map(p.shape[0], p.shape[1], origin)
        mod = np.where(ch == self.ch_l, 1.0, -1.0)
        o = D_RADIUS                                             # offset of the current window in p
        guide = l_guide(p, ch, self.ch_l)
        m = self._m_at_s(valid(p, o), valid(ch, o), guide, prm.ms_radius1, None)
        o += 2 * prm.ms_radius1 + COMBINE_RADIUS
        k = D_RADIUS + PRE_RADIUS + 2 * prm.chroma_radius
        if prm.passes == 2:
            c, ylp = self._chroma(m, valid(mod, o), noise)
            o += k
            y = valid(m, k) - c * valid(mod, o)
            r2 = prm.ms_radius2
            m = self._m_at_s(valid(p, o), valid(ch, o), y, r2,
                             (valid(y, 2 * r2), valid(c, 2 * r2), valid(ylp, 2 * r2)))
            o += 2 * r2 + COMBINE_RADIUS
        c, ylp_wide = self._chroma(m, valid(mod, o), noise, BP_RADIUS)
        o += k
        lm = lm_output(valid(m, k), c, valid(ylp_wide, BP_RADIUS), valid(mod, o), self.noise, self.ch_l,
                       self.ch_m, prm.blend_k, self.chroma_neutral, prm.alias_c, tonal_energy(ylp_wide),
                       prm.alias_h)
        o += COMBINE_RADIUS
        rs = prm.s_radius
        g = guided_filter(lm[..., 1], valid(p, o), valid(ch, o) == self.ch_s, rs, prm.s_eps,
                          noise.shot[self.ch_s], noise.floor[self.ch_s], False)
        o += 2 * rs
        s = s_output(valid(p, o), valid(ch, o), g, self.ch_s, self.noise)
        k = 2 * rs + RI_RADIUS
        lms = np.concatenate([valid(lm[..., :2], k), s[..., None]], axis=-1)
        return s_alias(lms, valid(lm[..., 2], k), self.s_from_m, prm.alias_s, prm.alias_st)

    # -- OpenCL ---------------------------------------------------------------------------------
    # Windows: every intermediate lives on a window of the input shrunk by an offset (o_*, px on each
    # side); a kernel reads inputs on larger windows through offsets relative to its own window.

    def defines(self) -> dict[str, int]:
        """Compile-time constants of clisp/modules/demosaic_lms_guided/demosaic_lms_guided.cl (see its header). No CFA phase among
        them: it is folded into the origin (``_origin``), so all phases share the programs. The guided
        filters' kernels (clisp/modules/common/guided_filter.cl) get LATTICE and their radius instead."""
        return {**LATTICE, "NOISY": int(self.noise is not None),
                "TONE_POWER": TONE_POWER, "D_RADIUS": D_RADIUS, "PRE_RADIUS": PRE_RADIUS,
                "COMBINE_RADIUS": COMBINE_RADIUS, "RI_RADIUS": RI_RADIUS, "BP_RADIUS": BP_RADIUS,
                "HP_RADIUS": AXIAL_HP.shape[0] // 2, "S_ALIAS_RADIUS": S_ALIAS_RADIUS}

    def _origin(self, origin: tuple[int, int]) -> tuple[np.int32, np.int32]:
        """Kernel arguments (oy, ox) for image ``origin``: shifted by the translation that maps this CFA
        onto the base LMS tile that LATTICE describes (so one program serves every CFA phase)."""
        return i32(origin[0] + self.shift[0]), i32(origin[1] + self.shift[1])

    @staticmethod
    @lru_cache(maxsize=1)
    def generated_source() -> str:
        """``D_TAPS`` and ``TENT_TAPS``: X(dy, dx, t) for each non-zero tap t (structure, not weights;
        D_TAPS without the centre)."""
        d = " ".join(f"X({dy}, {dx}, {t})" for t, (dy, dx) in enumerate(_support(D9, centre=False)))
        tent = " ".join(f"X({dy}, {dx}, {t})" for t, (dy, dx) in enumerate(_support(TENT)))
        groups: dict[float, list[str]] = {}
        for (dy, dx), wt in zip(_support(D9, centre=False), as_f32(_weights(D9, centre=False))):
            groups.setdefault(float(wt), []).append(f"P({dy}, {dx})")
        d_sum = " + ".join(f"{wt!r}f * ({' + '.join(taps)})" for wt, taps in groups.items())
        b_groups: dict[float, list[str]] = {}
        for (dy, dx), wt in zip(_support(B5), as_f32(_weights(B5))):
            b_groups.setdefault(float(wt) * (-1) ** (int(dy + dx) & 1), []).append(f"P({dy}, {dx})")
        b_sum = " + ".join(f"{wt!r}f * ({' + '.join(taps)})" for wt, taps in b_groups.items())
        return ("/* generated by clisp: supports of D (off-centre) and of the S-lattice tent; D_SUM(P): the\n"
                " * off-centre D taps of P(dy, dx), taps of one weight summed first (D's 8-fold symmetry:\n"
                " * 6 multiplications instead of 40), weights as float32 literals; B5_SUM(P): the 5 x 5 binomial\n"
                " * B5 times (-1)^(dy + dx) (the chroma carrier's sign), grouped the same way */\n"
                f"#define D_TAPS {d}\n#define TENT_TAPS {tent}\n#define D_SUM(P) ({d_sum})\n"
                f"#define B5_SUM(P) ({b_sum})\n")

    def _launch(self, rt: Runtime, kernel_name: str, width: int, height: int, *args: object) -> None:
        """Enqueue ``kernel_name`` of clisp/modules/demosaic_lms_guided/demosaic_lms_guided.cl over exactly width x height outputs
        (``runtime.launch_exact``, one command: the kernels take their coordinates from common.h's inward_id
        or check them)."""
        kernel = rt.kernel("demosaic_lms_guided", kernel_name, self.defines(), self.generated_source())
        launch_exact(rt, kernel, width, height, *args, inward=True)

    def _launch_named(self, rt: Runtime, kernel_name: str, width: int, height: int, args: dict[str, object]) -> None:
        """Enqueue ``kernel_name`` with its arguments by name (``Runtime.launch_named``)."""
        rt.launch_named("demosaic_lms_guided", kernel_name, width, height, args, self.defines(),
                        self.generated_source(), inward=True)

    def enqueue_l_guide(self, rt: Runtime, p: DeviceImage, origin: tuple[int, int]) -> DeviceImage:
        """I0 on p's window shrunk by D_RADIUS."""
        h, w = p.height - 2 * D_RADIUS, p.width - 2 * D_RADIUS
        dst = rt.acquire(1, h, w)
        self._launch(rt, "l_guide", w, h, p.buffer, dst.buffer, i32(p.width), i32(w), *self._origin(origin),
                     rt.constant(as_f32(_weights(D9, centre=False))), i32(h))
        return dst

    def enqueue_m_at_s(self, rt: Runtime, p: DeviceImage, origin: tuple[int, int], guide: DeviceImage,
                       o_guide: int, r: int, directional: tuple[DeviceImage, DeviceImage, DeviceImage, int, int]
                       | None = None) -> DeviceImage:
        """m on guide's window (p's shrunk by o_guide) shrunk by 2r + COMBINE_RADIUS; ``directional`` =
        (y, c, ylp, o_y, o_ylp): y and c on the window p's shrunk by o_y, ylp by o_ylp."""
        prm, noise = self.params, self.pixel_noise
        own, g_origin = (guide.height, guide.width), (origin[0] + o_guide, origin[1] + o_guide)
        fits = enqueue_guided_pair(rt, own, g_origin, self.shift, guide, 0, p, o_guide, r, prm.ms_eps,
                                   (noise.shot[self.ch_m], noise.floor[self.ch_m]),
                                   (noise.shot[self.ch_s], noise.floor[self.ch_s]), False)
        o_fit = o_guide + 2 * r
        h, w = fits[0].height - 2 * COMBINE_RADIUS, fits[0].width - 2 * COMBINE_RADIUS
        dst = rt.acquire(1, h, w)
        self._launch(rt, "m_keep", w, h, p.buffer, dst.buffer, i32(p.width), i32(o_fit + COMBINE_RADIUS), i32(w),
                     i32(h))
        oy, ox = self._origin((origin[0] + o_fit, origin[1] + o_fit))
        args = dict(p=p, mfit=fits[0], sfit=fits[1], dst=dst, in_w=fits[0].width, p_w=p.width, p_off=o_fit,
                    out_w=w, out_h=h, oy=oy, ox=ox, shot_m=noise.shot[self.ch_m], floor_m=noise.floor[self.ch_m],
                    shot_s=noise.shot[self.ch_s], floor_s=noise.floor[self.ch_s])
        if directional is None:
            self._launch_named(rt, "m_at_s_combine", (w + 3) // 4, (h + 1) // 2, args)
        else:
            y, c, ylp, o_y, o_l = directional
            lum_shot, lum_floor = self._lum_noise()
            self._launch_named(rt, "m_at_s_combine_dir", (w + 3) // 4, (h + 1) // 2, dict(
                args, yg=y, cg=c, ylpg=ylp, y_w=y.width, y_off=o_fit - o_y, l_w=ylp.width, l_off=o_fit - o_l,
                kappa=prm.dir_kappa, dir_eps=prm.dir_eps, blend_k=prm.blend_k, lum_shot=lum_shot,
                lum_floor=lum_floor, alias_m=prm.alias_m, m_from_s=self.m_from_s))
        for fit in fits:
            rt.release(fit)
        return dst

    def _lum_noise(self) -> tuple[float, float]:
        """(shot, floor) of the noise of ylp (and of y - ylp): sum(D^2) (var_L + var_M) / 2."""
        n = self.pixel_noise
        return (LUM_NOISE_GAIN * 0.5 * (n.shot[self.ch_l] + n.shot[self.ch_m]),
                LUM_NOISE_GAIN * 0.5 * (n.floor[self.ch_l] + n.floor[self.ch_m]))

    def enqueue_chroma(self, rt: Runtime, m: DeviceImage, m_origin: tuple[int, int]
                       ) -> tuple[DeviceImage, DeviceImage]:
        """(c, ylp): ylp on m's window shrunk by D_RADIUS, c by D + PRE + 2 chroma_radius."""
        prm, r = self.params, self.params.chroma_radius
        h, w = m.height - 2 * D_RADIUS, m.width - 2 * D_RADIUS
        ylp = rt.acquire(1, h, w)
        self._launch(rt, "lum_lowpass", w, h, m.buffer, ylp.buffer, i32(m.width), i32(w), *self._origin(m_origin),
                     rt.constant(as_f32(_weights(D9, centre=False))), i32(h))
        y_origin = (m_origin[0] + D_RADIUS, m_origin[1] + D_RADIUS)
        hc, wc = h - 2 * PRE_RADIUS, w - 2 * PRE_RADIUS
        cin = rt.acquire(1, hc, wc)
        self._launch(rt, "chroma_input", wc, hc, m.buffer, ylp.buffer, cin.buffer, i32(w), i32(m.width), i32(wc),
                     *self._origin(y_origin), rt.constant(as_f32(B5)), i32(hc))
        c_origin = (y_origin[0] + PRE_RADIUS, y_origin[1] + PRE_RADIUS)
        guide, g_off = ylp, PRE_RADIUS
        if self.guide_lambda:                             # ylp + lambda cin on cin's window
            guide, g_off = rt.acquire(1, hc, wc), 0
            self._launch(rt, "chroma_guide", wc, hc, ylp.buffer, cin.buffer, guide.buffer, i32(w), i32(wc),
                         f32(self.guide_lambda), i32(hc))
        c = enqueue_guided_filter(rt, (hc, wc), c_origin, self.shift, guide, g_off, cin, 0, r, MASK_ALL,
                                  prm.chroma_eps, self._chroma_noise(self.pixel_noise), True)
        if guide is not ylp:
            rt.release(guide)
        rt.release(cin)
        return c, ylp

    def enqueue_keep_luminance(self, rt: Runtime, m: DeviceImage, c: DeviceImage, m_off: int,
                               c_origin: tuple[int, int]) -> DeviceImage:
        """y = m - c mod on c's window (m's larger by m_off)."""
        dst = rt.acquire(1, c.height, c.width)
        self._launch(rt, "keep_luminance", c.width, c.height, m.buffer, c.buffer, dst.buffer, i32(m.width),
                     i32(m_off), i32(c.width), *self._origin(c_origin), i32(c.height))
        return dst

    def enqueue_s_output(self, rt: Runtime, src: DeviceImage, origin: tuple[int, int], g: DeviceImage, o_g: int,
                         lm: DeviceImage, lm_off: int) -> DeviceImage:
        """s_residual then s_output: L, M (planes 0, 1 of lm, on g's window grown by lm_off) and S on g's
        window (src's shrunk by o_g) shrunk by RI_RADIUS."""
        noise = self.pixel_noise
        out_h, out_w = g.height - 2 * RI_RADIUS, g.width - 2 * RI_RADIUS
        lms = rt.acquire(3, out_h, out_w)
        res = rt.acquire(1, g.height, g.width)
        oy_g, ox_g = self._origin((origin[0] + o_g, origin[1] + o_g))
        self._launch(rt, "s_residual", g.width, g.height, src.buffer, g.buffer, res.buffer, i32(g.width),
                     i32(src.width), i32(o_g), oy_g, ox_g, i32(g.height))
        self._launch_named(rt, "s_output", out_w, out_h, dict(
            rs=res, g=g, lm=lm, dst=lms, lat=rt.constant(s_output_lattice(g.width, int(ox_g))), in_w=g.width,
            lm_w=lm.width, lm_h=lm.height, lm_off=lm_off, out_w=out_w, out_h=out_h, oy=oy_g,
            tent=rt.constant(as_f32(_weights(TENT))), shot_s=noise.shot[self.ch_s], floor_s=noise.floor[self.ch_s]))
        rt.release(res)
        return lms

    def enqueue(self, rt: Runtime, src: DeviceImage, origin: tuple[int, int]) -> DeviceImage:
        """All steps on the device (module doc); intermediates from the pool, released when done."""
        if np.dtype(src.dtype) != np.float32:
            raise ClispError("the guided LMS demosaic reads the white-balanced float32 mosaic")
        prm, noise = self.params, self.pixel_noise

        def at(o: int) -> tuple[int, int]:
            return origin[0] + o, origin[1] + o

        k_chroma = D_RADIUS + PRE_RADIUS + 2 * prm.chroma_radius
        guide = self.enqueue_l_guide(rt, src, origin)
        o_m = D_RADIUS
        m = self.enqueue_m_at_s(rt, src, origin, guide, o_m, prm.ms_radius1)
        rt.release(guide)
        o_m += 2 * prm.ms_radius1 + COMBINE_RADIUS
        c, ylp = self.enqueue_chroma(rt, m, at(o_m))
        if prm.passes == 2:
            o_c, o_ylp = o_m + k_chroma, o_m + D_RADIUS
            y = self.enqueue_keep_luminance(rt, m, c, k_chroma, at(o_c))
            rt.release(m)
            m = self.enqueue_m_at_s(rt, src, origin, y, o_c, prm.ms_radius2, (y, c, ylp, o_c, o_ylp))
            for image in (y, c, ylp):
                rt.release(image)
            o_m = o_c + 2 * prm.ms_radius2 + COMBINE_RADIUS
            c, ylp = self.enqueue_chroma(rt, m, at(o_m))
        o_c, o_ylp = o_m + k_chroma, o_m + D_RADIUS
        h, w = c.height - 2 * COMBINE_RADIUS, c.width - 2 * COMBINE_RADIUS
        energy = rt.acquire(4, c.height, c.width)
        oy_c, ox_c = self._origin(at(o_c))
        self._launch_named(rt, "lm_energy", c.width, c.height, dict(
            m=m, c=c, ylp=ylp, dst=energy, m_w=m.width, m_off=o_c - o_m, l_w=ylp.width, l_off=o_c - o_ylp,
            out_w=c.width, out_h=c.height, oy=oy_c, ox=ox_c, chroma_neutral=self.chroma_neutral,
            bp_w=rt.constant(as_f32(HALF_NYQUIST_TAPS))))
        rows = enqueue_box(rt, energy, 0, COMBINE_RADIUS, release_src=True)    # sums along x
        lm = rt.acquire(3, h, w)
        lum_shot, lum_floor = self._lum_noise()
        self._launch_named(rt, "lm_output", w, h, dict(
            m=m, c=c, ylp=ylp, rows=rows, dst=lm, in_w=c.width, m_w=m.width, m_off=o_c - o_m, l_w=ylp.width,
            l_off=o_c - o_ylp, rows_w=rows.width, rows_h=c.height, out_w=w, out_h=h, oy=oy_c, ox=ox_c,
            blend_k=prm.blend_k, lum_shot=lum_shot, lum_floor=lum_floor, chroma_neutral=self.chroma_neutral,
            alias_c=prm.alias_c, alias_h=prm.alias_h))
        for image in (m, c, ylp, rows):
            rt.release(image)
        o_lm = o_c + COMBINE_RADIUS
        rs = prm.s_radius
        g = enqueue_guided_filter(rt, (h, w), at(o_lm), self.shift, lm, 0, src, o_lm, rs, MASK_S, prm.s_eps,
                                  (noise.shot[self.ch_s], noise.floor[self.ch_s]), False, g_plane=1)
        o_g = o_lm + 2 * rs
        lms = self.enqueue_s_output(rt, src, origin, g, o_g, lm, 2 * rs + RI_RADIUS)
        out_h, out_w = lms.height, lms.width
        rt.release(g)
        tone_h, tone_w = out_h - 2 * COMBINE_RADIUS, out_w - 2 * COMBINE_RADIUS
        tone = rt.acquire(2, tone_h, tone_w)
        self._launch(rt, "s_tone_energy", tone_w, tone_h, lms.buffer, tone.buffer, i32(out_w), i32(out_h),
                     i32(tone_w), i32(tone_h), rt.constant(as_f32(AXIAL_HP.ravel())))
        rows = enqueue_box(rt, tone, 0, COMBINE_RADIUS, release_src=True)    # sums along x
        fin_h, fin_w = out_h - 2 * S_ALIAS_RADIUS, out_w - 2 * S_ALIAS_RADIUS
        dst = rt.acquire(3, fin_h, fin_w)
        self._launch_named(rt, "s_alias", fin_w, fin_h, dict(
            lms=lms, lm=lm, rows=rows, dst=dst, in_w=out_w, in_h=out_h, lm_w=lm.width, lm_h=lm.height,
            lm_off=2 * rs + RI_RADIUS, rows_w=rows.width, rows_h=tone_h, out_w=fin_w, out_h=fin_h,
            s_from_m=self.s_from_m, alias_s=prm.alias_s, alias_st=prm.alias_st))
        rt.release(lms)
        rt.release(rows)
        rt.release(lm)
        return dst


def s_output_lattice(w: int, ox: int) -> np.ndarray:
    """s_output's lattice-only sums, 8 x w float32: row p < 4, column x: sum of the TENT_TAPS weights
    (float32, in tap order) over the S sites around image pixel (iy, x + ox), iy & 3 == p (LATTICE's
    closed form, ox with the CFA shift folded in); row 4 + p: the number of S sites in its 7 x 7."""
    r = RI_RADIUS
    iy, ix = np.mgrid[-r:4 + r, ox - r:ox + w + r]
    chi = (((iy + LATTICE["S_Y"]) % 2 == 0) & ((ix - iy + LATTICE["S_D"]) % 4 == 0)).astype(np.float32)
    den = np.zeros((4, w), np.float32)
    for (dy, dx), wt in zip(_support(TENT), as_f32(_weights(TENT))):
        den += np.float32(wt) * chi[r + dy:r + dy + 4, r + dx:r + dx + w]
    cnt = sum(chi[r + dy:r + dy + 4, r + dx:r + dx + w] for dy in range(-r, r + 1) for dx in range(-r, r + 1))
    return np.concatenate([den, cnt]).astype(np.float32)


def _support(k: np.ndarray, centre: bool = True) -> np.ndarray:
    """(T, 2) (dy, dx) of the non-zero taps of a centred square kernel, row order (X(...) order)."""
    r = k.shape[0] // 2
    nz = k != 0
    if not centre:
        nz[r, r] = False
    return np.argwhere(nz) - r


def _weights(k: np.ndarray, centre: bool = True) -> np.ndarray:
    """Weights of ``_support(k, centre)``, in order."""
    r = k.shape[0] // 2
    return np.array([k[dy + r, dx + r] for dy, dx in _support(k, centre)])
