"""White balance pass 1 on the raw mosaic: the choice (``--wb``) and the estimates
(docs/model.md section 4).

``--wb`` picks the pass-1 multipliers per CFA channel (:func:`with_white_balance`):

``camera``      as shot: the camera's multipliers where the raw has them; a raw read without them
                (the Canon D30 CRW: clisp.io.rawimage.NO_CAMERA_WB) gets its scene's grey pixels
                (:func:`grey_pixel_gains`, from the run's statistics), as LibRaw falls back to its
                auto white balance; clisp's simulated raws carry their known illuminant (D65).
``auto``        the scene's light among the plausible ones (:func:`auto_gains`, clisp.scene.illuminant:
                bright surfaces, grey edges and gray world weighed against a prior over the
                Planckian and daylight lights in the camera's space); a raw without daylight
                multipliers (so without a known D65 white) falls back to its grey pixels
                (:func:`grey_pixel_gains`).
``daylight``    the camera's daylight multipliers (LibRaw's ``pre_mul``, what rawpy's default
                postprocess uses); clisp's simulations are all lit by D65, so theirs is the known one.
``R,G,B``       multipliers in the CFA's channel order (R, G, B or L, M, S), scaled so the
                reference channel's is 1.

Gray world (:func:`gray_world_gains`, the fallback of a scene without grey pixels):
gain_c = mean(reference channel) / mean(channel c), over the CFA blocks that hold no clipped
pixel (a clipped pixel's block is dropped with it, so clipping cannot bias a channel).
The reference channel is G for Bayer and L for LMS, whose gain is therefore 1.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from ..cfa import CFA
from ..engine import host_threads
from ..errors import ClispError, clip
from ..io.rawimage import MAX_GAIN, NO_CAMERA_WB, RawImage
from .statistics import thumbnail

WB_CHOICES = ("camera", "auto", "daylight")
"""The named ``--wb`` choices; anything else is read as multipliers."""

CLIP_FRACTION = 0.98
"""A pixel at or above black + 0.98 (white - black) counts as clipped."""


def reference_channel(cfa: CFA) -> int:
    """Index of the channel whose gain is 1: G for Bayer, L (the first) otherwise."""
    return cfa.channels.index("G") if "G" in cfa.channels else 0


def gray_world_gains(data: np.ndarray, cfa: CFA, black_level: np.ndarray, white_level: float) -> np.ndarray:
    """Gray-world pass-1 multipliers per CFA channel, shape (n_channels,), reference channel = 1.

    ``data``: H x W mosaic in DN (black included). Uses whole CFA blocks (period x period) only.
    """
    p = cfa.period
    h, w = data.shape[0] // p * p, data.shape[1] // p * p
    black = np.asarray(black_level, dtype=np.float64)
    channel = cfa.channel_map(p, p)
    blocks = data[:h, :w].astype(np.float64).reshape(h // p, p, w // p, p).transpose(0, 2, 1, 3)
    signal = blocks - black[channel]
    clipped = blocks >= black[channel] + CLIP_FRACTION * (float(white_level) - black[channel])
    keep = ~clipped.any(axis=(2, 3))
    if not keep.any():
        raise ClispError("gray-world white balance: every CFA block has a clipped pixel")
    means = np.array([signal[keep][:, channel == c].mean() for c in range(cfa.n_channels)])
    if np.any(means <= 0):
        raise ClispError("gray-world white balance: a channel has no signal above black")
    return means[reference_channel(cfa)] / means


# --------------------------------------------------------------------------------------------
# Grey pixels (``--wb auto``)
# --------------------------------------------------------------------------------------------

GREY_SHARE = 0.01
"""Share of the thumbnail's pixels taken as grey-pixel candidates (the 1 % greyest)."""
GREY_MIN_PIXELS = 64
"""At least this many candidates (small raws), when that many are usable."""
GREY_SIGMA = 0.5
"""Gaussian derivative scale of the log-contrast, thumbnail pixels (Yang et al.'s GPedge)."""
GREY_WINDOW = 7
"""Side of the box that averages the greyness index (Yang et al.)."""
GREY_MIN_CONTRAST = 1e-3
"""Log-contrast below this in any channel carries no information (flat): not a candidate."""
GREY_DARK_FRACTION = 0.01
"""Pixels darker than this fraction of the 99th percentile are noise: not candidates."""
GREY_BANDWIDTH = 0.2
"""Mean-shift bandwidth on the candidates' log chromaticities (0.2: about 20 % in a gain)."""
GREY_SHIFT_STEPS = 30
"""Most mean-shift steps (it converges in under 10 on the raws tried)."""


def grey_pixel_gains(data: np.ndarray, cfa: CFA, black_level: np.ndarray, white_level: float,
                     share: float = GREY_SHARE, statistics: Any = None) -> tuple[np.ndarray, str]:
    """Pass-1 multipliers per CFA channel from the scene's grey pixels, reference channel = 1, and
    the method's name.

    1. Grey pixels, after K.-F. Yang, S.-B. Gao, Y.-J. Li, "Efficient illuminant estimation for
       color constancy using grey pixels", CVPR 2015. On a raw thumbnail (one camera triplet per
       CFA cell: the statistics pass's cell thumbnail, clisp.scene.statistics) the illuminant-invariant measure of each
       channel is the local contrast of its logarithm, |grad log I_c| (Gaussian derivative,
       GREY_SIGMA): the edge between two grey surfaces changes every channel in the same
       proportion under any illuminant, an edge involving a coloured surface changes them
       unequally. The greyness index is the three contrasts' relative standard deviation,
       averaged over GREY_WINDOW x GREY_WINDOW; the ``share`` greyest pixels (at least
       GREY_MIN_PIXELS) among those with contrast in every channel, no clipped sample nearby and
       above the dark end are the candidates.
    2. Their dominant colour, after Y. Qian, K. Chen, J. Nikkanen, J.-K. Kamarainen, J. Matas,
       "Revisiting gray pixel for statistical illumination estimation", VISAPP 2019: shading on
       one coloured surface also changes the channels in proportion, so some candidates are not
       grey; the true grey ones agree on one colour. A brightness-weighted mean shift on the
       candidates' log chromaticities (log(c / reference), Gaussian kernel of GREY_BANDWIDTH,
       from their median) finds that colour, and the candidates within GREY_BANDWIDTH of it,
       summed, are the illuminant.

    Unlike gray world this needs no assumption on the scene's average colour: a dominant coloured
    surface (wood, foliage, sky) does not pull the estimate; edges of neutral objects (metal,
    paper, greys, black frames against white) drive it. A scene without such pixels (a flat
    field) falls back to gray world (:func:`gray_world_gains`), and says so in the name.

    ``statistics``: the raw's clisp.scene.statistics.SceneStatistics, whose cell thumbnail (every
    k-th cell of at most 2^19) is the thumbnail, and the gray-world fallback is taken over its
    unclipped cells; None reads that thumbnail here.
    """
    cells, clipped = statistics.thumbnail() if statistics is not None else \
        thumbnail(data, cfa, black_level, white_level)
    thumb, ok = cells.astype(np.float64), ~clipped
    candidates = _grey_candidates(thumb, ok, share)
    if candidates is None:
        return _thumbnail_gray_world(thumb, ok, cfa), "gray world (no grey pixels found)"
    ref = reference_channel(cfa)
    illuminant = _dominant_colour(candidates, ref)
    return illuminant[ref] / illuminant, "auto (grey pixels)"


def _thumbnail_gray_world(thumb: np.ndarray, ok: np.ndarray, cfa: CFA) -> np.ndarray:
    """Gray-world multipliers (reference channel = 1) over a thumbnail's unclipped cells."""
    if not ok.any():
        raise ClispError("gray-world white balance: every CFA block has a clipped pixel")
    means = thumb[ok].mean(axis=0)
    if np.any(means <= 0):
        raise ClispError("gray-world white balance: a channel has no signal above black")
    return means[reference_channel(cfa)] / means


def _grey_candidates(thumb: np.ndarray, ok: np.ndarray, share: float) -> np.ndarray | None:
    """The greyest pixels of ``thumb`` (R x C x 3, camera units), shape (n, 3), or None when
    fewer than GREY_MIN_PIXELS are usable (step 1 of :func:`grey_pixel_gains`)."""
    logs = np.log(np.maximum(thumb, 1e-6))
    contrast = np.stack(host_threads.map_items(lambda c: gradient_magnitude(logs[..., c], GREY_SIGMA),
                                               range(thumb.shape[-1])), axis=-1)   # a channel per core
    mean = channel_mean(contrast)
    index = np.sqrt(channel_mean((contrast - mean[..., None]) ** 2)) / np.maximum(mean, 1e-12)
    if not ok.any():
        return None
    level = channel_mean(thumb)
    usable = (eroded(ok, 2)
              & (level > GREY_DARK_FRACTION * percentile_linear(level[ok], 99))
              & every_channel_above(contrast, GREY_MIN_CONTRAST) & every_channel_above(thumb, 0.0))
    if usable.sum() < GREY_MIN_PIXELS:
        return None
    index = box_mean(np.where(usable, index, 1.0), GREY_WINDOW)
    candidates = np.flatnonzero(usable)
    n = min(candidates.size, max(GREY_MIN_PIXELS, int(share * usable.size)))
    chosen = candidates[np.argpartition(index.ravel()[candidates], n - 1)[:n]]
    return thumb.reshape(-1, thumb.shape[-1])[chosen]


def channel_mean(a: np.ndarray) -> np.ndarray:
    """``a.mean(axis=-1)`` of an R x C x 3 float array, bit for bit (the same additions in the same
    order), as three whole-plane additions: NumPy's reduction over a 3-long inner axis took 9 ms of a
    2^19-cell thumbnail on this project's 2-core VM, this 3 ms."""
    return row_sum(a) / 3 if a.shape[-1] == 3 else a.mean(axis=-1)


def row_sum(a: np.ndarray) -> np.ndarray:
    """``a.sum(axis=-1)`` of an n x k array (k of 2 or 3), bit for bit, column by column."""
    total = a[..., 0] + a[..., 1]
    for c in range(2, a.shape[-1]):
        total = total + a[..., c]
    return total


def every_channel_above(a: np.ndarray, level: float) -> np.ndarray:
    """``np.all(a > level, axis=-1)`` of an R x C x k array, plane by plane (NumPy's reduction
    over a short inner axis is the slow one)."""
    above = a[..., 0] > level
    for c in range(1, a.shape[-1]):
        above &= a[..., c] > level
    return above


def percentile_linear(values: np.ndarray, q: float) -> float:
    """``np.percentile(values, q)`` (its default, linear method), bit for bit, by one partition: in
    NumPy 2 the first percentile of a process imports numpy.ma (30 ms of a run).

    >>> percentile_linear(np.array([4.0, 1.0, 3.0, 2.0]), 50), percentile_linear(np.arange(101.0), 99.5)
    (2.5, 99.5)
    """
    a = np.asarray(values).ravel()
    virtual = (a.size - 1) * np.true_divide(q, 100)          # NumPy's virtual index and weight
    below = min(max(int(np.floor(virtual)), 0), a.size - 1)
    above = min(below + 1, a.size - 1)
    gamma = virtual - below
    part = np.partition(a, [below, above])
    lo, hi = part[below], part[above]
    diff = hi - lo
    return float(hi - diff * (1 - gamma) if gamma >= 0.5 else lo + diff * gamma)   # NumPy's _lerp


# The three filters of the grey-pixel search, in NumPy: scipy.ndimage computes the same (to float64
# rounding; tests/scene/test_white_balance.py compares them), but importing it costs 0.4 s of every run
# of a raw without camera white balance, where the filters take a few ms on the 2^19-cell thumbnail.

def _gaussian_kernel(sigma: float, order: int) -> np.ndarray:
    """scipy.ndimage's Gaussian (order 0) or its derivative (order 1), radius int(4 sigma + 0.5),
    as the correlation weights gaussian_filter1d uses (the kernel reversed)."""
    radius = int(4.0 * sigma + 0.5)
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    phi = np.exp(-0.5 / sigma ** 2 * x ** 2)
    phi /= phi.sum()
    kernel = phi if order == 0 else -x / sigma ** 2 * phi
    return kernel[::-1]


def _correlate1d(a: np.ndarray, weights: np.ndarray, axis: int) -> np.ndarray:
    """``a`` correlated with ``weights`` (odd length) along ``axis``, edges repeated (mode 'nearest')."""
    r = len(weights) // 2
    pad = [(0, 0)] * a.ndim
    pad[axis] = (r, r)
    padded = np.pad(a, pad, mode="edge")
    n = a.shape[axis]

    def shifted(k: int) -> np.ndarray:
        index = [slice(None)] * a.ndim
        index[axis] = slice(k, k + n)
        return padded[tuple(index)]

    out = weights[0] * shifted(0)
    for k in range(1, len(weights)):
        out += weights[k] * shifted(k)
    return out


def gradient_magnitude(a: np.ndarray, sigma: float) -> np.ndarray:
    """scipy.ndimage.gaussian_gradient_magnitude(a, sigma, mode='nearest') of a 2-D float array: the
    root of the squared Gaussian derivatives along each axis (smoothed along the other).

    >>> ramp = np.tile(np.arange(6.0), (4, 1))          # slope 1 along the columns: the sampled
    >>> np.round(gradient_magnitude(ramp, 0.5)[1:3, 2:4], 5).tolist()   # derivative at sigma 0.5 gives 0.86
    [[0.86005, 0.86005], [0.86005, 0.86005]]
    """
    smooth, derive = _gaussian_kernel(sigma, 0), _gaussian_kernel(sigma, 1)
    dy = _correlate1d(_correlate1d(a, derive, 0), smooth, 1)
    dx = _correlate1d(_correlate1d(a, smooth, 0), derive, 1)
    return np.sqrt(dy * dy + dx * dx)


def eroded(mask: np.ndarray, iterations: int) -> np.ndarray:
    """scipy.ndimage.binary_erosion(mask, iterations=..., border_value=1): each pass keeps a pixel
    whose 4 neighbours are set too (outside the image counts as set)."""
    out = mask.astype(bool)
    for _ in range(iterations):
        p = np.pad(out, 1, constant_values=True)
        out = out & p[:-2, 1:-1] & p[2:, 1:-1] & p[1:-1, :-2] & p[1:-1, 2:]
    return out


def box_mean(a: np.ndarray, size: int) -> np.ndarray:
    """scipy.ndimage.uniform_filter(a, size, mode='nearest') for an odd ``size``: the mean over the
    size x size box, edges repeated."""
    weights = np.full(size, 1.0 / size)
    return _correlate1d(_correlate1d(a, weights, 0), weights, 1)


def _dominant_colour(pixels: np.ndarray, ref: int) -> np.ndarray:
    """Sum of the ``pixels`` (n x 3) near the mode of their log chromaticity against channel
    ``ref`` (step 2 of :func:`grey_pixel_gains`), shape (3,)."""
    others = [c for c in range(pixels.shape[1]) if c != ref]
    chroma = np.log(pixels[:, others] / pixels[:, [ref]])
    weight = row_sum(pixels)
    mode = np.median(chroma, axis=0)
    for _ in range(GREY_SHIFT_STEPS):
        kernel = weight * np.exp(-0.5 * row_sum((chroma - mode) ** 2) / GREY_BANDWIDTH ** 2)
        new = (kernel[:, None] * chroma).sum(axis=0) / kernel.sum()
        done = np.allclose(new, mode, rtol=0, atol=1e-6)
        mode = new
        if done:
            break
    near = row_sum((chroma - mode) ** 2) <= GREY_BANDWIDTH ** 2
    return pixels[near].sum(axis=0) if near.any() else pixels.sum(axis=0)


# --------------------------------------------------------------------------------------------
# The choice (``--wb``)
# --------------------------------------------------------------------------------------------

def with_white_balance(raw: RawImage, choice: str = "camera", statistics: Any = None) -> RawImage:
    """``raw`` with the pass-1 multipliers ``choice`` picks (module docstring), and
    ``metadata['wb_source']`` saying which; ``raw`` itself for ``camera``. ClispError naming the
    raw for a choice it cannot serve (no daylight multipliers, unusable multipliers).
    ``statistics``: the raw's SceneStatistics for ``auto`` (None: measured from the mosaic)."""
    if choice == "camera" and has_camera_wb(raw):
        return raw
    extra = {}
    if choice == "camera":                      # a file without as-shot multipliers: its scene's grey pixels
        try:
            gains, how = grey_pixel_gains(raw.data, raw.cfa, raw.black_level, raw.white_level, statistics=statistics)
        except ClispError as exc:
            raise ClispError(f"{raw.source}: no camera white balance, and {clip(exc, 120)}") from exc
        return replace(raw, wb=gains, metadata={**raw.metadata, "wb_source": f"{how}, file has no camera WB"})
    if choice == "auto":
        gains, source, extra = auto_gains(raw, statistics)
    elif choice == "daylight":
        gains, source = daylight_gains(raw), "daylight"
    else:
        gains, source = parse_multipliers(choice, raw.cfa, raw.source), "multipliers (--wb)"
    return replace(raw, wb=gains, metadata={**raw.metadata, "wb_source": source, **extra})


def has_camera_wb(raw: RawImage) -> bool:
    """Whether ``raw`` was read with as-shot multipliers (False: clisp.io.rawimage.NO_CAMERA_WB)."""
    return (raw.metadata or {}).get("wb_source") != NO_CAMERA_WB


def auto_gains(raw: RawImage, statistics: Any = None) -> tuple[np.ndarray, str, dict[str, str]]:
    """``--wb auto``'s pass-1 multipliers (reference channel = 1), its short name (the output
    file's description) and ``{'wb_explain': line}`` (what ``--explain`` prints): :func:`scene_light_gains`
    with the raw's daylight multipliers where it has them (:func:`daylight_gains`), from the raw's
    ``statistics`` (clisp.scene.statistics; None: measured from the mosaic)."""
    try:
        daylight = daylight_gains(raw)
    except ClispError:
        daylight = None
    gains, source, explain = scene_light_gains(raw.data, raw.cfa, raw.black_level, raw.white_level,
                                               raw.colour_matrix, daylight, statistics)
    return gains, source, {"wb_explain": explain}


def scene_light_gains(data: np.ndarray, cfa: CFA, black_level: np.ndarray, white_level: float,
                      matrix: np.ndarray, daylight: np.ndarray | None,
                      statistics: Any = None) -> tuple[np.ndarray, str, str]:
    """(multipliers, short name, explanation line) of the scene's light, reference channel = 1.

    With the camera's D65 white known (``daylight``: its D65 pass-1 multipliers; ``matrix``:
    white-balanced camera -> linear sRGB) the light is estimated among the plausible ones from the
    mosaic's block statistics (clisp.scene.illuminant.estimate_light); without it (None), from the
    scene's grey pixels (:func:`grey_pixel_gains`), which need no matrix. Both read the cell thumbnail
    of ``statistics`` (clisp.scene.statistics.SceneStatistics), measured here when None."""
    if daylight is None:
        gains, source = grey_pixel_gains(data, cfa, black_level, white_level, statistics=statistics)
        return gains, source, (f"white balance auto: {source} (no daylight multipliers, so no plausible "
                               f"lights to choose among)")
    from .illuminant import CameraLights, block_statistics, block_statistics_of, estimate_light   # deferred: only --wb auto
    ref = reference_channel(cfa)
    daylight = np.asarray(daylight, dtype=np.float64) / float(daylight[ref])
    if statistics is not None:
        stats = block_statistics_of(*statistics.thumbnail(), statistics.step, tuple(cfa.channels))
    else:
        stats = block_statistics(data, cfa, black_level, white_level)
    estimate = estimate_light(stats, CameraLights(np.asarray(matrix, dtype=np.float64), daylight), ref)
    return estimate.gains, f"auto ({estimate.temperature:.0f} K)", estimate.describe()


def daylight_gains(raw: RawImage) -> np.ndarray:
    """The raw's daylight pass-1 multipliers (reference channel = 1): a camera raw's
    ``metadata['daylight_multipliers']`` (clisp.io.camera), a clisp simulation's own (D65)
    multipliers; ClispError naming the raw when it has neither."""
    md = raw.metadata or {}
    if md.get("daylight_multipliers") is not None:
        gains = np.asarray(md["daylight_multipliers"], dtype=np.float64).reshape(-1)
    elif md.get("simulator"):
        gains = np.asarray(raw.wb, dtype=np.float64)
    else:
        raise ClispError(f"{raw.source}: has no daylight white balance (try --wb auto or --wb camera)")
    if gains.shape != (raw.cfa.n_channels,) or not np.all(np.isfinite(gains)) or np.any(gains <= 0):
        raise ClispError(f"{raw.source}: its daylight white balance is unusable (try --wb auto)")
    return gains / gains[reference_channel(raw.cfa)]


def parse_multipliers(text: str, cfa: CFA, source: str = "") -> np.ndarray:
    """``--wb`` multipliers 'a,b,c' in the CFA's channel order, scaled so the reference channel's
    is 1, shape (n_channels,). ClispError naming ``source`` unless there is one positive finite
    number per channel within 1e-4..1e4 of each other.

    >>> from clisp.cfa import bayer_cfa
    >>> parse_multipliers("2,1,1.5", bayer_cfa()).tolist()
    [2.0, 1.0, 1.5]
    """
    names = ",".join(cfa.channels)
    try:
        values = np.array([float(v) for v in text.split(",")], dtype=np.float64)
    except ValueError:
        values = np.array([])
    if values.size != cfa.n_channels or not np.all(np.isfinite(values)) or np.any(values <= 0):
        raise ClispError(f"{source}: --wb {text!r} is neither camera, auto, daylight nor {cfa.n_channels} "
                         f"positive multipliers {names}")
    gains = values / values[reference_channel(cfa)]
    if np.any(gains > MAX_GAIN) or np.any(gains < 1.0 / MAX_GAIN):
        raise ClispError(f"{source}: --wb {text!r}: multipliers must lie within a factor {MAX_GAIN:g} "
                         f"of the {cfa.channels[reference_channel(cfa)]} one")
    return gains
