"""Luminance-guided multiresolution chroma denoising, replacing the colour matrix.

The paper (section "Chrominance Denoising") converts white-balanced camera channels to a
luminance and chrominance space, denoises only the chrominance, and converts to sRGB::

    LMS   (paper):  RGB = P cam,  Y = (L + M) / 2,  c_k = RGB_k - Y  (k = R, G, B),  RGB_k = Y + c^_k
    Bayer (paper's baseline): RGB = B cam,  BT.601  Y = .299 R + .587 G + .114 B,
                    U = .492 (B - Y),  V = .877 (R - Y),  denoise U, V,  invert

Both are a :class:`ChromaSpace`: Y = luma . cam, c = chroma . cam, RGB = from_luma Y + from_chroma c^.
With c^ = c the stage is exactly the colour matrix. Y is never modified.

Denoiser: Zhang & Gunturk's multiresolution bilateral filter (M. Zhang, B. K. Gunturk,
"Multiresolution bilateral filtering for image denoising", IEEE TIP 17(12), 2324-2333, 2008), made
luminance-guided: every bilateral's range weight also uses Y, decomposed in the same pyramid.
Per chroma channel k and level j = J .. 1, from the coarsest::

    a_j, (dx_j, dy_j, dd_j) = Haar analysis of a_{j-1}            (a_0 = c_k; block means, see below)
    a_j <- joint_bilateral(a_j; Y_j)                              radius r at level j
    d_j <- bayes_shrink(d_j)                                      local window radius r_w at level j
    a_{j-1} = Haar synthesis (a_j, d_j)
    c^_k = joint_bilateral(a_0; Y_0)                              final full-resolution pass

    joint_bilateral: out(p) = sum_q w(p,q) a(q) / sum_q w(p,q) over |q - p|_inf <= r,
      w(p,q) = exp(-|p-q|^2 / 2 sd^2 - (Y_p - Y_q)^2 / 2 sY(p)^2 - (a_p - a_q)^2 / 2 sc(p)^2),
      sY = k_Y sigma_Y,j(Y_p),  sc = k_c s_k sigma_k,j(Y_p)     (floored at sigma_floor)
      range_joint > 0 (levels j >= 1, both spaces by default): one w for every chroma plane, its
      chroma term the Mahalanobis distance of the planes' differences in noise sigmas
      (ChromaDenoise.range_metric; issue 17)
    bayes_shrink (BayesShrink, Chang, Yu & Vetterli, IEEE TIP 9(9), 2000, with a local variance):
      sigma_n = s_k sigma_k,j,o(Y_j),  E = mean of d^2 over the (2 r_w + 1)^2 window,
      sigma_x = sqrt(max(E - sigma_n^2, 0)),  T = sigma_n^2 / sigma_x (T = inf when sigma_x = 0),
      d' = sign(d) max(|d| - T, 0);  luminance-guided [decision]: d'' = d' + g_Y (d - d') with
      g_Y = var_xY / (var_xY + var_nY), the local Wiener gain of the Y detail of the same subband:
      chroma detail is kept where the luminance has structure (edges), shrunk where it is flat.

The Y guide in the bilateral is worth +0.3..1.5 dB PSNR over the plain bilateral (k_luma = 0). The
pyramid is a decimated Haar one: about 1.3 full-resolution bilateral passes (an undecimated a-trous
pyramid would cost J + 1), and it tiles exactly (below). Measured choices and history: README.md.

Haar, normalised so approximations are block means (orthogonal up to a factor 2 per level)::

    a = (x00 + x01 + x10 + x11)/4    dx = (x00 - x01 + x10 - x11)/4
    dy = (x00 + x01 - x10 - x11)/4   dd = (x00 - x01 - x10 + x11)/4

Noise levels sigma_{.,j}(s) are not estimated per image from the subbands (a global median would
break tiling): they come from a :class:`NoiseTable`, the variance of Y and of each chroma
approximation and detail subband at every level as an affine function of the local luminance s, measured once per pipeline by :func:`calibrate_noise` on flat fields pushed through
the actual demosaic with the raw's noise (:mod:`clisp.scene.noise`). No noise -> every sigma is
0 -> the stage is the colour matrix (to rounding).

Tiling. The decimation grid is anchored to image coordinates: blocks of level j start at multiples
of 2^j, so a window whose origin is not a multiple of ``align`` = 2^J first skips to the next
multiple. Each level's bilateral eats r pixels of that level, so the valid margin grows as
m_J = r, m_j = 2 m_{j+1} + r, m_0 = r (2^(J+1) - 1); halo = m_0 + 2^J - 1 covers any origin
(52 px at J = 3, r = 3). Output for a pixel depends only on image coordinates, so tiled output
equals whole-image output for tiles at any origin (multiples of ``align`` waste the least).
"""
from __future__ import annotations

import hashlib
import io
import pickle
import zipfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Sequence

import numpy as np

from ...errors import ClispError
from ...engine.disk_cache import cache_dir, device_identity, entry_name, keep_bytes
from ...engine.profile import stage_label
from ...engine.runtime import DeviceImage, Runtime
from ...engine.stage import Stage, as_f32
from ...sim.colorimetry import SRGB_ENCODING
from ..colour.stage import ColourMatrix, ToneCurve, srgb_source

BT601 = np.array([0.299, 0.587, 0.114])
"""BT.601 luma weights of R, G, B."""
U_SCALE, V_SCALE = 0.492, 0.877
"""BT.601 U = 0.492 (B - Y), V = 0.877 (R - Y)."""
ORIENTATIONS = ("dx", "dy", "dd")

CHROMA_RANGE_CAP: dict[str, float | None] = {"yuv": 0.027, "lms": None, "rgb-cfa": 0.032, "rgb-snr": 0.032,
                                              "lms-cfa": None, "lms-snr": None}
"""Default ``chroma_range_cap`` per chroma space (ChromaDenoiseParams). Bayer (YUV): 0.027 keeps
k_chroma = 2 up to gain 16 and lowers it to 0.98 at gain 64, where it averaged across isoluminant
colour edges (ring colour shift 1.45/5.81 -> ~1.0/2.3 at -0.05 dB PSNR; README.md). LMS: none yet
(its shift comes from the guided demosaic). The other luminances (LUMAS, issue 45) take their
camera's: for RGB the YUV cap times 1.18, the ratio of the difference planes' mid-grey chroma noise
to U and V's after RI (sigma_0 0.0279 against 0.0236 at gain 16, 0.0594 against 0.0502 at 64), so
the cap bites at the same noise."""
CORR_CUT = 1e-2
"""Eigenvalues of a noise correlation matrix below this share of the largest are left out of the
range metric's pseudo-inverse: LMS's R-Y, G-Y, B-Y have 2 noise sources, and the third
eigenvalue (about 1e-4, from the colour matrix not being exactly white-preserving) would
otherwise weigh its direction 100x."""
RANGE_JOINT_SIGMA: dict[str, tuple[float, float]] = {"yuv": (0.0, 0.0), "lms": (0.015, 0.03),
                                                     "rgb-cfa": (0.0, 0.0), "rgb-snr": (0.0, 0.0),
                                                     "lms-cfa": (0.015, 0.03), "lms-snr": (0.015, 0.03)}
"""Default ``range_joint_sigma`` per chroma space. LMS: off up to sigma_0 0.015 (gain ~12 on the
simulated sensor), in full from 0.03 (gain ~45): where the noise is low the planes' own range terms
already keep colour edges, and the joint term held back the smoothing (README.md). Bayer: in full
at every gain. The other luminances (LUMAS) take their camera's (LMS or YUV)."""
RANGE_JOINT: dict[str, float] = {"yuv": 1.0, "lms": 2.0, "rgb-cfa": 1.0, "rgb-snr": 1.0, "lms-cfa": 2.0,
                                 "lms-snr": 2.0}
"""Default ``range_joint`` per chroma space (ChromaDenoiseParams): the coarse levels' joint range
term, a Mahalanobis distance of the chroma planes in k_chroma noise sigmas (range_metric).
Bayer 1, LMS 2 (faded in by RANGE_JOINT_SIGMA): worst ring colour shift at gain 64 2.27 -> 1.81
and 4.46 -> 2.57 (README.md, with the values not taken). The other luminances take their camera's."""
SHRINK_RULES = ("soft", "wiener", "none")


# ---------------------------------------------------------------------------------- colour spaces

@dataclass(frozen=True)
class ChromaSpace:
    """Linear maps of the denoiser's colour space; ``cam`` = white-balanced camera channels.

    to_rgb       (3, 3) camera -> linear sRGB (the colour matrix this stage replaces).
    luma         (3,) Y = luma . cam.
    chroma       (n, 3) c = chroma @ cam, n chroma channels.
    from_luma    (3,) and from_chroma (3, n): RGB = from_luma Y + from_chroma c.
    strengths    (n,) default per-channel denoising strengths s_k.
    names        chroma channel names.
    """

    name: str
    to_rgb: np.ndarray
    luma: np.ndarray
    chroma: np.ndarray
    from_luma: np.ndarray
    from_chroma: np.ndarray
    strengths: tuple[float, ...]
    names: tuple[str, ...]

    @property
    def n_chroma(self) -> int:
        return int(self.chroma.shape[0])

    @property
    def split_matrix(self) -> np.ndarray:
        """(1 + n, 3): rows luma, chroma_1 .. chroma_n."""
        return np.vstack([self.luma[None, :], self.chroma])

    @property
    def merge_matrix(self) -> np.ndarray:
        """(3, 1 + n): columns from_luma, from_chroma."""
        return np.hstack([self.from_luma[:, None], self.from_chroma])


def difference_space(matrix: np.ndarray, luma: Sequence[float], name: str,
                     strengths: Sequence[float] = (1.0, 1.0, 1.5)) -> ChromaSpace:
    """The paper's LMS construction for any luminance: Y = luma . cam, c_k = (M cam)_k - Y for
    k = R, G, B (M = ``matrix``); RGB_k = Y + c_k. Three chroma planes of rank 2."""
    p = np.asarray(matrix, dtype=np.float64)
    luma = np.asarray(luma, dtype=np.float64)
    return ChromaSpace(name, p, luma, p - np.outer(np.ones(3), luma), np.ones(3), np.eye(3),
                       tuple(float(s) for s in strengths), ("R-Y", "G-Y", "B-Y"))


def lms_space(matrix: np.ndarray, strengths: Sequence[float] = (1.0, 1.0, 1.5)) -> ChromaSpace:
    """Paper's LMS space: Y = (L + M)/2, c_k = (P cam)_k - Y for k = R, G, B; RGB_k = Y + c_k."""
    return difference_space(matrix, (0.5, 0.5, 0.0), "lms", strengths)


def yuv_space(matrix: np.ndarray, strengths: Sequence[float] = (1.5, 1.0)) -> ChromaSpace:
    """BT.601 YUV of RGB = matrix cam (the paper's Bayer baseline); chroma (U, V)."""
    b = np.asarray(matrix, dtype=np.float64)
    e_r, e_b = np.eye(3)[0], np.eye(3)[2]
    luma = BT601 @ b
    chroma = np.stack([U_SCALE * (e_b - BT601) @ b, V_SCALE * (e_r - BT601) @ b])
    # R = Y + V/.877, B = Y + U/.492, G = (Y - .299 R - .114 B)/.587
    from_chroma = np.array([[0.0, 1.0 / V_SCALE],
                            [-BT601[2] / (BT601[1] * U_SCALE), -BT601[0] / (BT601[1] * V_SCALE)],
                            [1.0 / U_SCALE, 0.0]])
    return ChromaSpace("yuv", b, luma, chroma, np.ones(3), from_chroma,
                       tuple(float(s) for s in strengths), ("U", "V"))


def space_for(kind: str, matrix: np.ndarray, strengths: Sequence[float] | None = None) -> ChromaSpace:
    """The paper's space for a CFA's spectral kind (clisp.cfa ``CFA.spectral``): 'lms' -> :func:`lms_space`,
    'rgb' -> :func:`yuv_space`; 'bayer' is accepted for 'rgb' (the kind of the RGB Bayer CFA)."""
    make = {"lms": lms_space, "rgb": yuv_space, "bayer": yuv_space}.get(kind)
    if make is None:
        raise ClispError(f"no chroma space for CFA kind {kind!r}")
    return make(matrix) if strengths is None else make(matrix, strengths)


LUMAS = ("paper", "cfa", "snr")
"""The chroma denoiser's luminance (ChromaDenoiseParams.luma, :func:`space_for_cfa`; issue 45):
'paper' the paper's space of the CFA's channels (LMS Y = (L + M) / 2, Bayer BT.601 YUV); 'cfa' the
CFA's baseband luminance, each channel weighted by its share of the pixels (the mosaic's DC
carrier: Bayer (R + 2 G + B) / 4, the LMS CFA (4 L + 3 M + S) / 8, ``ML/LS`` (2 L + M + S) / 4):
the luminance every sample carries; 'snr' the same shares divided by the channels' white-balance
gains (in white-balanced units a channel's shot-noise variance is its gain times the signal, so
these weights give the least-noise mix of the samples on grey: the luminance with the most signal
for its noise). Both in :func:`difference_space`'s form, named '<spectral>-<luma>'."""


def luma_weights(cfa, luma: str, gains: Sequence[float] | None = None) -> np.ndarray:
    """(3,) weights on the white-balanced camera channels of ``cfa`` for LUMAS' 'cfa' (the channels'
    shares of the pixels) or 'snr' (shares / pass-1 ``gains``, normalised to sum 1).

    >>> from clisp.cfa import bayer_cfa
    >>> luma_weights(bayer_cfa(), "cfa").tolist()
    [0.25, 0.5, 0.25]
    >>> np.round(luma_weights(bayer_cfa(), "snr", (2.0, 1.0, 2.0)), 4).tolist()
    [0.1667, 0.6667, 0.1667]
    """
    w = np.asarray(cfa.densities(), dtype=np.float64)
    if luma == "snr":
        g = np.ones(len(w)) if gains is None else np.asarray(gains, dtype=np.float64)
        w = w / g
    elif luma != "cfa":
        raise ClispError(f"no luminance weights for luma {luma!r}; expected cfa or snr")
    return w / w.sum()


def space_for_cfa(cfa, matrix: np.ndarray, luma: str = "paper", gains: Sequence[float] | None = None,
                  strengths: Sequence[float] | None = None) -> ChromaSpace:
    """The chroma denoiser's space for ``cfa`` (its channels and, for 'cfa' and 'snr', its layout) with
    the luminance ``luma`` (LUMAS); ``gains``: the raw's white balance pass 1 (for 'snr')."""
    if luma == "paper":
        return space_for(cfa.spectral, matrix, strengths)
    if luma not in LUMAS:
        raise ClispError(f"unknown chroma denoise luma {luma!r}; expected one of {', '.join(LUMAS)}")
    if cfa.spectral not in ("lms", "rgb"):
        raise ClispError(f"no chroma space for CFA kind {cfa.spectral!r}")
    name = f"{cfa.spectral}-{luma}"
    weights = luma_weights(cfa, luma, gains)
    return difference_space(matrix, weights, name) if strengths is None else \
        difference_space(matrix, weights, name, strengths)


# ---------------------------------------------------------------------------------- parameters

@dataclass(frozen=True)
class ChromaDenoiseParams:
    """Parameters of :class:`ChromaDenoise`; defaults are our choices where the paper is silent (README.md).

    Units: signal values are linear (white ~ 1); radii and sigma_d in pixels of the level.
    """

    levels: int = 3
    """J, number of Haar levels (align = 2^J; halo grows as r 2^(J+1))."""
    radius: int = 3
    """Bilateral window radius r at every level (px of that level)."""
    sigma_d: float = 1.8
    """Bilateral spatial sigma (px of that level)."""
    k_chroma: float = 2.0
    """Chroma range sigma = k_chroma * s_k * chroma noise std at the level (Zhang & Gunturk: ~2)."""
    k_chroma_coarse: float | None = None
    """k_chroma at the pyramid levels j >= 1 (None: k_chroma). Smaller keeps isoluminant colour
    edges where the level's chroma noise is low (issue 17)."""
    chroma_range_cap: float | str | None = "space"
    """Upper bound of the level-0 chroma range sigma k_chroma * sigma_0 at mid-grey (Y = 0.18;
    chroma units of the space, linear): at high noise k_chroma shrinks to cap / sigma_0 (every
    level alike), so colour edges of more than about the cap are no longer averaged across
    (issue 17). "space": the space's CHROMA_RANGE_CAP; None: no cap."""
    range_joint: float | str = "space"
    """At the pyramid levels j >= 1: 0, each chroma plane's bilateral weight has its own range term
    (the plane's difference over its range sigma); s > 0, one weight shared by every plane, whose
    range term is s times the Mahalanobis distance of the planes' differences over their rank
    (:meth:`ChromaDenoise.range_metric`), so that a colour edge one plane shows stops the
    averaging of the others as well (issue 17: in the LMS space the blue sky's edge is 2.3 range
    sigmas in B-Y but 1.1 in R-Y at gain 64, so R-Y was averaged across it). "space": the space's
    RANGE_JOINT."""
    range_joint_sigma: tuple[float, float] | str = "space"
    """(off, full): level-0 chroma noise std at mid-grey (sigma_0, :meth:`ChromaDenoise.mid_grey_sigma`)
    below which range_joint is 0 and from which it applies in full, linear in between; (0, 0): in
    full at every noise. "space": the space's RANGE_JOINT_SIGMA."""
    k_luma: float = 2.0
    """Guide range sigma = k_luma * Y noise std at the level; 0 disables the guide (plain bilateral)."""
    shrink_radius: int = 2
    """BayesShrink local-variance window radius r_w (coefficients of the level); must be <= radius."""
    shrink: str = "soft"
    """Detail subbands: 'soft' (BayesShrink soft threshold), 'wiener' (local Wiener gain
    var_x / (var_x + var_n)), or 'none' (kept)."""
    shrink_guide: bool = True
    """Keep chroma details where the luminance detail of the same subband is signal (see bayes_shrink)."""
    strengths: tuple[float, ...] | None = None
    """Per-chroma-channel strengths s_k (None: the space's default, LMS (1, 1, 1.5), YUV (1.5, 1))."""
    luma: str = "paper"
    """The space's luminance (LUMAS, :func:`space_for_cfa`): 'paper' (LMS (L + M) / 2, Bayer BT.601),
    'cfa' (the CFA's baseband luminance) or 'snr' (its least-noise weighting)."""
    noise_scale: float = 1.0
    """Multiplies every noise standard deviation of the table (> 1: smoother, < 1: sharper)."""
    sigma_floor: float = 1e-6
    """Smallest range sigma (signal units): keeps the weights defined when the noise is 0."""

    def __post_init__(self) -> None:
        if not 1 <= self.levels <= 6:
            raise ClispError(f"chroma denoise levels must be 1..6, got {self.levels}")
        if self.shrink not in SHRINK_RULES:
            raise ClispError(f"chroma denoise shrink must be one of {SHRINK_RULES}, got {self.shrink!r}")
        if self.radius < 1 or not 0 <= self.shrink_radius <= self.radius:
            raise ClispError("chroma denoise needs radius >= 1 and 0 <= shrink_radius <= radius")
        if self.sigma_d <= 0 or self.k_chroma <= 0 or self.k_luma < 0 or self.noise_scale < 0 \
                or self.sigma_floor <= 0:
            raise ClispError("chroma denoise: sigma_d, k_chroma, sigma_floor > 0; k_luma, noise_scale >= 0")
        if self.luma not in LUMAS:
            raise ClispError(f"chroma denoise luma must be one of {', '.join(LUMAS)}, got {self.luma!r}")
        if self.range_joint != "space" and not (isinstance(self.range_joint, (int, float)) and self.range_joint >= 0):
            raise ClispError(f"chroma denoise range_joint must be 'space' or >= 0, got {self.range_joint!r}")


# ---------------------------------------------------------------------------------- noise table

@dataclass(frozen=True)
class NoiseTable:
    """Noise variance at every pyramid level as ``shot * max(s, 0) + floor``, s = local Y (level mean).

    approx  (J + 1, 1 + n, 2): level j = 0..J (0 = pixels), channel (Y, c_1..c_n), (shot, floor).
    detail  (J + 1, 1 + n, 3, 2): level j = 1..J (row 0 unused), channel (Y, c_1..c_n),
            orientation (dx, dy, dd), (shot, floor).
    """

    approx: np.ndarray
    detail: np.ndarray
    corr: np.ndarray | None = None
    """(J + 1, n, n) correlation matrices of the chroma approximations' noise at every level
    (measured on the calibration fields), or None: uncorrelated."""

    @classmethod
    def zero(cls, levels: int, n_chroma: int) -> "NoiseTable":
        return cls(np.zeros((levels + 1, 1 + n_chroma, 2)), np.zeros((levels + 1, 1 + n_chroma, 3, 2)))

    def prefix(self, levels: int) -> "NoiseTable":
        """The table of the first ``levels`` Haar levels (calibration measures every level on the
        same fields, so the prefix is exact)."""
        corr = None if self.corr is None else self.corr[:levels + 1]
        return NoiseTable(self.approx[:levels + 1], self.detail[:levels + 1], corr)

    def correlation(self, level: int, n_chroma: int) -> np.ndarray:
        """(n, n) noise correlation of the chroma approximations at ``level`` (identity without)."""
        return np.eye(n_chroma) if self.corr is None else np.asarray(self.corr[level], dtype=np.float64)

    @property
    def levels(self) -> int:
        return self.approx.shape[0] - 1

    @property
    def is_zero(self) -> bool:
        return not np.any(self.approx) and not np.any(self.detail)


def _affine_var(coef: np.ndarray, s: np.ndarray) -> np.ndarray:
    """coef[..., 0] * max(s, 0) + coef[..., 1]."""
    return coef[0] * np.maximum(s, 0.0) + coef[1]


# ---------------------------------------------------------------------------------- region plan

@dataclass(frozen=True)
class Plan:
    """Where each level's arrays lie in one window (per axis: y then x).

    skip      (sy, sx) first aligned pixel of the window (window coordinates).
    size      (ny, nx) aligned extent used at level 0 (multiples of 2^J).
    margins   m_j for j = 0..J: first valid pixel of level j after its bilateral (level-j px,
              relative to the aligned start); m_J = r, m_j = 2 m_{j+1} + r.
    crop      (cy, cx) offset of the output's (0, 0) inside the level-0 valid region.
    out       (oh, ow) output size (window less the halo on each side).
    """

    skip: tuple[int, int]
    size: tuple[int, int]
    margins: tuple[int, ...]
    crop: tuple[int, int]
    out: tuple[int, int]


def margins(levels: int, radius: int) -> tuple[int, ...]:
    """m_j, j = 0..J: valid margin at level j after its bilateral (level-j px)."""
    m = [0] * (levels + 1)
    m[levels] = radius
    for j in range(levels - 1, -1, -1):
        m[j] = 2 * m[j + 1] + radius
    return tuple(m)


def make_plan(levels: int, radius: int, height: int, width: int, origin: tuple[int, int]) -> Plan:
    """The region plan of a ``height x width`` window whose (0, 0) is image pixel ``origin``."""
    align = 2 ** levels
    m = margins(levels, radius)
    halo = m[0] + align - 1
    skip = tuple((-o) % align for o in origin)
    size = tuple((n - s) // align * align for n, s in zip((height, width), skip))
    out = (height - 2 * halo, width - 2 * halo)
    if min(out) < 1 or min(size) // align <= 2 * radius:
        raise ClispError(f"chroma denoise window {height}x{width} is too small for halo {halo}")
    crop = tuple(halo - s - m[0] for s in skip)
    return Plan(skip, size, m, crop, out)  # type: ignore[arg-type]


# ---------------------------------------------------------------------------------- reference steps
# Each function is one kernel of clisp/modules/chroma_denoise/chroma_denoise.cl, same name, same arithmetic (float64 here).
# Images are planar: (planes, h, w).

def chroma_split(cam: np.ndarray, split: np.ndarray) -> np.ndarray:
    """(3, h, w) camera -> (1 + n, h, w): plane 0 = Y, planes 1..n = chroma. Halo 0."""
    return np.einsum("ij,jhw->ihw", split, cam)


def haar_analyze(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(P, 2h, 2w) -> approx (P, h, w) and details (3, P, h, w), orientation-major (dx, dy, dd).

    Block means and differences (see module docstring). Halo 0 (2 x 2 blocks, aligned)::

        >>> a, d = haar_analyze(np.array([[[1.0, 2.0], [3.0, 6.0]]]))
        >>> a.ravel().tolist(), d.ravel().tolist()
        ([3.0], [-1.0, -1.5, 0.5])
    """
    x00, x01 = a[:, 0::2, 0::2], a[:, 0::2, 1::2]
    x10, x11 = a[:, 1::2, 0::2], a[:, 1::2, 1::2]
    approx = (x00 + x01 + x10 + x11) / 4.0
    dx = (x00 - x01 + x10 - x11) / 4.0
    dy = (x00 + x01 - x10 - x11) / 4.0
    dd = (x00 - x01 - x10 + x11) / 4.0
    return approx, np.stack([dx, dy, dd])


def haar_pyramid(a: np.ndarray, levels: int) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray | None]]:
    """``levels`` steps of :func:`haar_analyze` on (1 + n, h, w) planes (plane 0 = Y): (the coarsest
    planes, Y at every level from the finest, the details of every level with None at level 0)."""
    ys, details = [a[0]], [None]
    for _ in range(levels):
        a, d = haar_analyze(a)
        ys.append(a[0])
        details.append(d)
    return a, ys, details


def haar_synthesize(approx: np.ndarray, detail: np.ndarray) -> np.ndarray:
    """approx (n, h, w) and details (3, n, h, w) -> (n, 2h, 2w); exact inverse of haar_analyze."""
    dx, dy, dd = detail
    n, h, w = approx.shape
    out = np.empty((n, 2 * h, 2 * w))
    out[:, 0::2, 0::2] = approx + dx + dy + dd
    out[:, 0::2, 1::2] = approx - dx + dy - dd
    out[:, 1::2, 0::2] = approx + dx - dy - dd
    out[:, 1::2, 1::2] = approx - dx - dy + dd
    return out


def _window(a: np.ndarray, r: int, dy: int, dx: int) -> np.ndarray:
    """a[..., r+dy : h-r+dy, r+dx : w-r+dx] (valid-region shift)."""
    h, w = a.shape[-2:]
    return a[..., r + dy:h - r + dy, r + dx:w - r + dx]


def _wiener_gain(var_x: np.ndarray, var_n: np.ndarray) -> np.ndarray:
    """var_x / (var_x + var_n), 0 where both are 0."""
    total = var_x + var_n
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(total > 0, var_x / np.where(total > 0, total, 1.0), 0.0)


def bayes_shrink(detail: np.ndarray, y: np.ndarray, var_coef: np.ndarray, strengths: np.ndarray,
                 r_w: int, rule: str = "soft", guide: bool = True) -> np.ndarray:
    """Shrink the chroma details; (3, 1 + n, h, w) (plane 0 = Y) -> (3, n, h - 2 r_w, w - 2 r_w).

    Per orientation o and chroma plane k, with E = mean d^2 over the (2 r_w + 1)^2 window,
    var_n = s_k^2 (shot max(Y, 0) + floor) and var_x = max(E - var_n, 0):
    'soft' (BayesShrink): d' = sign(d) max(|d| - var_n / sqrt(var_x), 0), 0 where var_x = 0;
    'wiener': d' = d var_x / (var_x + var_n).
    ``guide``: blend back towards d where the luminance detail of the same subband is signal,
    d'' = d' + g_Y (d - d'), g_Y = var_xY / (var_xY + var_nY) (Wiener gain of the Y detail, s = 1).
    ``y``: the level's Y approximation (h, w), the signal level of the noise. ``var_coef``:
    (1 + n, 3, 2) affine noise variance per channel (Y first) and orientation."""
    energy = np.zeros((3, detail.shape[1], detail.shape[2] - 2 * r_w, detail.shape[3] - 2 * r_w))
    for dy in range(-r_w, r_w + 1):
        for dx in range(-r_w, r_w + 1):
            energy += _window(detail, r_w, dy, dx) ** 2
    energy /= (2 * r_w + 1) ** 2
    d = _window(detail, r_w, 0, 0)
    s = _window(y, r_w, 0, 0)
    n = d.shape[1] - 1
    out = np.empty((3, n) + d.shape[2:])
    for o in range(3):
        var_ny = _affine_var(var_coef[0, o], s)
        g_y = _wiener_gain(np.maximum(energy[o, 0] - var_ny, 0.0), var_ny) if guide else 0.0
        for k in range(n):
            dk = d[o, 1 + k]
            var_n = strengths[k] ** 2 * _affine_var(var_coef[1 + k, o], s)
            var_x = np.maximum(energy[o, 1 + k] - var_n, 0.0)
            if rule == "wiener":
                shrunk = dk * _wiener_gain(var_x, var_n)
            else:
                with np.errstate(divide="ignore", invalid="ignore"):
                    t = np.where(var_x > 0, var_n / np.sqrt(var_x), np.inf)
                shrunk = np.sign(dk) * np.maximum(np.abs(dk) - t, 0.0)
            out[o, k] = shrunk + g_y * (dk - shrunk)
    return out


def joint_bilateral(c: np.ndarray, y: np.ndarray, var_y: np.ndarray, var_c: np.ndarray,
                    k_luma: float, k_chroma: np.ndarray, sigma_d: float, radius: int,
                    sigma_floor: float, metric: np.ndarray | None = None) -> np.ndarray:
    """Luminance-guided bilateral of chroma planes (n, h, w) with guide y (h, w) -> (n, h-2r, w-2r).

    var_y (2,), var_c (n, 2): affine noise variances of Y and of each chroma plane at this level;
    range sigmas sY = k_luma sigma_Y(Y_p), sc_k = k_chroma[k] sigma_k(Y_p), floored at sigma_floor.
    k_luma = 0 drops the guide term. ``metric`` None: each plane's weight has its own chroma term
    z_k^2, z_k = (c_q,k - c_p,k) / (sqrt 2 sc_k); an (n, n) M: every plane shares one weight whose
    chroma term is z^T M z (ChromaDenoise.range_metric)."""
    r = radius
    yc = _window(y, r, 0, 0)
    cc = _window(c, r, 0, 0)
    inv_y = 0.0 if k_luma == 0 else 1.0 / (2.0 * np.maximum(k_luma ** 2 * _affine_var(var_y, yc), sigma_floor ** 2))
    inv_c = np.stack([1.0 / (2.0 * np.maximum(k_chroma[k] ** 2 * _affine_var(var_c[k], yc), sigma_floor ** 2))
                      for k in range(c.shape[0])])
    num = np.zeros_like(cc)
    den = np.zeros_like(cc)
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            cq = _window(c, r, dy, dx)
            base = (dy * dy + dx * dx) / (2.0 * sigma_d * sigma_d) + (_window(y, r, dy, dx) - yc) ** 2 * inv_y
            if metric is None:
                rng = (cq - cc) ** 2 * inv_c
            else:
                z = (cq - cc) * np.sqrt(inv_c)
                rng = np.einsum("khw,kl,lhw->hw", z, metric, z)[None]
            w = np.exp(-(base + rng))
            num += w * cq
            den += w
    return num / den


def chroma_merge(y: np.ndarray, c: np.ndarray, merge: np.ndarray) -> np.ndarray:
    """Y (h, w) and chroma (n, h, w) -> RGB (3, h, w) = merge @ (Y, c). Halo 0."""
    return np.einsum("ij,jhw->ihw", merge, np.concatenate([y[None], c]))


# ---------------------------------------------------------------------------------- the stage

def vector_width(rt: Runtime) -> int:
    """Pixels per work item (VEC) of every kernel: 8 on CPU devices (PoCL
    does not vectorise the scalar kernels; float8 measured 8x cheaper for the bilateral), 1 on GPUs
    (one pixel per lane, coalesced). A launch whose rows are narrower than VEC uses 1."""
    return 8 if rt.device.type & rt.cl.device_type.CPU else 1


@dataclass
class ChromaDenoise(Stage):
    """White-balanced camera (H x W x 3) -> linear sRGB with chroma denoised ((H - 2 halo) x ...).

    space   the colour space (LMS or BT.601 YUV) and the colour matrix it includes.
    noise   per-level noise (see :func:`calibrate_noise`); None = noiseless (colour matrix only).
    params  :class:`ChromaDenoiseParams`.

    A flat field comes out as the colour matrix applied to it, whatever the noise table::

        >>> from clisp.sim.colorimetry import P_LMS
        >>> table = NoiseTable(np.full((4, 4, 2), 1e-3), np.full((4, 4, 3, 2), 1e-3))
        >>> stage = ChromaDenoise(lms_space(P_LMS), table)
        >>> out = stage.reference(np.full((2 * 52 + 2, 2 * 52 + 3, 3), 0.5), (0, 0))
        >>> out.shape, bool(np.allclose(out, P_LMS @ [0.5, 0.5, 0.5]))
        ((2, 3, 3), True)
    """

    space: ChromaSpace
    noise: NoiseTable | None = None
    params: ChromaDenoiseParams = field(default_factory=ChromaDenoiseParams)
    interleaved: bool = False
    tone: ToneCurve | None = None
    """The pipeline's tone curve folded into the merge's store (:meth:`fuse`): the stage then
    outputs what the ToneCurve would (encoded float, 16- or 8-bit codes), one pass fewer."""
    name = "chroma_denoise"
    in_channels = 3
    out_channels = 3
    writes_into = True

    @property
    def out_dtype(self) -> np.dtype:
        return np.dtype(np.float32) if self.tone is None else self.tone.out_dtype

    def __post_init__(self) -> None:
        if self.noise is None:
            self.noise = NoiseTable.zero(self.params.levels, self.space.n_chroma)
        if self.noise.levels != self.params.levels:
            raise ClispError(f"noise table has {self.noise.levels} levels, params ask for {self.params.levels}")
        if len(self.strengths) != self.space.n_chroma:
            raise ClispError(f"need {self.space.n_chroma} strengths for {self.space.name}, got {self.strengths}")

    @property
    def strengths(self) -> np.ndarray:
        s = self.space.strengths if self.params.strengths is None else self.params.strengths
        return np.asarray(s, dtype=np.float64)

    @property
    def align(self) -> int:
        """Tile origins at multiples of this keep the decimation grid without skipped pixels."""
        return 2 ** self.params.levels

    @property
    def halo(self) -> int:
        return margins(self.params.levels, self.params.radius)[0] + self.align - 1

    @property
    def bytes_per_pixel(self) -> float:
        """float32 planes per input-window pixel held in the pool: level 0 (Y + n chroma), the
        level-0 synthesis and bilateral outputs (n each), the RGB output (3); at level j >= 1
        (4^-j of the pixels) the approximation (1 + n), details (3 (1 + n)), shrunk details
        (3 n), bilateral and synthesis outputs (n each). LMS: 13 + 10.2 planes = 93 B/px, YUV 69."""
        n, j_max = self.space.n_chroma, self.params.levels
        coarse = sum(4.0 ** -j for j in range(1, j_max + 1)) * (4 * (1 + n) + 5 * n)
        return 4.0 * ((1 + n) + 2 * n + 3 + coarse)

    def _scaled_noise(self) -> tuple[np.ndarray, np.ndarray]:
        """Noise table with noise_scale applied (variances times noise_scale^2)."""
        f2 = self.params.noise_scale ** 2
        return self.noise.approx * f2, self.noise.detail * f2

    # -- reference ------------------------------------------------------------------------------
    def reference(self, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
        prm, sp = self.params, self.space
        plan = make_plan(prm.levels, prm.radius, x.shape[0], x.shape[1], origin)
        approx_var, detail_var = self._scaled_noise()
        (sy, sx), (ny, nx) = plan.skip, plan.size
        cam = np.moveaxis(x.astype(np.float64), -1, 0)[:, sy:sy + ny, sx:sx + nx]
        a, ys, details = haar_pyramid(chroma_split(cam, sp.split_matrix), prm.levels)   # (1 + n, ny, nx) split
        c = a[1:]
        m, r = plan.margins, prm.radius
        start = 0                                                    # level-j start of c
        for j in range(prm.levels, -1, -1):
            y_j = ys[j][start:ys[j].shape[0] - start, start:ys[j].shape[1] - start]
            c = joint_bilateral(c, y_j, approx_var[j, 0], approx_var[j, 1:], prm.k_luma,
                                self.k_chroma(j), prm.sigma_d, r, prm.sigma_floor,
                                self.range_metric(j))                                 # now starts at m[j]
            if j == 0:
                break
            d = details[j]
            if prm.shrink != "none":
                rw = prm.shrink_radius
                d = bayes_shrink(d, ys[j], detail_var[j], self.strengths, rw, prm.shrink, prm.shrink_guide)
                o = m[j] - rw
            else:
                d, o = d[:, 1:], m[j]
            d = d[..., o:o + c.shape[1], o:o + c.shape[2]]
            c = haar_synthesize(c, d)
            start = 2 * m[j]
        y0 = ys[0][m[0]:ys[0].shape[0] - m[0], m[0]:ys[0].shape[1] - m[0]]
        rgb = chroma_merge(y0, c, sp.merge_matrix)
        (cy, cx), (oh, ow) = plan.crop, plan.out
        out = np.moveaxis(rgb[:, cy:cy + oh, cx:cx + ow], 0, -1)
        return out if self.tone is None else self.tone.reference(out, origin)

    # -- OpenCL ---------------------------------------------------------------------------------
    def fuse(self, following: Stage) -> Stage | None:
        """A following colour matrix M (e.g. white balance pass 2) folds into the merge:
        M (from_luma Y + from_chroma c) = (M from_luma) Y + (M from_chroma) c. Y, c and the
        denoising are unchanged. A following ToneCurve folds into the merge's store (``tone``);
        nothing folds after it."""
        if self.interleaved or self.tone is not None:
            return None
        if isinstance(following, ToneCurve):
            return replace(self, tone=replace(following, interleaved=False))
        if not isinstance(following, ColourMatrix):
            return None
        m = np.asarray(following.matrix, dtype=np.float64)
        sp = self.space
        space = ChromaSpace(sp.name, m @ sp.to_rgb, sp.luma, sp.chroma, m @ sp.from_luma, m @ sp.from_chroma,
                            sp.strengths, sp.names)
        return ChromaDenoise(space, self.noise, self.params)

    def with_interleaved_output(self) -> "ChromaDenoise":
        return replace(self, interleaved=True)

    def defines(self) -> dict[str, int]:
        """Compile-time constants of chroma_denoise.cl; JOINT_RANGE (joint_bilateral) and INTERLEAVED
        (chroma_merge) are 0 here and set per launch, VEC per launch."""
        return {"NCHROMA": self.space.n_chroma, "RADIUS": self.params.radius,
                "SHRINK_RADIUS": self.params.shrink_radius,
                "SHRINK_RULE": SHRINK_RULES.index(self.params.shrink), "JOINT_RANGE": 0, "INTERLEAVED": 0}

    def range_metric(self, level: int) -> np.ndarray | None:
        """(n, n) M of the joint range term at ``level`` (None where range_joint is 0): the term is
        z^T M z, z_k = (c_q,k - c_p,k) / (sqrt 2 sc_k), M = range_joint S R^+ S / rank (S = diag of
        the strengths s_k, so that the term measures differences in k_chroma noise sigmas whatever
        the planes' strengths), R the level's noise correlation of the chroma planes, its
        pseudo-inverse over the eigenvalues above
        CORR_CUT of the largest (rank of them). Uncorrelated planes: range_joint times the mean of
        the planes' own terms; correlated ones (LMS's R-Y, G-Y, B-Y share two noise sources): the
        Mahalanobis distance, so a difference that noise makes only in one combination does not
        count as often as there are planes."""
        joint = self.range_joint(level)
        if joint <= 0:
            return None
        n = self.space.n_chroma
        w, v = np.linalg.eigh(self.noise.correlation(level, n))
        keep = w > CORR_CUT * w.max()
        inverse = (v[:, keep] / w[keep]) @ v[:, keep].T
        strengths = np.asarray(self.strengths, dtype=np.float64)      # z_k carries 1 / s_k: undo it
        return joint * np.outer(strengths, strengths) * inverse / int(keep.sum())

    def range_joint(self, level: int) -> float:
        """The joint range factor of ``level``'s bilateral: range_joint (or the space's RANGE_JOINT)
        at levels >= 1 times the noise fade of range_joint_sigma, 0 at level 0."""
        joint = self.params.range_joint
        if joint == "space":
            joint = RANGE_JOINT.get(self.space.name, 0.0)
        if level < 1 or joint <= 0:
            return 0.0
        sigmas = self.params.range_joint_sigma
        lo, hi = RANGE_JOINT_SIGMA.get(self.space.name, (0.0, 0.0)) if sigmas == "space" else sigmas
        fade = float(np.clip((self.mid_grey_sigma() - lo) / (hi - lo), 0.0, 1.0)) if hi > lo else 1.0
        return float(joint) * fade

    def k_chroma(self, level: int) -> np.ndarray:
        """(n,) chroma range factors at ``level``: k_chroma (k_chroma_coarse at j >= 1) * s_k, times
        the high-noise factor of ``chroma_range_cap`` (:meth:`range_cap_factor`)."""
        prm = self.params
        k = prm.k_chroma if level == 0 or prm.k_chroma_coarse is None else prm.k_chroma_coarse
        return k * self.range_cap_factor() * np.asarray(self.strengths, dtype=np.float64)

    def range_cap_factor(self) -> float:
        """min(1, cap / (k_chroma sigma_0)), sigma_0 = rms over the chroma channels of the level-0
        chroma noise at Y = 0.18 (noise_scale included); 1 without a cap or without noise."""
        prm = self.params
        cap = CHROMA_RANGE_CAP.get(self.space.name) if prm.chroma_range_cap == "space" else prm.chroma_range_cap
        if cap is None:
            return 1.0
        sigma = self.mid_grey_sigma()
        return 1.0 if sigma <= 0 else min(1.0, float(cap) / (prm.k_chroma * sigma))

    def mid_grey_sigma(self) -> float:
        """sigma_0: rms over the chroma channels of the level-0 chroma noise std at Y = 0.18
        (noise_scale included); 0 without noise."""
        approx, _ = self._scaled_noise()
        var = approx[0, 1:, 0] * 0.18 + approx[0, 1:, 1]
        return float(np.sqrt(max(np.mean(var), 0.0)))

    def bilateral_constants(self, level: int) -> np.ndarray:
        """The ``bilateral_constants`` struct of ``joint_bilateral`` at ``level``: one record of
        :func:`bilateral_constants_dtype` (the metric is zeros without a joint range term)."""
        prm, n = self.params, self.space.n_chroma
        approx_var, _ = self._scaled_noise()
        k_c2 = self.k_chroma(level) ** 2
        metric = self.range_metric(level)
        record = np.zeros((), dtype=bilateral_constants_dtype(n))
        record["inv_2sd2"] = 0.5 / prm.sigma_d ** 2
        record["floor2"] = prm.sigma_floor ** 2
        record["luma"] = approx_var[level, 0] * prm.k_luma ** 2
        record["chroma"] = (approx_var[level, 1:] * k_c2[:, None]).ravel()
        record["metric"] = np.zeros(n * n) if metric is None else metric.ravel()
        return record

    def enqueue(self, rt: Runtime, src: DeviceImage, origin: tuple[int, int],
                out: DeviceImage | None = None) -> DeviceImage:
        target = out                    # ``out``: the host's band to write (Runtime.host_image), if given
        prm, sp, n = self.params, self.space, self.space.n_chroma
        plan = make_plan(prm.levels, prm.radius, src.height, src.width, origin)
        defines = self.defines()
        _, detail_var = self._scaled_noise()
        strength2 = rt.constant(as_f32(self.strengths ** 2))
        (sy, sx), (ny, nx) = plan.skip, plan.size
        m, r, rw = plan.margins, prm.radius, prm.shrink_radius

        vec = vector_width(rt)

        def vec_kernel(name: str, width: int, extra: dict | None = None) -> tuple:
            """(kernel, work items along x) for ``width`` outputs per row, VEC = vec when width >= vec."""
            v = vec if width >= vec else 1
            return rt.kernel("chroma_denoise", name, {**defines, **(extra or {}), "VEC": v}), -(-width // v)

        levels = [rt.acquire(1 + n, ny, nx)]
        split, gx = vec_kernel("chroma_split", nx)
        rt.launch(split, gx, ny, src.buffer, levels[0].buffer,
                  np.int32(src.width), np.int32(src.height), np.int32(sy), np.int32(sx),
                  np.int32(nx), np.int32(ny), rt.constant(as_f32(sp.split_matrix)))
        details: list[DeviceImage | None] = [None]
        for j in range(1, prm.levels + 1):
            h, w = ny >> j, nx >> j
            approx, detail = rt.acquire(1 + n, h, w), rt.acquire(3 * (1 + n), h, w)
            analyze, gx = vec_kernel("haar_analyze", w)
            rt.launch(analyze, gx, h, levels[-1].buffer, approx.buffer, detail.buffer, np.int32(w), np.int32(h))
            if prm.shrink != "none":
                shrunk = rt.acquire(3 * n, h - 2 * rw, w - 2 * rw)
                shrink, gx = vec_kernel("bayes_shrink", shrunk.width)
                rt.launch(shrink, gx, shrunk.height,
                          detail.buffer, approx.buffer, shrunk.buffer, np.int32(w), np.int32(h),
                          np.int32(shrunk.width), np.int32(shrunk.height),
                          rt.constant(as_f32(detail_var[j])), strength2, np.int32(prm.shrink_guide))
                rt.release(detail)
                detail = shrunk
            levels.append(approx)
            details.append(detail)

        top = levels[-1]
        c, c_offset, start = top, top.height * top.width, 0           # chroma planes of level J
        for j in range(prm.levels, -1, -1):
            lvl = levels[j]
            out = rt.acquire(n, c.height - 2 * r, c.width - 2 * r)
            bilateral, gx = vec_kernel("joint_bilateral", out.width, {"JOINT_RANGE": int(self.range_joint(j) > 0)})
            rt.launch(bilateral, gx, out.height, c.buffer, np.int32(c_offset), lvl.buffer,
                      out.buffer, np.int32(c.width), np.int32(c.height), np.int32(lvl.width),
                      np.int32(start), np.int32(out.width), np.int32(out.height),
                      np.int32(prm.k_luma > 0), rt.constant(self.bilateral_constants(j)))
            if c is not top:
                rt.release(c)
            c, c_offset = out, 0
            if j == 0:
                break
            d = details[j]
            shrunk = prm.shrink != "none"
            d_shift, d_planes, d_first = (m[j] - rw, n, 0) if shrunk else (m[j], 1 + n, 1)
            up = rt.acquire(n, 2 * c.height, 2 * c.width)
            synthesize, gx = vec_kernel("haar_synthesize", up.width)
            rt.launch(synthesize, gx, up.height, c.buffer, d.buffer, up.buffer, np.int32(c.width),
                      np.int32(c.height), np.int32(d.width), np.int32(d.height), np.int32(d_shift),
                      np.int32(d_planes), np.int32(d_first))
            rt.release(c)
            rt.release(d)
            c, start = up, 2 * m[j]
        (cy, cx), (oh, ow) = plan.crop, plan.out
        dst = target if target is not None else rt.acquire(3, oh, ow, self.out_dtype)
        v = vec if ow >= vec else 1
        tone = self.tone
        store = {"ENCODE_SRGB": 0, "QUANTIZE": 0, "CODE_BITS": 16} if tone is None else \
            {**SRGB_ENCODING, "ENCODE_SRGB": 1, "QUANTIZE": int(tone.quantize), "CODE_BITS": tone.bits}
        rt.launch_named("chroma_denoise", "chroma_merge", -(-ow // v), oh, dict(
            level=levels[0], chroma=c, dst=dst, y_w=nx, y_shift_y=m[0] + cy, y_shift_x=m[0] + cx, c_w=c.width,
            c_h=c.height, c_shift_y=cy, c_shift_x=cx, width=ow, height=oh, m=rt.constant(as_f32(sp.merge_matrix))),
            {**defines, **store, "INTERLEAVED": int(self.interleaved), "VEC": v}, exact=False,
            generated="" if tone is None else srgb_source(rt))
        rt.release(c)
        for lvl in levels:
            rt.release(lvl)
        dst.interleaved = self.interleaved
        return dst


# ---------------------------------------------------------------------------------- calibration

CALIBRATION_LEVELS = (0.03, 0.5)
"""Linear gray levels of the two flat fields that calibrate the noise table."""
CALIBRATION_SIZE = 384
"""Side of each calibration flat field (px); level 3 then holds 48 x 48 coefficients."""
CALIBRATION_SEED = 20240601


def measure_noise(cam: np.ndarray, space: ChromaSpace, levels: int
                  ) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """Noise of a flat noisy camera image (h, w, 3): (mean Y, approx variances (J+1, 1+n), detail
    variances (J+1, 1+n, 3), chroma approx correlations (J+1, n, n))."""
    a = chroma_split(np.moveaxis(cam, -1, 0), space.split_matrix)
    n = space.n_chroma
    approx = np.zeros((levels + 1, 1 + n))
    detail = np.zeros((levels + 1, 1 + n, 3))
    corr = np.zeros((levels + 1, n, n))
    approx[0] = a.reshape(a.shape[0], -1).var(axis=1)
    corr[0] = _correlation(a[1:])
    mean_y = float(a[0].mean())
    for j in range(1, levels + 1):
        a, d = haar_analyze(a)
        approx[j] = a.reshape(a.shape[0], -1).var(axis=1)
        detail[j] = np.mean(d ** 2, axis=(2, 3)).T
        corr[j] = _correlation(a[1:])
    return mean_y, approx, detail, corr


def _correlation(planes: np.ndarray) -> np.ndarray:
    """(n, n) correlation matrix of n planes (n, h, w); identity where a plane has no variance."""
    x = planes.reshape(planes.shape[0], -1)
    x = x - x.mean(axis=1, keepdims=True)
    cov = x @ x.T / x.shape[1]
    sd = np.sqrt(np.diag(cov))
    if np.any(sd <= 0):
        return np.eye(planes.shape[0])
    return cov / np.outer(sd, sd)


def bilateral_constants_dtype(n_chroma: int) -> np.dtype:
    """The record of chroma_denoise.cl's ``bilateral_constants`` struct for ``n_chroma`` planes: its
    fields by name, float32, in the struct's order (all floats: no padding).

    >>> bilateral_constants_dtype(2).itemsize // 4       # 1 + 1 + 2 + 2 * 2 + 2 * 2
    12
    """
    f4 = np.float32
    return np.dtype([("inv_2sd2", f4), ("floor2", f4), ("luma", f4, (2,)), ("chroma", f4, (2 * n_chroma,)),
                     ("metric", f4, (n_chroma * n_chroma,))])


def is_noiseless(noise) -> bool:
    """True when every shot and floor term of a per-channel noise (ChannelNoise) is 0."""
    return not any(noise.shot) and not any(noise.floor)


def run_demosaic(demosaic: Stage, mosaic: np.ndarray, rt: Runtime | None = None) -> np.ndarray:
    """``demosaic`` on an H x W mosaic whose pixel (0, 0) is at image (0, 0): (H-2r) x (W-2r) x 3,
    by its NumPy reference (float64; ``rt`` None) or its OpenCL kernels on ``rt`` (float32, returned
    as float64)."""
    if rt is None:
        return demosaic.reference(mosaic, (0, 0))
    stage_label("noise calibration (pipeline set-up)")
    with rt.metering():        # the demosaic's programs, built at once (in parallel on PoCL) before it runs
        rt.release(demosaic.enqueue(rt, rt.acquire(1, *mosaic.shape), (0, 0)))
    src = rt.upload(np.ascontiguousarray(mosaic, dtype=np.float32))
    dst = demosaic.enqueue(rt, src, (0, 0))
    out = rt.download(dst)
    rt.release(src)
    rt.release(dst)
    return (out if dst.interleaved else np.moveaxis(out, 0, -1)).astype(np.float64)


CALIBRATION_CACHE_SIZE = 16
"""Noise tables kept per process (:func:`calibrate_noise`): a folder of raws from one camera at one
gain calibrates once (``clisp process`` with several inputs, a batch worker)."""
_CALIBRATIONS: dict[bytes, "NoiseTable"] = {}


def calibration_key(*inputs: object) -> bytes | None:
    """SHA-256 of the pickled inputs of a calibration (exact: arrays by value, floats by bits); None
    when something in them does not pickle (then nothing is cached)."""
    try:
        return hashlib.sha256(pickle.dumps(inputs, protocol=4)).digest()
    except (pickle.PicklingError, TypeError, AttributeError):
        return None


def calibrate_noise(demosaic: Stage, cfa, space: ChromaSpace, raw_noise, levels: int = 3,
                    size: int = CALIBRATION_SIZE, gray: Sequence[float] = CALIBRATION_LEVELS,
                    seed: int = CALIBRATION_SEED, rt: Runtime | None = None) -> NoiseTable:
    """:func:`measure_calibration`, remembered for the same inputs (the same demosaic
    configuration, CFA, space, raw noise, levels, fields and seed, and reference or device): the
    calibration is deterministic, so a repeat returns the same table without running it. Kept per
    process and on disk (:func:`calibration_path`: per device and clisp code), so a later process
    reads it (about 1 ms) instead of measuring it (0.13 s per 1 MP LMS raw at gain 4 on 2 CPU
    cores, plus the programs it builds)."""
    key = calibration_key(type(demosaic).__qualname__, demosaic, cfa, space, raw_noise, levels, size,
                          tuple(gray), seed, rt is None)
    if key is not None and key in _CALIBRATIONS:
        return _CALIBRATIONS[key]
    path = calibration_path(key, rt) if key is not None else None
    table = read_calibration(path) if path is not None else None
    if table is None:
        table = measure_calibration(demosaic, cfa, space, raw_noise, levels, size, gray, seed, rt)
        if path is not None:
            write_calibration(path, table)
    for array in (table.approx, table.detail, table.corr):
        if array is not None:
            array.flags.writeable = False          # shared between pipelines: never changed in place
    if key is not None:
        if len(_CALIBRATIONS) >= CALIBRATION_CACHE_SIZE:
            _CALIBRATIONS.pop(next(iter(_CALIBRATIONS)))
        _CALIBRATIONS[key] = table
    return table


def calibration_path(key: bytes, rt: Runtime | None) -> Path | None:
    """The file in clisp's cache folder that keeps the calibration of ``key`` as measured by this
    clisp code (:func:`clisp.engine.disk_cache.code_fingerprint`) on ``rt``'s device (the
    reference when None: float32 kernels and the float64 reference differ in rounding); None
    without a home folder."""
    name = entry_name(key, "numpy reference" if rt is None else device_identity(rt.platform, rt.device))
    try:
        return cache_dir() / "calibration" / f"{name}.npz"
    except RuntimeError:                               # Path.home() without a home
        return None


def read_calibration(path: Path) -> NoiseTable | None:
    """The table kept at ``path`` by :func:`write_calibration`; None if missing or damaged."""
    try:
        with np.load(path, allow_pickle=False) as data:
            corr = data["corr"] if "corr" in data.files else None
            table = NoiseTable(data["approx"], data["detail"], corr)
    except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile):
        return None
    if table.approx.ndim != 3 or table.detail.ndim != 4 or table.detail.shape[:2] != table.approx.shape[:2]:
        return None
    return table


def write_calibration(path: Path, table: NoiseTable) -> None:
    """Keep ``table`` at ``path`` (clisp.engine.disk_cache.keep_bytes: atomic, skipped where the
    cache folder cannot be written)."""
    arrays = {"approx": table.approx, "detail": table.detail}
    if table.corr is not None:
        arrays["corr"] = table.corr
    data = io.BytesIO()
    np.savez(data, **arrays)
    keep_bytes(path, data.getvalue())


def measure_calibration(demosaic: Stage, cfa, space: ChromaSpace, raw_noise, levels: int = 3,
                        size: int = CALIBRATION_SIZE, gray: Sequence[float] = CALIBRATION_LEVELS,
                        seed: int = CALIBRATION_SEED, rt: Runtime | None = None) -> NoiseTable:
    """Noise table of ``space`` after ``demosaic`` for the raw noise ``raw_noise`` (a ChannelNoise).

    ``raw_noise``: per-channel noise with ``shot``, ``floor`` and ``variance(channel, level)``
    (ChannelNoise). Two flat neutral fields (linear gray ``gray``; WB'd camera value
    gray * inv(to_rgb) [1,1,1]) get
    Gaussian noise of the raw's variance per CFA channel, go through the demosaic (``rt`` None: its
    NumPy reference; else its OpenCL kernels on ``rt``: the same within float32 rounding, and 30x
    faster for the guided LMS demosaic, whose reference took 0.9 s of every run's start-up), and
    the variances of every subband are measured; a line through the two gives (shot, floor) per
    subband as a function of the mean Y. Deterministic for a given seed; zero noise -> zero table.
    """
    n = space.n_chroma
    if raw_noise is None or is_noiseless(raw_noise):
        return NoiseTable.zero(levels, n)
    rng = np.random.default_rng(seed)
    halo = demosaic.halo
    side = size + 2 * halo
    channel = cfa.channel_map(side, side)
    white_cam = np.linalg.solve(space.to_rgb, np.ones(3))
    points = []
    for g in gray:
        level = g * white_cam[channel]
        var = np.choose(channel, [raw_noise.variance(c, g * white_cam[c]) for c in range(cfa.n_channels)])
        mosaic = level + rng.standard_normal(level.shape) * np.sqrt(var)
        cam = run_demosaic(demosaic, mosaic, rt)
        points.append(measure_noise(cam, space, levels))
    (s0, a0, d0, r0), (s1, a1, d1, r1) = points
    def fit(v0: np.ndarray, v1: np.ndarray) -> np.ndarray:
        shot = np.maximum((v1 - v0) / (s1 - s0), 0.0)
        floor = np.maximum(v0 - shot * s0, 0.0)
        return np.stack([shot, floor], axis=-1)
    return NoiseTable(fit(a0, a1), fit(d0, d1), (r0 + r1) / 2.0)
