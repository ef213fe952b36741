"""The paper's hybrid spatial/frequency LMS demosaic (Fig. 5) with S by a masked guided filter.

T. Singh & M. Singh, *The Case for an LMS Camera*, section "Demosaicking", Fig. 5; our reading of
it is written out below (the choices the paper leaves open: README.md). Input: the white-balanced
LMS mosaic p (H x W); output: L, M, S at every pixel ((H - 2 halo) x (W - 2 halo) x 3). With
``mod = +1 at L sites, -1 elsewhere`` (the (pi, pi) carrier, ``(-1)^(x+y)`` up to the CFA phase):

Step A, M at S sites (``m_at_s``, radius 2). Four directional estimates E_d (h, v and the two
diagonals, each the mean of the two nearest M samples on that line) and gradients G_d (h/v: |M pair|
+ |L pair|; diagonals: 2 |M pair|); ``soft``: M = sum w_d E_d / sum w_d, w_d = 1/(eps + G_d)^2,
eps = eps0 + eps_sigma * sigma (sigma: noise std of an M sample at the local level); ``hard``: the
E_d of the smallest G_d; ``iso``: mean of the four diagonal M. Then the S-detail correction
M += k (p - mean of the four S at (+-2, +-2)). Result: the L/M quincunx mosaic m.

Step B, luminance/chrominance split (``luma_lowpass`` radius 4, ``chroma_demodulate_rows`` and
``lm_combine`` radius 4 together)::

    h_lum = (1 - alpha) (delta - g5 . mod) + alpha D      lum = h_lum * m             ~ (L+M)/2
    chr   = g_c * ((m - lum) . mod)                                                   ~ (L-M)/2
    L = lum + chr,  M = lum - chr                         at every pixel

g5: 5x5 binomial, g_c: 9x9 binomial (run separably: rows with the demodulation, columns with the
combination), D: 9x9 Hamming-windowed diamond half-band filter (``diamond_halfband``; centre 1/2 and
the other taps scaled to sum 1/2, so that h_lum has the DC gain 1 and the zero at (pi, pi) it
needs; every tap scaled to sum 1 is ``exact_halfband=False``, which changes the noiseless
PSNR by <= 0.05 dB but leaves 0.0038 at (pi, pi), so a flat L != M field comes back 0.2% wrong).
At the default alpha = 0.75, h_lum is (rows y = -4..4, columns x = -4..4; 8-fold symmetric, 53 non-zero
taps, weights to 6 decimals)::

    [ 0       -.001465  0       -.001567  0       -.001567  0       -.001465  0      ]
    [-.001465  0        .008334  0        .006787  0        .008334  0       -.001465]
    [ 0        .008334 -.000977 -.027938 -.005859 -.027938 -.000977  .008334  0      ]
    [-.001567  0       -.027938 -.015625  .163486 -.015625 -.027938  0       -.001567]
    [ 0        .006787 -.005859  .163486  .589844  .163486 -.005859  .006787  0      ]
    (rows 1..4 mirror rows -1..-4)

Frequency response: 1 at DC; 0 at the (pi, pi) chroma carrier (|H| < 1e-15; with every tap scaled to
sum 1, 0.00382 = alpha * 0.00509, the windowed diamond's leak); 0.625 at (0, pi) and (pi, 0);
0.609 at (pi/2, pi/2). Flat-field noise gain sum(h^2) = 0.463 (-3.34 dB of pixel noise).

Step C, S: He et al.'s guided filter with guide I = lum and statistics over the S sites only (chi = S
indicator, box = window mean over (2r+1)^2), the masked guided filter that both LMS demosaics share
(``clisp.modules.common.guided_filter``: reference ``guided_filter``, written out as ``guided_filter_spec``;
clisp/modules/common/guided_filter.cl, run by ``enqueue_s_guided``)::

    n = box(chi); muI = box(chi I)/n; muS = box(chi S)/n
    a = (box(chi I S)/n - muI muS) / (box(chi I^2)/n - muI^2 + eps); b = muS - a muI
    S^ = box(a) I + box(b)            eps = gf_eps + noise variance of S at the level muS

computed with separable box sums: row sums of the masked moments with I centred on the row's centre
value, then column sums moved to the output pixel's centre value (exact algebra; it keeps the variance
free of float32 cancellation, see clisp/modules/common/guided_filter.cl).

or, with ``s_method='bilateral'`` (``s_joint_bilateral``), joint bilateral interpolation of S/I (or
S - I) over the S sites within radius r_b, spatial sigma sigma_s, range kernel on I with
sigma_r = max(sigma_r_min, k_r * noise std of lum).

Halo: the S and the chroma steps both start from lum, so the radii add along the longest chain:
2 (step A) + 4 (lum) + max(4 (chroma), 2 r (guided: statistics r, box of a and b r)) = 14 at r = 4;
with the bilateral option 2 + 4 + max(4, r_b) = 10.

Noise: ``noise`` (a :class:`ChannelNoise`, per-channel affine variance of a white-balanced sample) sets
eps in steps A and C and sigma_r of the bilateral option; None (default) means noiseless.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from ...cfa import CFA
from ...errors import ClispError
from ...sim.noise import NOISELESS, ChannelNoise
from ...engine.runtime import DeviceImage, Runtime, launch_exact
from ...engine.stage import Stage, as_f32
from ..common.guided_filter import MASK_S, enqueue_guided_filter, guided_filter
from ..common.lms import (NoiseFromRaw, binomial, check_lms_structure, correlate_valid, diamond_halfband,
                         lattice_shift, valid)

A_RADIUS = 2
"""Radius of step A (M at S sites): E_v reads (y +- 2, x), the S-detail correction (y +- 2, x +- 2)."""
LUM_RADIUS = 4
"""Radius of h_lum (9 x 9)."""
CHROMA_RADIUS = 4
"""Radius of the 9 x 9 binomial chroma low-pass g_c."""
SELECTS = ("soft", "hard", "iso")
S_METHODS = ("guided", "bilateral")
BILATERAL_DOMAINS = ("ratio", "difference")
i32, f32 = np.int32, np.float32
"""Kernel argument types."""


# ---------------------------------------------------------------------------------- filters

def luma_filter(alpha: float = 0.75, exact_halfband: bool = True) -> np.ndarray:
    """h_lum = (1 - alpha)(delta - g5 . mod) + alpha D, 9 x 9 (step B)."""
    r = LUM_RADIUS
    t = np.arange(-r, r + 1)
    mod = (-1.0) ** (t[:, None] + t[None, :])
    notch = np.zeros((2 * r + 1, 2 * r + 1))
    notch[r, r] = 1.0
    g5 = np.outer(binomial(5), binomial(5))
    notch[r - 2:r + 3, r - 2:r + 3] -= g5 * mod[r - 2:r + 3, r - 2:r + 3]
    return (1.0 - alpha) * notch + alpha * diamond_halfband(r, exact_halfband)


def frequency_response(h: np.ndarray, wy: float, wx: float) -> float:
    """Response of a centred, point-symmetric 2-D filter at (wy, wx) rad/px (real)."""
    r = h.shape[0] // 2
    t = np.arange(-r, r + 1)
    return float(np.sum(h * np.cos(wy * t[:, None] + wx * t[None, :])))


# ---------------------------------------------------------------------------------- parameters



@dataclass(frozen=True)
class LMSHybridParams:
    """Parameters of :class:`DemosaicLMSHybrid`; defaults are our choices where the paper is silent (README.md).

    Units: signal values are white-balanced normalised raw (white ~ 1); radii in pixels.
    """

    select: Literal["soft", "hard", "iso"] = "soft"
    """Step A direction choice: soft weights 1/(eps+G)^2, hard argmin G, or iso (diagonal mean)."""
    eps0: float = 1e-3
    """Step A: eps floor of the soft weights (signal units)."""
    eps_sigma: float = 2.0
    """Step A: eps grows by this many noise standard deviations of an M sample."""
    s_detail: float = 0.25
    """Step A: k of the S-detail correction M += k (S - mean of the 4 S at (+-2, +-2)); 0 disables."""
    alpha: float = 0.75
    """Step B: blend of the (pi, pi) notch (0) and the diamond half-band (1) in h_lum."""
    exact_halfband: bool = True
    """Step B: normalise D as a true half-band filter (0 at (pi, pi)); False: every tap scaled to sum 1."""
    s_method: Literal["guided", "bilateral"] = "guided"
    """Step C: masked guided filter (default) or joint bilateral interpolation."""
    gf_radius: int = 4
    """Step C guided: window radius r of the statistics and of the box of a, b (px)."""
    gf_eps: float = 1e-4
    """Step C guided: regulariser (signal units^2), plus the S noise variance at the local level."""
    bl_radius: int = 4
    """Step C bilateral: radius of the S sites used (px)."""
    bl_sigma_s: float = 2.0
    """Step C bilateral: spatial sigma (px)."""
    bl_sigma_r: float = 2.5
    """Step C bilateral: range sigma in units of the luminance noise std."""
    bl_sigma_r_min: float = 0.02
    """Step C bilateral: smallest range sigma (signal units), used when noiseless [decision]."""
    bl_domain: Literal["ratio", "difference"] = "ratio"
    """Step C bilateral: interpolate S/I (ratio) or S - I (difference), then reapply I."""
    bl_ratio_floor: float = 1e-3
    """Step C bilateral: I is clamped to at least this before dividing (signal units)."""

    def __post_init__(self) -> None:
        if self.select not in SELECTS:
            raise ClispError(f"select must be one of {SELECTS}, got {self.select!r}")
        if self.s_method not in S_METHODS:
            raise ClispError(f"s_method must be one of {S_METHODS}, got {self.s_method!r}")
        if self.bl_domain not in BILATERAL_DOMAINS:
            raise ClispError(f"bl_domain must be one of {BILATERAL_DOMAINS}, got {self.bl_domain!r}")
        if self.gf_radius < 2 or self.bl_radius < 2:
            raise ClispError("S radii must be >= 2 px (the S covering radius of the LMS CFA)")
        if self.eps0 <= 0 or self.gf_eps <= 0 or self.bl_sigma_s <= 0 or self.bl_sigma_r_min <= 0:
            raise ClispError("eps0, gf_eps, bl_sigma_s and bl_sigma_r_min must be > 0")

    @property
    def s_radius(self) -> int:
        """Radius of step C on lum: 2r for the guided filter, r_b for the bilateral."""
        return 2 * self.gf_radius if self.s_method == "guided" else self.bl_radius


# ---------------------------------------------------------------------------------- helpers







def site_table(cfa: CFA, channel: int, radius: int) -> tuple[np.ndarray, np.ndarray]:
    """Offsets of the ``channel`` sites within Chebyshev ``radius`` of a pixel of each CFA phase.

    Returns (offsets (P*P, N, 2) int32 (dy, dx), padded with zeros; counts (P*P,) int32), phase
    k = py * P + px of the centre. Sites are listed in row order.
    """
    p = cfa.period
    lists = []
    for py in range(p):
        for px in range(p):
            lists.append([(dy, dx) for dy in range(-radius, radius + 1) for dx in range(-radius, radius + 1)
                          if cfa.pattern[(py + dy) % p, (px + dx) % p] == channel])
    n = max(len(v) for v in lists)
    offsets = np.zeros((p * p, n, 2), dtype=np.int32)
    for k, v in enumerate(lists):
        offsets[k, :len(v)] = v
    return offsets, np.array([len(v) for v in lists], dtype=np.int32)


# ---------------------------------------------------------------------------------- reference steps
# One function per kernel, same names. Inputs and outputs are float64 windows; ``channel`` is the CFA
# channel map of the function's input window (cfa.channel_map(H, W, origin)).

def m_at_s(p: np.ndarray, channel: np.ndarray, ch_s: int, params: LMSHybridParams,
           noise: ChannelNoise, ch_m: int) -> np.ndarray:
    """Step A: the L/M quincunx m, (H-4) x (W-4): p where not S; M estimated at S sites."""
    def at(dy: int, dx: int) -> np.ndarray:
        return valid(p, A_RADIUS, dy, dx)

    estimates = np.stack([(at(0, -2) + at(0, 2)) / 2, (at(-2, 0) + at(2, 0)) / 2,
                          (at(-1, -1) + at(1, 1)) / 2, (at(-1, 1) + at(1, -1)) / 2])
    gradients = np.stack([np.abs(at(0, -2) - at(0, 2)) + np.abs(at(0, -1) - at(0, 1)),
                          np.abs(at(-2, 0) - at(2, 0)) + np.abs(at(-1, 0) - at(1, 0)),
                          2 * np.abs(at(-1, -1) - at(1, 1)),
                          2 * np.abs(at(-1, 1) - at(1, -1))])
    iso = (estimates[2] + estimates[3]) / 2
    if params.select == "soft":
        sigma = np.sqrt(noise.variance(ch_m, iso))
        weights = 1.0 / (params.eps0 + params.eps_sigma * sigma + gradients) ** 2
        m_est = np.sum(weights * estimates, axis=0) / np.sum(weights, axis=0)
    elif params.select == "hard":
        m_est = np.take_along_axis(estimates, np.argmin(gradients, axis=0)[None], axis=0)[0]
    else:
        m_est = iso
    s_mean = (at(-2, -2) + at(-2, 2) + at(2, -2) + at(2, 2)) / 4
    m_est = m_est + params.s_detail * (at(0, 0) - s_mean)
    return np.where(valid(channel, A_RADIUS) == ch_s, m_est, at(0, 0))


def luma_lowpass(m: np.ndarray, h_lum: np.ndarray) -> np.ndarray:
    """Step B: lum = h_lum * m, (H-8) x (W-8)."""
    return correlate_valid(m, h_lum)


def chroma_demodulate_rows(m: np.ndarray, lum: np.ndarray, mod: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Step B, first half of chr: the demodulated (m - lum) mod low-passed along rows with g (1-D).

    m, mod: the window of lum grown by LUM_RADIUS (m's own window); returns lum's rows x (cols - 2R).
    """
    r = len(g) // 2
    d = (valid(m, LUM_RADIUS) - lum) * valid(mod, LUM_RADIUS)
    return sum(g[k + r] * d[:, r + k:d.shape[1] - r + k] for k in range(-r, r + 1))


def lm_combine(lum: np.ndarray, rows: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Step B, second half: chr = column low-pass of ``rows``; returns (L, M) = lum +- chr, shape
    (H-2R) x (W-2R) x 2 for lum H x W and rows (H) x (W-2R)."""
    r = len(g) // 2
    chr_ = sum(g[k + r] * rows[r + k:rows.shape[0] - r + k] for k in range(-r, r + 1))
    centre = lum[r:lum.shape[0] - r, r:lum.shape[1] - r]
    return np.stack([centre + chr_, centre - chr_], axis=-1)


def s_joint_bilateral(lum: np.ndarray, p: np.ndarray, is_s: np.ndarray, params: LMSHybridParams,
                      lum_noise_gain: float, noise: ChannelNoise, ch_l: int, ch_m: int) -> np.ndarray:
    """Step C option: joint bilateral interpolation of S/I (or S - I) over the S sites within r_b.

    Weights exp(e - max e), e = -d^2/(2 sigma_s^2) - (I_q - I)^2/(2 sigma_r^2): the usual bilateral
    weights scaled per pixel so that the largest is 1 (same result, no underflow)."""
    r = params.bl_radius
    centre = valid(lum, r)
    var_lm = 0.5 * (noise.variance(ch_l, centre) + noise.variance(ch_m, centre))
    sigma_r = np.maximum(params.bl_sigma_r_min, params.bl_sigma_r * np.sqrt(lum_noise_gain * var_lm))
    exponents, values = [], []
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            guide = valid(lum, r, dy, dx)
            sample = valid(p, r, dy, dx)
            if params.bl_domain == "ratio":
                values.append(sample / np.maximum(guide, params.bl_ratio_floor))
            else:
                values.append(sample - guide)
            exponents.append(np.where(valid(is_s, r, dy, dx),
                                      -(dy * dy + dx * dx) / (2 * params.bl_sigma_s ** 2)
                                      - (guide - centre) ** 2 / (2 * sigma_r ** 2), -np.inf))
    e = np.stack(exponents)
    w = np.exp(e - e.max(axis=0))                 # largest weight 1 per pixel: no 0/0 underflow
    num = np.sum(w * np.stack(values), axis=0)
    den = np.sum(w, axis=0)
    ratio = num / den
    if params.bl_domain == "ratio":
        return centre * ratio
    return centre + ratio


# ---------------------------------------------------------------------------------- the stage

@dataclass
class DemosaicLMSHybrid(NoiseFromRaw, Stage):
    """LMS mosaic (white-balanced, H x W) -> L, M, S ((H-2 halo) x (W-2 halo) x 3); see module doc.

    A flat field (L != M != S) comes back exactly:

    >>> from clisp.cfa import lms_cfa
    >>> stage = DemosaicLMSHybrid(lms_cfa())
    >>> mosaic = np.array([0.6, 0.45, 0.3])[lms_cfa().channel_map(33, 35)]
    >>> out = stage.reference(mosaic, (0, 0))
    >>> out.shape, stage.halo, bool(np.allclose(out, [0.6, 0.45, 0.3], rtol=0, atol=1e-12))
    ((5, 7, 3), 14, True)
    """

    cfa: CFA
    params: LMSHybridParams = field(default_factory=LMSHybridParams)
    noise: ChannelNoise | None = None
    name = "demosaic_lms_hybrid"
    cfa_kinds = ("lms",)
    in_channels = 1
    out_channels = 3

    def __post_init__(self) -> None:
        self.ch_l, self.ch_m, self.ch_s = check_lms_structure(self.cfa, "LMS hybrid demosaic")
        self.shift = lattice_shift(self.cfa, self.ch_l, self.ch_s)      # for the guided filter's kernels
        self.h_lum = luma_filter(self.params.alpha, self.params.exact_halfband)
        self.g_c = binomial(2 * CHROMA_RADIUS + 1)
        self.lum_support = np.argwhere(self.h_lum != 0) - LUM_RADIUS     # (dy, dx), row order
        self.site_offsets, self.site_counts = site_table(self.cfa, self.ch_s, self.params.bl_radius)

    @property
    def pixel_noise(self) -> ChannelNoise:
        return NOISELESS if self.noise is None else self.noise

    @property
    def halo(self) -> int:
        return A_RADIUS + LUM_RADIUS + max(CHROMA_RADIUS, self.params.s_radius)

    @property
    def bytes_per_pixel(self) -> float:
        """Device bytes per input pixel kept in the pool (for the tile planner): float32 planes m,
        lum, chroma rows and the 3 output planes; the guided filter adds 5 moment, 2 (a, b) and
        2 row-sum planes. Upper bound: every plane counted at the input window's size."""
        planes = 1 + 1 + 1 + 3 + (5 + 2 + 2 if self.params.s_method == "guided" else 0)
        return 4.0 * planes

    # -- reference ------------------------------------------------------------------------------
    def reference(self, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
        prm, noise, big_r = self.params, self.pixel_noise, self.halo
        p = x.astype(np.float64)
        channel = self.cfa.channel_map(p.shape[0], p.shape[1], origin)
        mod = np.where(channel == self.ch_l, 1.0, -1.0)
        m = m_at_s(p, channel, self.ch_s, prm, noise, self.ch_m)
        lum = luma_lowpass(m, self.h_lum)                         # frame offset 6
        o_lum = A_RADIUS + LUM_RADIUS
        c0 = big_r - CHROMA_RADIUS - o_lum                         # lum rows/cols used by chroma
        lum_c = lum[c0:lum.shape[0] - c0, c0:lum.shape[1] - c0]
        m_c = valid(m, c0)
        mod_c = valid(mod, c0 + A_RADIUS)
        rows = chroma_demodulate_rows(m_c, lum_c, mod_c, self.g_c)
        lm = lm_combine(lum_c, rows, self.g_c)
        s0 = big_r - prm.s_radius - o_lum                          # lum rows/cols used by S
        lum_s = lum[s0:lum.shape[0] - s0, s0:lum.shape[1] - s0]
        p_s = valid(p, s0 + o_lum)
        is_s = valid(channel, s0 + o_lum) == self.ch_s
        if prm.s_method == "guided":
            s = guided_filter(lum_s, p_s, is_s, prm.gf_radius, prm.gf_eps, noise.shot[self.ch_s],
                              noise.floor[self.ch_s], False)
        else:
            s = s_joint_bilateral(lum_s, p_s, is_s, prm, float(np.sum(self.h_lum ** 2)), noise,
                                  self.ch_l, self.ch_m)
        return np.concatenate([lm, s[..., None]], axis=-1)

    # -- OpenCL ---------------------------------------------------------------------------------
    def defines(self) -> dict[str, int | float]:
        """Compile-time constants of clisp/modules/demosaic_lms/demosaic_lms.cl (see its header)."""
        select = SELECTS.index(self.params.select)
        return {"CFA_PERIOD": self.cfa.period, "CH_L": self.ch_l, "CH_M": self.ch_m, "CH_S": self.ch_s,
                "SELECT": select, "NOISY": int(self.noise is not None), "LUM_R": LUM_RADIUS,
                "CHROMA_R": CHROMA_RADIUS, "BL_R": self.params.bl_radius,
                "BL_RATIO": int(self.params.bl_domain == "ratio"),
                "MAX_SITES": self.site_offsets.shape[1]}

    def generated_source(self) -> str:
        """``LUM_SUPPORT``: X(dy, dx, t) for each non-zero tap t of h_lum (structure, not weights)."""
        taps = " ".join(f"X({dy}, {dx}, {t})" for t, (dy, dx) in enumerate(self.lum_support))
        return f"/* generated by clisp: support of h_lum */\n#define LUM_SUPPORT {taps}\n"

    def _launch(self, rt: Runtime, kernel_name: str, width: int, height: int, *args: object) -> None:
        """Enqueue ``kernel_name`` of clisp/modules/demosaic_lms/demosaic_lms.cl over exactly width x height outputs
        (``runtime.launch_exact``: no bounds checks in the kernels, one command: their coordinates from
        common.h's inward_id)."""
        kernel = rt.kernel("demosaic_lms", kernel_name, self.defines(), self.generated_source())
        launch_exact(rt, kernel, width, height, *args, inward=True)

    def _launch_named(self, rt: Runtime, kernel_name: str, width: int, height: int, args: dict[str, object]) -> None:
        """Enqueue ``kernel_name`` with its arguments by name (``Runtime.launch_named``)."""
        rt.launch_named("demosaic_lms", kernel_name, width, height, args, self.defines(), self.generated_source(),
                        inward=True)

    def _noise_args(self, channel: int) -> tuple[np.float32, np.float32]:
        """(shot, floor) of ``channel`` as kernel arguments."""
        n = self.pixel_noise
        return f32(n.shot[channel]), f32(n.floor[channel])

    def _sites(self, rt: Runtime) -> tuple[object, object]:
        """Device constants of the S sites within the bilateral radius per CFA phase: offsets
        (dy, dx) padded to MAX_SITES, and 1/0 weights marking the real entries."""
        n = self.site_offsets.shape[1]
        real = (np.arange(n)[None, :] < self.site_counts[:, None])
        return rt.constant(self.site_offsets), rt.constant(as_f32(real))

    def enqueue_m_at_s(self, rt: Runtime, src: DeviceImage, origin: tuple[int, int]) -> DeviceImage:
        """Step A: p (H x W, pixel (0, 0) = image pixel ``origin``) -> m ((H-4) x (W-4))."""
        prm = self.params
        h, w = src.height - 2 * A_RADIUS, src.width - 2 * A_RADIUS
        dst = rt.acquire(1, h, w)
        shot, floor = self._noise_args(self.ch_m)
        self._launch_named(rt, "m_at_s", w, h, dict(
            p=src, m=dst, in_w=src.width, out_w=w, out_h=h, oy=origin[0], ox=origin[1],
            pattern=rt.constant(self.cfa.pattern), eps0=prm.eps0, eps_sigma=prm.eps_sigma, s_detail=prm.s_detail,
            shot_m=shot, floor_m=floor))
        return dst

    def enqueue_luma_lowpass(self, rt: Runtime, m: DeviceImage) -> DeviceImage:
        """Step B luminance: m -> lum, shrunk by LUM_RADIUS."""
        h, w = m.height - 2 * LUM_RADIUS, m.width - 2 * LUM_RADIUS
        dst = rt.acquire(1, h, w)
        weights = self.h_lum[tuple((self.lum_support + LUM_RADIUS).T)]
        self._launch(rt, "luma_lowpass", w, h, m.buffer, dst.buffer, i32(m.width), i32(w), i32(h),
                     rt.constant(as_f32(weights)))
        return dst

    def enqueue_chroma_demodulate_rows(self, rt: Runtime, m: DeviceImage, lum: DeviceImage,
                                       lum_origin: tuple[int, int], out_h: int, out_w: int,
                                       at: tuple[int, int]) -> DeviceImage:
        """Step B chroma, rows: output (y, x) is the row low-pass centred on lum (y + at[0], x + at[1]);
        lum (0, 0) is image pixel ``lum_origin``; m is lum's window grown by LUM_RADIUS."""
        dst = rt.acquire(1, out_h, out_w)
        self._launch_named(rt, "chroma_demodulate_rows", out_w, out_h, dict(
            m=m, lum=lum, rows=dst, m_w=m.width, lum_w=lum.width, out_w=out_w, out_h=out_h, at_y=at[0], at_x=at[1],
            oy=lum_origin[0], ox=lum_origin[1], pattern=rt.constant(self.cfa.pattern), g=rt.constant(as_f32(self.g_c))))
        return dst

    def enqueue_lm_combine(self, rt: Runtime, lum: DeviceImage, rows: DeviceImage, dst: DeviceImage,
                           at: tuple[int, int]) -> None:
        """Step B combine: planes 0, 1 (L, M) of ``dst``; dst (y, x) is lum (y + at), rows (y + 4, x)."""
        self._launch(rt, "lm_combine", dst.width, dst.height, lum.buffer, rows.buffer, dst.buffer,
                     i32(lum.width), i32(rows.width), i32(dst.width), i32(dst.height), i32(at[0]), i32(at[1]),
                     rt.constant(as_f32(self.g_c)))

    def enqueue_s_guided(self, rt: Runtime, lum: DeviceImage, src: DeviceImage, dst: DeviceImage,
                         lum_origin: tuple[int, int], at: int, src_at: int) -> None:
        """Step C: the masked guided filter (``guided_filter``) of S over the S sites against lum into
        plane 2 of ``dst``; dst (y, x) is lum (y + at, x + at) and src (y + src_at, x + src_at); lum (0, 0)
        is image pixel ``lum_origin``."""
        r, o = self.params.gf_radius, at - 2 * self.params.gf_radius     # the filter's window in lum
        enqueue_guided_filter(rt, (dst.height + 4 * r, dst.width + 4 * r), (lum_origin[0] + o, lum_origin[1] + o),
                              self.shift, lum, o, src, src_at - 2 * r, r, MASK_S, self.params.gf_eps,
                              self._noise_args(self.ch_s), False, out=(dst, 2))

    def enqueue_s_joint_bilateral(self, rt: Runtime, lum: DeviceImage, src: DeviceImage, dst: DeviceImage,
                                  lum_origin: tuple[int, int], at: tuple[int, int],
                                  src_at: tuple[int, int]) -> None:
        """Step C option: plane 2 (S) of ``dst``; dst (y, x) is lum (y + at) and src (y + src_at)."""
        prm, noise = self.params, self.pixel_noise
        gain = float(np.sum(self.h_lum ** 2))                 # lum noise variance / pixel variance
        lum_shot = gain * 0.5 * (noise.shot[self.ch_l] + noise.shot[self.ch_m])
        lum_floor = gain * 0.5 * (noise.floor[self.ch_l] + noise.floor[self.ch_m])
        site, site_w = self._sites(rt)
        self._launch_named(rt, "s_joint_bilateral", dst.width, dst.height, dict(
            lum=lum, p=src, dst=dst, lum_w=lum.width, p_w=src.width, out_w=dst.width, out_h=dst.height, at_y=at[0],
            at_x=at[1], p_y=src_at[0], p_x=src_at[1], oy=lum_origin[0] + at[0], ox=lum_origin[1] + at[1], site=site,
            site_w=site_w, inv_2ss=f32(1.0 / (2 * prm.bl_sigma_s ** 2)), sr_k=prm.bl_sigma_r,
            sr_min=prm.bl_sigma_r_min, ratio_floor=prm.bl_ratio_floor, lum_shot=lum_shot, lum_floor=lum_floor))

    def enqueue(self, rt: Runtime, src: DeviceImage, origin: tuple[int, int]) -> DeviceImage:
        """Steps A, B, C on the device. Each intermediate covers only what the output needs:
        m the window less 2, lum less 6 (= A + LUM), chroma rows and the guided filter's planes
        just the output grown by their remaining radii."""
        prm, big_r = self.params, self.halo
        out_h, out_w = self.output_shape(src.height, src.width)
        o_lum = A_RADIUS + LUM_RADIUS                                    # lum (0, 0) in the window
        lum_origin = (origin[0] + o_lum, origin[1] + o_lum)
        at = big_r - o_lum                                               # output (0, 0) in lum
        m = self.enqueue_m_at_s(rt, src, origin)
        lum = self.enqueue_luma_lowpass(rt, m)
        dst = rt.acquire(3, out_h, out_w)
        rows = self.enqueue_chroma_demodulate_rows(rt, m, lum, lum_origin, out_h + 2 * CHROMA_RADIUS, out_w,
                                                   (at - CHROMA_RADIUS, at))
        self.enqueue_lm_combine(rt, lum, rows, dst, (at, at))
        rt.release(rows)
        rt.release(m)
        if prm.s_method == "guided":
            self.enqueue_s_guided(rt, lum, src, dst, lum_origin, at, big_r)
        else:
            self.enqueue_s_joint_bilateral(rt, lum, src, dst, lum_origin, (at, at), (big_r, big_r))
        rt.release(lum)
        return dst
