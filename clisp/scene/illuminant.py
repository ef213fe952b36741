"""The scene's light for white balance ``auto``: plausible lights in a camera's space, the small
per-block statistics the estimate reads, and the estimate (issue 42, item 1).

Three parts, each usable alone:

1. **The lights** (:func:`light_srgb`, :class:`CameraLights`). A light is a point (T, Duv): its
   correlated colour temperature T and its distance Duv from the locus in CIE 1960 uv, along
   the locus' normal. The locus is Planck's below LOCUS_JOIN_K and the CIE daylight locus above
   it (the lights people meet: tungsten and fire below, daylight, shade and flash above). Its
   colour in linear sRGB (white = D65) goes into the camera's space through the camera's
   matrix: a raw whose D65 white needs the multipliers ``d`` (the daylight multipliers of a
   camera raw, the known D65 multipliers of a clisp simulation) and whose colour matrix M maps
   white-balanced camera values to linear sRGB sees a light of linear sRGB colour w as
   ``diag(1/d) M^-1 w``; its pass-1 multipliers are ``d * (M^-1 1) / (M^-1 w)``, which are
   ``d`` for D65 itself.

2. **The statistics** (:func:`block_statistics_of` -> :class:`BlockStats`): what the estimate
   reads of the raw, per block of a grid aligned to the CFA (blocks of CFA cells, about BLOCKS of
   them; a cell is one CFA period, period x period pixels, and gives one camera triplet: the mean
   of each channel's samples in it). See :class:`BlockStats` for the list. They are sums over the
   statistics pass's cell thumbnail (clisp.scene.statistics), which reads the mosaic once for
   every estimate; :func:`block_statistics` measures them from a mosaic alone.

3. **The estimate** (:func:`estimate_light`): evidence against a prior over the lights,
   described in its docstring; it returns an :class:`Estimate` with the light, the pass-1
   multipliers, a confidence and what decided it (``clisp process --explain`` prints it).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..cfa import CFA
from ..sim.colorimetry import XYZ_TO_SRGB
from .statistics import MAX_CELLS, cell_thumbnail, thumbnail_step

# --------------------------------------------------------------------------------------------
# 1. The lights
# --------------------------------------------------------------------------------------------

LOCUS_JOIN_K = 4000.0
"""Below this temperature the locus is Planck's, above it CIE daylight's (where the daylight
formula starts); the two are 0.003 apart in Duv there, joined by a linear blend over
LOCUS_BLEND_K."""
LOCUS_BLEND_K = (4000.0, 5000.0)
"""Temperatures (K) between which the locus blends from Planck's to daylight's."""


def planck_xy(t: np.ndarray) -> np.ndarray:
    """CIE 1931 xy of a black body at ``t`` kelvin, 1667..25000 K, shape (..., 2): the cubic
    spline of B. Kang, O. Moon, C. Hong, H. Lee, B. Cho, Y. Kim, "Design of advanced color
    temperature control system for HDTV applications", J. Korean Phys. Soc. 41 (2002), within
    about 0.0003 of the integral.

    >>> np.round(planck_xy(np.array(2856.0)), 4).tolist()   # illuminant A, 2856 K on the old c2 scale: (0.4476, 0.4074)
    [0.4471, 0.4075]
    """
    t = np.clip(np.asarray(t, dtype=np.float64), 1667.0, 25000.0)
    x = np.where(t <= 4000.0,
                 -0.2661239e9 / t ** 3 - 0.2343589e6 / t ** 2 + 0.8776956e3 / t + 0.179910,
                 -3.0258469e9 / t ** 3 + 2.1070379e6 / t ** 2 + 0.2226347e3 / t + 0.240390)
    y = np.where(t <= 2222.0, -1.1063814 * x ** 3 - 1.34811020 * x ** 2 + 2.18555832 * x - 0.20219683,
                 np.where(t <= 4000.0, -0.9549476 * x ** 3 - 1.37418593 * x ** 2 + 2.09137015 * x - 0.16748867,
                          3.0817580 * x ** 3 - 5.87338670 * x ** 2 + 3.75112997 * x - 0.37001483))
    return np.stack([x, y], axis=-1)


def daylight_xy(t: np.ndarray) -> np.ndarray:
    """CIE 1931 xy of CIE daylight at ``t`` kelvin, 4000..25000 K (CIE 15:2004, eq. 3.3-3.4),
    shape (..., 2).

    >>> np.round(daylight_xy(np.array(6504.0)), 4).tolist()     # D65 (tabulated: 0.3127, 0.3290)
    [0.3127, 0.3291]
    """
    t = np.clip(np.asarray(t, dtype=np.float64), 4000.0, 25000.0)
    x = np.where(t <= 7000.0, 0.244063 + 0.09911e3 / t + 2.9678e6 / t ** 2 - 4.6070e9 / t ** 3,
                 0.237040 + 0.24748e3 / t + 1.9018e6 / t ** 2 - 2.0064e9 / t ** 3)
    return np.stack([x, -3.000 * x ** 2 + 2.870 * x - 0.275], axis=-1)


def _xy_to_uv(xy: np.ndarray) -> np.ndarray:
    x, y = xy[..., 0], xy[..., 1]
    d = -2.0 * x + 12.0 * y + 3.0
    return np.stack([4.0 * x / d, 6.0 * y / d], axis=-1)


def _uv_to_xy(uv: np.ndarray) -> np.ndarray:
    u, v = uv[..., 0], uv[..., 1]
    d = 2.0 * u - 8.0 * v + 4.0
    return np.stack([3.0 * u / d, 2.0 * v / d], axis=-1)


def locus_uv(t: np.ndarray) -> np.ndarray:
    """CIE 1960 uv of the lights' locus at ``t`` kelvin (module docstring), shape (..., 2)."""
    t = np.asarray(t, dtype=np.float64)
    lo, hi = LOCUS_BLEND_K
    a = np.clip((t - lo) / (hi - lo), 0.0, 1.0)[..., None]
    return (1.0 - a) * _xy_to_uv(planck_xy(t)) + a * _xy_to_uv(daylight_xy(t))


def light_xy(t: np.ndarray, duv: np.ndarray | float = 0.0) -> np.ndarray:
    """CIE 1931 xy of the light (T, Duv): the locus point at ``t`` moved ``duv`` along its normal
    in CIE 1960 uv (positive: towards green, as Duv is usually signed: above Planck's locus)."""
    t = np.asarray(t, dtype=np.float64)
    uv = locus_uv(t)
    step = locus_uv(t * 1.001) - locus_uv(t / 1.001)
    tangent = step / np.linalg.norm(step, axis=-1, keepdims=True)
    normal = np.stack([-tangent[..., 1], tangent[..., 0]], axis=-1)      # T up: u down, v down
    normal = np.where(normal[..., 1:2] < 0, -normal, normal)            # +Duv: v up (greener)
    return _uv_to_xy(uv + np.asarray(duv, dtype=np.float64)[..., None] * normal)


def light_srgb(t: np.ndarray, duv: np.ndarray | float = 0.0) -> np.ndarray:
    """Linear sRGB colour of the light (T, Duv) at luminance Y = 1, shape (..., 3) (D65 is about
    (1, 1, 1); its blue is near 0 at 1900 K).

    >>> np.round(light_srgb(np.array(6504.0)) / light_srgb(np.array(6504.0))[1], 2).tolist()
    [1.0, 1.0, 1.0]
    """
    xy = light_xy(t, duv)
    xyz = np.stack([xy[..., 0] / xy[..., 1], np.ones(xy.shape[:-1]), (1 - xy[..., 0] - xy[..., 1]) / xy[..., 1]],
                   axis=-1)
    return xyz @ XYZ_TO_SRGB.T


@dataclass(frozen=True)
class CameraLights:
    """The lights as a camera sees them. ``matrix``: white-balanced camera -> linear sRGB (3 x 3);
    ``daylight``: the pass-1 multipliers of D65 (n_channels = 3, reference channel 1).

    ``balanced(w)`` is the camera's response to a white surface under linear sRGB colour ``w``
    after the daylight multipliers (M^-1 w, so D65 gives M^-1 1); ``gains(w)`` its pass-1
    multipliers, d * (M^-1 1) / (M^-1 w)."""

    matrix: np.ndarray
    daylight: np.ndarray

    def balanced(self, w: np.ndarray) -> np.ndarray:
        return np.asarray(w, dtype=np.float64) @ np.linalg.inv(self.matrix).T

    def gains(self, w: np.ndarray) -> np.ndarray:
        white = self.balanced(np.ones(3))
        return np.asarray(self.daylight, dtype=np.float64) * white / self.balanced(w)


# --------------------------------------------------------------------------------------------
# 2. The statistics
# --------------------------------------------------------------------------------------------

BLOCKS = 1024
"""About this many blocks cover the image: a block is the side sqrt(cells / BLOCKS) in read
cells, at least MIN_BLOCK_CELLS (a 768 x 512 Bayer raw: 9 x 9 cells, 18 px; the 24 MP Bayer
raw: 23 x 23 read cells, 184 px), so that the evidence weighs the same share of any image."""
MIN_BLOCK_CELLS = 4
"""Smallest block side, cells."""
GREY_INDEX = 0.15
"""A cell is a grey-edge cell when the relative spread of its three channels' log-contrast is
below this (0: the channels change in one proportion, as at an edge between neutral surfaces
or in the shading of any one surface; Yang, Gao and Li's greyness index)."""
BRIGHT_POWER = 8.0
"""Exponent of the bright soft maximum: a cell half as bright as the block's brightest weighs 1/256."""
GREY_MIN_CONTRAST = 0.02
"""Log-contrast a cell needs in every channel to be measured for greyness (2 %: well above the
quantisation of a dark 10-bit sample, below the edges of textured surfaces)."""


@dataclass
class BlockStats:
    """Per-block statistics of a mosaic, on a grid of ``block`` x ``block`` CFA cells (shape
    (by, bx) blocks). Values are black-subtracted and divided by (white - black), one camera
    channel per column (the CFA's channel order), before any white balance. Every sum runs over
    the block's unclipped cells only; a cell with a clipped sample counts in ``clipped`` alone.

    ``count``         (by, bx)     unclipped cells
    ``clipped``       (by, bx)     cells with a clipped sample
    ``sum``           (by, bx, 3)  sum of the cells' channel values (mean = sum / count)
    ``grey_weight``   (by, bx)     sum of the grey-edge cells' mean log-contrast: a cell is a
                                   grey-edge cell when it and its right and lower neighbours are
                                   unclipped, its log-contrast to them is >= GREY_MIN_CONTRAST in
                                   every channel and the channels' relative spread of it is below
                                   GREY_INDEX; stronger edges weigh more (noise makes weak ones)
    ``grey_sum``      (by, bx, 3)  the grey-edge cells' channel values, each times its weight
    ``bright_weight`` (by, bx)     sum of (cell's channel sum) ^ BRIGHT_POWER
    ``bright_sum``    (by, bx, 3)  the cells' channel values, each times that weight: a soft
                                   maximum, bright_sum / bright_weight is about the mean of the
                                   block's few brightest cells (less noisy than its brightest)
    ``step``          the cell subsampling: every step-th cell row and column was read
    """

    count: np.ndarray
    clipped: np.ndarray
    sum: np.ndarray
    grey_weight: np.ndarray
    grey_sum: np.ndarray
    bright_weight: np.ndarray
    bright_sum: np.ndarray
    block: int = MIN_BLOCK_CELLS
    step: int = 1
    channels: tuple[str, ...] = field(default=("R", "G", "B"))


def cell_means(data: np.ndarray, cfa: CFA, black_level: np.ndarray, white_level: float,
               max_cells: int = MAX_CELLS) -> tuple[np.ndarray, np.ndarray, int]:
    """(cells, clipped, step): one camera triplet per whole CFA cell, the mean of each channel's
    normalised samples in it, float32 (H/p/step, W/p/step, n); ``clipped`` marks cells with a
    sample at or above clisp.scene.statistics.CLIP_FRACTION; every ``step``-th cell row and column when the raw has more
    than ``max_cells`` cells: the statistics pass's cell thumbnail (clisp.scene.statistics)."""
    step = thumbnail_step(data.shape, cfa.period, max_cells)
    cells, clipped = cell_thumbnail(data, cfa, black_level, white_level, step)
    return cells, clipped, step


def block_statistics(data: np.ndarray, cfa: CFA, black_level: np.ndarray, white_level: float,
                     block: int | None = None, max_cells: int = MAX_CELLS) -> BlockStats:
    """The :class:`BlockStats` of a mosaic ``data`` (H x W, DN with black) on CFA ``cfa``: cells
    by :func:`cell_means`, then :func:`block_statistics_of`."""
    cells, clipped, step = cell_means(data, cfa, black_level, white_level, max_cells)
    return block_statistics_of(cells, clipped, step, tuple(cfa.channels), block)


def block_statistics_of(cells: np.ndarray, clipped: np.ndarray, step: int, channels: tuple[str, ...],
                        block: int | None = None) -> BlockStats:
    """The :class:`BlockStats` of a cell thumbnail (``cells`` (ty, tx, n) normalised camera
    triplets, ``clipped`` (ty, tx), every ``step``-th cell: the statistics pass's, clisp.scene.
    statistics.SceneStatistics): per block of ``block`` x ``block`` cells (None: BLOCKS blocks over
    the image; the last partial row and column of blocks dropped) the sums of BlockStats."""
    if block is None:
        block = max(MIN_BLOCK_CELLS, int(np.sqrt(cells.shape[0] * cells.shape[1] / BLOCKS)))
    b = max(1, min(block, cells.shape[0], cells.shape[1]))
    by, bx = cells.shape[0] // b, cells.shape[1] // b
    cells, clipped = cells[:by * b, :bx * b], clipped[:by * b, :bx * b]
    ok = ~clipped

    # grey-edge cells: the relative spread of the channels' log-contrast to the right and lower cells
    logs = np.log(np.maximum(cells, 1e-4))
    gx = np.zeros_like(logs)
    gy = np.zeros_like(logs)
    gx[:, :-1] = np.diff(logs, axis=1)
    gy[:-1] = np.diff(logs, axis=0)
    contrast = np.sqrt(gx * gx + gy * gy)
    n = cells.shape[-1]
    planes = [contrast[..., c] for c in range(n)]      # per channel: NumPy reduces a last axis of 3 slowly
    mean = sum(planes[1:], planes[0]) / np.float32(n)
    spread = np.sqrt(sum(((p - mean) ** 2 for p in planes[1:]), (planes[0] - mean) ** 2) / np.float32(n))
    grey = ok & (spread < GREY_INDEX * mean)
    for plane in planes:
        grey &= plane >= GREY_MIN_CONTRAST
    grey[:, :-1] &= ok[:, 1:]
    grey[:-1] &= ok[1:]
    grey[:, -1] = grey[-1, :] = False
    weight = np.where(grey, mean, 0.0).astype(np.float32)
    # bright: a soft maximum per block, the cells weighted by (channel sum) ^ BRIGHT_POWER
    level = sum((cells[..., c] for c in range(1, n)), cells[..., 0])
    power = np.where(ok, level, np.float32(0.0)).astype(np.float32) ** np.float32(BRIGHT_POWER)
    # every per-cell quantity in one float32 plane (planes, not a last axis: writing 13 strided
    # columns cost 30 ms on 375 k cells), summed per block in float64: the rows of each block row
    # first, then each block's columns
    k = 4 + 3 * n
    planes = np.zeros((k,) + cells.shape[:2], dtype=np.float32)
    planes[0], planes[1], planes[2 + n], planes[3 + 2 * n] = ok, clipped, weight, power
    for c in range(n):
        np.copyto(planes[2 + c], cells[..., c], where=ok)
        np.multiply(cells[..., c], weight, out=planes[3 + n + c])
        np.multiply(cells[..., c], power, out=planes[4 + 2 * n + c])
    rows = planes.reshape(k, by, b, -1).sum(axis=2, dtype=np.float64)
    sums = rows.reshape(k, by, bx, b).sum(axis=3).transpose(1, 2, 0)
    return BlockStats(count=sums[..., 0].astype(np.int64), clipped=sums[..., 1].astype(np.int64),
                      sum=sums[..., 2:2 + n], grey_weight=sums[..., 2 + n],
                      grey_sum=sums[..., 3 + n:3 + 2 * n], bright_weight=sums[..., 3 + 2 * n],
                      bright_sum=sums[..., 4 + 2 * n:], block=b, step=step, channels=tuple(channels))


# --------------------------------------------------------------------------------------------
# 3. The estimate
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Evidence:
    """The estimate's constants (:func:`estimate_light`), tuned on scenes made in code only
    (tools/wb_scenes.py; tools/tune_wb_auto.py --tune). Chroma is measured on the implied surface's
    linear sRGB, as log(channel) less the mean of the three logs (0 for a neutral; 0.1 is about
    10 % between channels)."""

    mired: tuple[float, float, float] = (50.0, 560.0, 10.0)
    """The lights' grid in mired (10^6 / T): first, last, step (20000 K .. 1786 K); the estimate
    is refined REFINE times finer around the grid's best."""
    duv: tuple[float, float, float] = (-0.02, 0.02, 0.004)
    """The lights' grid in Duv: first, last, step."""
    bright_share: float = 0.025
    """Share of the blocks whose soft maximum is a bright candidate (the brightest ones)."""
    bright_sigma: float = 0.2
    """Chroma scale of the bright candidates' kernel (Cauchy: 1 / (1 + (chroma / sigma)^2))."""
    bright_weight: float = 2.0
    """Weight of the bright term's log-likelihood."""
    grey_sigma: float = 0.2
    """Chroma scale of the grey-edge cells' kernel."""
    grey_weight: float = 0.25
    """Weight of the grey-edge term's log-likelihood."""
    grey_brightness: float = 4.0
    """A block's grey-edge cells weigh (their weight) x (their mean level / the 98th percentile) ^ this:
    bright grey edges (whites, metal) count, dark ones (noise, shadows) barely."""
    mean_sigma: float = 0.7
    """Chroma scale of the gray-world term (a Gaussian on the chroma of the scene's mean)."""
    mean_weight: float = 0.1
    """Weight of the gray-world term's log-likelihood."""
    prior_mired: float = 150.0
    """The prior's most likely light, mired (6667 K: daylight between sun and shade)."""
    prior_mired_sigma: float = 100.0
    """The prior's spread in mired (Gaussian): 2900 K and 4 x 10^4 K are two sigma away."""
    prior_duv_sigma: float = 0.003
    """The prior's spread in Duv (Gaussian around the locus)."""
    floor: float = 1e-3
    """Added to each kernel average before the logarithm: a term never vetoes a light alone."""
    allowed_nats: float = 2.0
    """The evidence *allows* the lights whose evidence (terms without the prior) is within this many
    nats of its best."""


EVIDENCE = Evidence()

TERMS = ("bright", "grey", "mean")
"""The evidence terms, in the order --explain names them."""
TERM_NAMES = {"bright": "bright surfaces", "grey": "grey edges", "mean": "gray world", "prior": "the prior"}


@dataclass
class Estimate:
    """The light :func:`estimate_light` found and why.

    ``temperature`` (K) and ``duv``: the light; ``srgb``: its linear sRGB colour (Y = 1); ``gains``:
    pass-1 multipliers per CFA channel (reference channel 1); ``confidence`` in [0, 1]: the
    posterior's mass within 20 mired and 0.004 Duv of the estimate; ``allowed``: the range of
    temperatures (K, low..high) the evidence allows (Evidence.allowed_nats); ``shares``: how much
    each term (TERMS and 'prior') pulled towards the estimate against the prior's most likely light
    allowed, fractions summing to 1; ``candidates``: how many bright and grey-edge candidates."""

    temperature: float
    duv: float
    srgb: np.ndarray
    gains: np.ndarray
    confidence: float
    allowed: tuple[float, float]
    shares: dict[str, float]
    candidates: dict[str, int]

    def describe(self) -> str:
        """One line for ``clisp process --explain``."""
        decided = ", ".join(f"{TERM_NAMES[k]} {v:.0%}" for k, v in sorted(self.shares.items(), key=lambda kv: -kv[1])
                            if v >= 0.005)
        lo, hi = self.allowed
        return (f"white balance auto: {self.temperature:.0f} K, Duv {self.duv:+.3f}, multipliers "
                f"{', '.join(f'{g:.3f}' for g in self.gains)}; confidence {self.confidence:.2f} "
                f"(evidence allows {lo:.0f}-{hi:.0f} K); decided by {decided or 'the prior alone'} "
                f"({self.candidates['bright']} bright, {self.candidates['grey']} grey-edge candidates)")


def _grid(spec: tuple[float, float, float]) -> np.ndarray:
    first, last, step = spec
    return np.arange(first, last + step / 2, step)


def _chroma_kernel(y: np.ndarray, matrix: np.ndarray, q: np.ndarray, sigma: float) -> np.ndarray:
    """Cauchy kernel of the implied surfaces' chroma, shape (n, H): candidates ``y`` (n, 3,
    daylight-balanced camera), each light's multipliers ``q`` (H, 3) on them, ``matrix`` to sRGB."""
    a = (y[:, None, :] * matrix[None, :, :]).astype(np.float32)           # a[n, i, k] = M[i, k] y[n, k]
    s = a @ q.T.astype(np.float32)                                        # (n, 3, H) implied sRGB
    planes = [s[:, i] for i in range(s.shape[1])]                        # per channel (NumPy reduces an axis of 3 slowly)
    low = np.maximum(np.maximum.reduce(planes), np.float32(1e-12)) * np.float32(1e-2)
    logs = [np.log(np.maximum(plane, low)) for plane in planes]
    mean = sum(logs[1:], logs[0]) / np.float32(len(logs))
    spread = sum(((v - mean) ** 2 for v in logs[1:]), (logs[0] - mean) ** 2)
    return 1.0 / (1.0 + spread / np.float32(sigma * sigma))


def estimate_light(stats: BlockStats, lights: CameraLights, reference: int,
                   evidence: Evidence = EVIDENCE) -> Estimate:
    """The scene's light among the plausible ones, from block statistics.

    Reads of :class:`BlockStats` exactly: ``sum`` (the gray-world term), ``bright_weight`` and
    ``bright_sum`` (the bright term), ``grey_weight`` and ``grey_sum`` (the grey-edge term).
    ``count`` and ``clipped`` are not needed (clipped cells are already out of every sum).

    The lights are a grid over (mired, Duv) (Evidence.mired, Evidence.duv). For a light h with
    pass-1 multipliers g_h, each candidate colour y (a daylight-balanced camera triplet) implies the
    surface M diag(g_h / d) y in linear sRGB. Three terms score how neutral the evidence's surfaces
    would be under h (each a log of a weighted mean of Cauchy kernels of the implied chroma, or a
    Gaussian, with their Evidence constants):

    * **bright**: the soft maximum (a few brightest unclipped cells) of each of the brightest blocks
      (whites, paper, the rims of specular highlights of the light, which a clipped core leaves);
    * **grey**: per block, the grey-edge cells' mean colour (cells where every channel changes in
      one proportion: edges between neutral surfaces, and the shading of any one surface),
      weighted towards strong and bright ones (Yang, Gao and Li, CVPR 2015, as a statistic per
      block);
    * **mean**: the scene's mean (gray world), a weak Gaussian.

    The log posterior is their weighted sum plus the log prior over the lights (Gaussian in mired
    and in Duv, Evidence.prior_*); the estimate is its maximum. Where the evidence is weak (flat
    terms: a flat field, one coloured surface without edges), the prior decides among the lights
    the evidence allows, so the answer is the prior's most likely light *within* what the scene
    permits, not a fixed daylight. A coloured surface that fills the frame pulls the grey and mean
    terms towards its own colour, but bright near-neutral surfaces (a white cup) and the prior's
    doubt of off-locus or extreme lights outvote it.

    ``reference``: the channel whose multiplier is 1. Returns an :class:`Estimate`.
    """
    matrix = np.asarray(lights.matrix, dtype=np.float64)
    daylight = np.asarray(lights.daylight, dtype=np.float64)
    evidence_terms = _Terms(stats, matrix, daylight, evidence)
    mired, duv = _grid(evidence.mired), _grid(evidence.duv)
    mm, dd = np.meshgrid(mired, duv, indexing="ij")
    shape = mm.shape
    terms = evidence_terms.score(lights, mm.ravel(), dd.ravel())
    evidence_sum = sum(terms.values(), np.zeros(mm.size)).reshape(shape)
    prior = _log_prior(mm, dd, evidence)
    posterior = evidence_sum + prior
    best = np.unravel_index(int(np.argmax(posterior)), shape)
    allowed = evidence_sum >= evidence_sum.max() - evidence.allowed_nats
    # the prior's most likely light among those the evidence allows: what the prior alone would say
    fallback = np.unravel_index(int(np.argmax(np.where(allowed, prior, -np.inf))), shape)
    pulls = {k: float(v.reshape(shape)[best] - v.reshape(shape)[fallback]) for k, v in terms.items()}
    pulls["prior"] = float(prior[best] - prior[fallback])
    positive = {k: max(v, 0.0) for k, v in pulls.items()}
    total = sum(positive.values())
    shares = {k: v / total for k, v in positive.items()} if total > 0 else {"prior": 1.0}
    p = np.exp(posterior - posterior.max())
    near = (np.abs(mm - mm[best]) <= 20.0 + 1e-9) & (np.abs(dd - dd[best]) <= 0.004 + 1e-9)
    confidence = float(p[near].sum() / p.sum())
    temps = 1e6 / mm[allowed]
    # refine around the best light of the grid: a finer grid of REFINE points each way
    fm = mm[best] + np.linspace(-1.0, 1.0, 2 * REFINE + 1) * evidence.mired[2]
    fd = dd[best] + np.linspace(-1.0, 1.0, 2 * REFINE + 1) * evidence.duv[2]
    fm, fd = np.meshgrid(fm[fm > 0], fd, indexing="ij")
    fine = evidence_terms.score(lights, fm.ravel(), fd.ravel())
    refined = sum(fine.values(), np.zeros(fm.size)) + _log_prior(fm.ravel(), fd.ravel(), evidence)
    i = int(np.argmax(refined))
    t_best, duv_best = 1e6 / float(fm.ravel()[i]), float(fd.ravel()[i])
    srgb = light_srgb(np.array(t_best), duv_best)
    gains = lights.gains(srgb)
    return Estimate(temperature=t_best, duv=duv_best, srgb=srgb, gains=gains / gains[reference],
                    confidence=confidence, allowed=(float(temps.min()), float(temps.max())), shares=shares,
                    candidates=evidence_terms.counts)


REFINE = 4
"""The estimate is refined on a grid REFINE times finer than Evidence's, one coarse step each way."""


def _log_prior(mired: np.ndarray, duv: np.ndarray, evidence: Evidence) -> np.ndarray:
    """Log prior of the lights (mired, Duv): Gaussian in each (Evidence.prior_*)."""
    return -0.5 * ((mired - evidence.prior_mired) / evidence.prior_mired_sigma) ** 2 \
        - 0.5 * (duv / evidence.prior_duv_sigma) ** 2


class _Terms:
    """The evidence of :func:`estimate_light`, its candidates chosen once, scored for any lights."""

    def __init__(self, stats: BlockStats, matrix: np.ndarray, daylight: np.ndarray, evidence: Evidence) -> None:
        self.matrix, self.evidence = matrix, evidence
        self.counts = {"bright": 0, "grey": 0}
        self.bright = self.grey = self.grey_weight = self.total = None
        bright_weight = stats.bright_weight.reshape(-1)
        order = np.flatnonzero(bright_weight > 0)
        if order.size:
            bright = stats.bright_sum.reshape(-1, 3)[order] / bright_weight[order, None] * daylight
            k = max(1, int(round(evidence.bright_share * order.size)))
            self.bright = bright[np.argsort(bright.sum(axis=1))[-k:]]
            self.counts["bright"] = int(k)
        grey_weight = stats.grey_weight.reshape(-1)
        has = np.flatnonzero(grey_weight > 0)
        if has.size:
            grey = stats.grey_sum.reshape(-1, 3)[has] * daylight / grey_weight[has, None]
            level = grey.sum(axis=1)
            weight = grey_weight[has] * np.clip(level / max(float(np.percentile(level, 98)), 1e-12), 0.0, 1.0) \
                ** evidence.grey_brightness
            if weight.sum() > 0:
                self.grey, self.grey_weight = grey, weight / weight.sum()
                self.counts["grey"] = int(has.size)
        total = stats.sum.reshape(-1, 3).sum(axis=0) * daylight
        self.total = total if np.all(total > 0) else None

    def score(self, lights: CameraLights, mired: np.ndarray, duv: np.ndarray) -> dict[str, np.ndarray]:
        """Each term's weighted log-likelihood of the lights (mired[i], duv[i]), shape (n,) each."""
        ev = self.evidence
        inverse = np.linalg.inv(self.matrix)
        q = (inverse @ np.ones(3)) / (light_srgb(1e6 / mired, duv) @ inverse.T)   # multipliers on balanced values
        terms = {}
        if self.bright is not None:
            kernel = _chroma_kernel(self.bright, self.matrix, q, ev.bright_sigma)
            terms["bright"] = ev.bright_weight * np.log(kernel.mean(axis=0) + ev.floor)
        if self.grey is not None:
            kernel = _chroma_kernel(self.grey, self.matrix, q, ev.grey_sigma)
            terms["grey"] = ev.grey_weight * np.log(self.grey_weight @ kernel + ev.floor)
        if self.total is not None:
            s = (self.matrix * self.total[None, :]) @ q.T                   # (3, n) implied sRGB of the mean
            logs = np.log(np.maximum(s, s.max(axis=0) * 1e-2))
            chroma = logs - logs.mean(axis=0)
            terms["mean"] = -0.5 * ev.mean_weight * (chroma * chroma).sum(axis=0) / ev.mean_sigma ** 2
        return terms
