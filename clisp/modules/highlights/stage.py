"""Highlight handling: colour where the sensor clipped (issue 14).

After white balance pass 1 each channel c clips at its own level ``L_c = clip_c * gain_c``
(normalised clip level times the pass-1 gain), so a blown white whose channels all clipped comes
out as (L_0, L_1, L_2): coloured. This stage runs right after the demosaic, on the white-balanced
camera channels (H x W x 3; LMS in LMS space), and decides per pixel from the demosaiced values.

Notation: ``n`` is the neutral of the camera space, the white-balanced camera values that the
colour matrix and white balance pass 2 take to a grey (n = M^-1 W2^-1 (1, 1, 1)); every channel is
measured in units of it, ``y_c = x_c / n_c`` (a neutral pixel has equal y). A channel is clipped
where ``y_c >= t_c``, ``t_c = CLIP_FRACTION L_c / n_c`` (the scene analysis' threshold,
clisp.analysis, so a raw the analysis finds unclipped is left alone exactly).

``clamp`` (halo 0, :class:`HighlightClamp`, preset fast): every channel capped at ``s n_c``, per
pixel (LibRaw's default): a blown white is neutral, a partly clipped pixel keeps some colour.

``clip`` (halo RIM): every pixel with a clipped channel becomes the neutral ``s n``,
``s = min_c t_c``: the brightest neutral that no channel clips on, a consistent white (LibRaw's
default clips each channel at that level after white balance; we also make the pixel neutral). A
neutral ramp through the clip point rises to s and stays there.

``reconstruct`` (halo RIM + RADIUS): the colour of a clipped light is taken from bright unclipped
pixels around it where the evidence supports it, the brightness from the pixel's unclipped
channels ("inpaint opposed", locally); where the evidence is weak the pixel becomes a neutral
(as ``clip``, but never below its records)::

    m(q)     = max_c y_c(q) / t_c                    how close q is to clipping
    ramp(q)  = clamp((m - LOW) / (REF - LOW), 0, 1)
    far:  w = ramp where m < REF and q is not near   rim:  w = ramp where q is near, m < 1
    rho_c(q) = y_c(q) / mean_k y_k(q)                q's chroma (mean 1 over the channels)
    rho^_c(p) = (sum_q w rho_c + PRIOR) / (sum_q w + PRIOR),  q in the 7 x 7 cells of 4 x 4 px
                (image grid) around p's cell, for the far (F^) and the rim (R^) references

    trust(p) = agree(F^, R^)                                the light's edge has the far colour
             x agree(y_free / sum y_free, F^_free / sum F^_free)      (one channel clipped)
             x clamp((RISE_HI - rise) / (RISE_HI - RISE_LO), 0, 1)    (some channel clipped)
      agree(a, b) = clamp((AGREE_HI - |D (a - b)|_inf) / (AGREE_HI - AGREE_LO), 0, 1), D the
                    display matrix (output RGB), rise = (sum y_free / sum F^_free) / the far
                    references' mean brightness
    rho = 1 + trust (F^ - 1)

    none clipped, not near:  unchanged
    near, none clipped:      y + (1 - keep) (mean(y) rho - y),
                             keep = sum w_far / (sum w_far + EVIDENCE) (1 - agree(y / mean y, F^))
    some clipped (C):        K = max(sum_{u not in C} y_u / sum_{u not in C} rho_u,
                                     max_{c in C} y_c / rho_c)      (rho_c >= RHO_MIN only)
                             y_c <- max(y_c, K rho_c) for c in C   (never below what was recorded)
    all clipped:             neutral at V = max_c y_c (the least bright neutral consistent with
                             every channel's record: brightness never falls as the scene brightens)

Why trust: the far references are every bright unclipped pixel within R, whether or not they
belong to the light (a white highlight beside saturated feathers, Kodak 23, took their colour with
K up to 5x the record). So the far colour is used only where the light's rim, the pixel's free
channels and the implied brightness agree with it, compared after the colour matrix. A clipped
channel's record is a lower bound on the truth, so K is at least what it implies with rho. The
reasoning in full: README.md.

The clipped test on demosaiced values uses MARGIN times the mosaic's threshold (demosaics put a
clipped channel a few percent low), and DIP times that next to a pixel where the channel is
clipped (at the other channels' sites they put it lower still); pixels within RIM of a clipped
pixel (the demosaic's false colour across a light's edge) keep their brightness but take rho
(``clip``: neutral), so the stage's halo is RIM (+ RADIUS for ``reconstruct``).

PRIOR (one pixel's weight) pulls rho^ to neutral where no bright unclipped pixel lies near: a
ramp or a white light keeps its neutral, a coloured light larger than the box keeps the colour of
its unclipped channels. The sums are taken per cell of CELL px on the image's grid, then over the
cells around each pixel's cell (:func:`cell_box_sums`, all within RADIUS of the pixel), so tiled
output equals whole-image output. Kernels: clisp/modules/highlights/highlights.cl.
Measured figures: docs/RESULTS.md, "Highlights".
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...errors import ClispError
from ...noise_estimate import CLIP_FRACTION
from ...engine.runtime import DeviceImage, Runtime
from ...engine.stage import Stage, as_f32
from ..colour.stage import ColourMatrix, camera_neutral

MODES = ("clip", "reconstruct", "clamp", "off")
DEFAULT_MODE = "reconstruct"
"""``--highlights`` default (tools/bench_highlights.py; docs/RESULTS.md, "Highlights")."""

RADIUS = 16
"""How far (px) the bright unclipped pixels that give a clipped pixel its colour may lie: the
stage's halo beyond RIM; the cells it reads lie within it (:func:`cell_radius`)."""

SUMS = 7
"""Reference planes that ``reconstruct`` box-sums (:func:`reference_weights`): far (4), rim (3)."""

CELL = 4
"""The references are summed over cells of CELL x CELL px on the image's grid, and a pixel's
reference colour over the (2 k + 1)^2 cells around its cell, k = :func:`cell_radius` (RADIUS 16:
7 x 7 cells, 28 px, reaching 12 to 15 px from the pixel): per-pixel box sums of seven planes cost
more than the rest of the stage."""

BLOCK = 16
"""Side of the blocks the OpenCL path tests for clipped pixels (clisp/modules/highlights/highlights.cl): every
kernel after the flags works only within the few blocks of one whose results can be read
(:func:`reach_levels`), so raws with few clipped pixels pay little more than the flags pass."""

REF = 0.9
"""A pixel is a colour reference only while every channel is below this share of its threshold
(the demosaic blends clipped samples into their neighbours' values just below the threshold)."""

LOW = 0.5
"""Reference weight ramps from 0 at this share of the threshold to 1 at REF."""

MARGIN = 0.9
"""The demosaiced test's threshold, as a share of the mosaic's: a demosaic that interpolates a
channel from colour differences puts a clipped channel a few percent below its clip level where
the other channels carry noise (DLMMSE, Bayer gain 1: 2-3 %), which left those pixels unhandled
and tinted (block chroma 0.066 on a neutral ramp with the full threshold)."""

RIM = 4
"""Pixels within this distance (Chebyshev) of a pixel with a clipped channel form its rim: the
demosaic carries the clipped pixels' false colour differences a few pixels across the light's
edge (DLMMSE, Bayer: 3-4 px on a blown lamp, block chroma 0.18 without this). Rim pixels keep
their brightness (mean of y) and take the reconstructed colour (``clip``: neutral), and are never
colour references."""

PRIOR = 1.0
"""Weight of the neutral prior in rho^ (in pixels of full weight)."""

AGREE_LO = 0.1
AGREE_HI = 0.25
"""Two chromas (mean 1 over the channels) agree fully while they differ by at most AGREE_LO in
every output channel (after the display matrix: 0.1 is a 2 % L - M difference on LMS), not at
all from AGREE_HI (chosen on Kodak's gross errors: docs/RESULTS.md, "Highlights")."""

RISE_LO = 2.0
RISE_HI = 4.0
"""Trust in the far chroma falls from 1 to 0 as the brightness it implies at a clipped pixel
goes from RISE_LO to RISE_HI times the far references' own mean brightness: a light is a few
times brighter than its rim, a white beside a saturated surface implies far more through the
surface's small chroma (docs/RESULTS.md, "Highlights")."""

EVIDENCE = 8.0
"""Far-reference weight (in pixels of full weight) at which a rim pixel whose colour differs from
theirs keeps half of its own colour."""

RHO_MIN = 0.2
"""A clipped channel bounds the brightness K from below only where its reference chroma rho^_c is
at least this (mean 1 over the channels): a clipped channel the references call nearly dark
contradicts them, and y_c / rho^_c would blow the other channels up."""

DIP = 0.8
"""At a pixel with a clipped channel, another channel at or above this share of its threshold
counts as clipped where it is clipped at one of the 8 neighbours: a demosaic puts a clipped
channel well below its clip level at the sites of the other channels (guided LMS, blown lamp:
16 px block chroma 0.043-0.055 without this, 0.001 with it). Only where another channel is
clipped: raising a channel on an unclipped light's edge coloured it (README.md)."""


@dataclass
class Highlights(Stage):
    """Clipped-highlight handling on white-balanced camera channels (see the module docstring).

    neutral    (3,) n: the camera values that come out grey.
    threshold  (3,) MARGIN t_c in units of n (y_c >= it: channel c clipped).
    white      s = min_c t_c, the neutral level of ``clip`` (units of n).
    mode       'clip' or 'reconstruct'.
    radius     R of 'reconstruct' (its halo beyond the rim).
    rim        RIM: the false-colour rim around clipped pixels (px).
    display    (3, 3) camera values in units of n to output RGB (:func:`display_matrix`), where
               'reconstruct' compares chromas; None: the identity.
    """

    neutral: np.ndarray
    threshold: np.ndarray
    white: float
    mode: str = DEFAULT_MODE
    radius: int = RADIUS
    rim: int = RIM
    display: np.ndarray | None = None
    name = "highlights"

    def __post_init__(self) -> None:
        if max(reach_levels(self.rim, self.radius).values()) > 4:
            raise ClispError(f"highlights: rim {self.rim} + radius {self.radius} reach past 4 blocks of {BLOCK} px")
        if self.mode not in ("clip", "reconstruct"):
            raise ClispError(f"unknown highlight mode {self.mode!r}; expected clip or reconstruct")
        self.neutral = np.asarray(self.neutral, dtype=np.float64).reshape(3)
        self.threshold = np.asarray(self.threshold, dtype=np.float64).reshape(3)
        self.white = float(self.white)
        self.display = np.eye(3) if self.display is None else np.asarray(self.display, dtype=np.float64).reshape(3, 3)

    @property
    def halo(self) -> int:
        return self.rim + (self.radius if self.mode == "reconstruct" else 0)

    @property
    def bytes_per_pixel(self) -> float:
        """float32 planes per input pixel: flags, near rows, near, output (3); reconstruct: the
        cell and cell-box sums (SUMS planes each at 1 / CELL^2 of the pixels)."""
        return 4.0 * (6 + (2 * SUMS / CELL ** 2 if self.mode == "reconstruct" else 0))

    # ------------------------------------------------------------------------------- reference

    def reference(self, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
        n, t, d, r = self.neutral, self.threshold, self.rim, self.radius
        y = np.asarray(x, dtype=np.float64) / n
        near = box_max(box_max((y >= t).any(axis=-1).astype(np.float64), d, 1), d, 0) > 0   # window - 2d
        clipped = clipped_channels(y, t)
        y = y[d:y.shape[0] - d, d:y.shape[1] - d]
        clipped = clipped[d:clipped.shape[0] - d, d:clipped.shape[1] - d]
        if self.mode == "clip":
            mean = y.mean(axis=-1, keepdims=True)
            out = np.where(near[..., None], mean, y)
            return np.where(clipped.any(axis=-1, keepdims=True), self.white, out) * n
        weights = reference_weights(y, t, near)                             # H x W x 7: far, rim
        offset = tuple((o + d) % CELL for o in origin)     # the cell grid in image coordinates
        sums = cell_box_sums(weights, offset, r)
        crop = (slice(r, y.shape[0] - r), slice(r, y.shape[1] - r))
        return reconstruct(y[crop], clipped[crop], near[crop], sums, self.display) * n

    # ------------------------------------------------------------------------------- OpenCL

    def enqueue(self, rt: Runtime, src: DeviceImage, origin: tuple[int, int]) -> DeviceImage:
        n, t = rt.constant(as_f32(self.neutral)), rt.constant(as_f32(self.threshold))
        w, h, d = src.width, src.height, self.rim
        r = self.radius if self.mode == "reconstruct" else 0
        defines = {"HL_RADIUS": r, "HL_RIM": d, "HL_REF": repr(REF) + "f", "HL_LOW": repr(LOW) + "f",
                   "HL_PRIOR": repr(PRIOR) + "f", "HL_DIP": repr(DIP) + "f", "HL_RHO_MIN": repr(RHO_MIN) + "f",
                   "HL_CLIP": int(self.mode == "clip"), "HL_AGREE_LO": repr(AGREE_LO) + "f",
                   "HL_AGREE_HI": repr(AGREE_HI) + "f", "HL_RISE_LO": repr(RISE_LO) + "f",
                   "HL_RISE_HI": repr(RISE_HI) + "f", "HL_EVIDENCE": repr(EVIDENCE) + "f", "HL_SUMS": SUMS,
                   "HL_CELL": CELL, "HL_CELL_R": cell_radius(self.radius)}
        defines["HL_BLOCK"] = BLOCK
        defines.update({f"HL_D_{k.upper()}": v for k, v in reach_levels(d, r).items()})
        def launch(kernel: str, gx: int, gy: int, /, **args: object) -> None:
            rt.launch_named("highlights", kernel, gx, gy, args, defines)

        flags = rt.acquire(1, h, w)
        launch("hl_flags", w, h, src=src, dst=flags, width=w, height=h, n=n, t=t)
        nbx, nby = -(-w // BLOCK), -(-h // BLOCK)
        blocks = rt.acquire(1, nby, nbx)
        launch("hl_blocks", nbx, nby, flags=flags, blocks=blocks, width=w, height=h, nbx=nbx)
        reach = rt.acquire(4, nby, nbx)
        launch("hl_reach", nbx, nby, blocks=blocks, reach=reach, nbx=nbx, nby=nby)
        rt.release(blocks)
        sparse = dict(reach=reach, nbx=nbx, nby=nby)
        w1, h1 = w - 2 * d, h - 2 * d
        rows = rt.acquire(1, h, w1)
        launch("hl_near_rows", w1, h, src=flags, dst=rows, width=w, out_w=w1, **sparse)
        rt.release(flags)
        near = rt.acquire(1, h1, w1)                    # on the window less the rim
        launch("hl_near", w1, h1, rows=rows, dst=near, w1=w1, h1=h1, **sparse)
        rt.release(rows)
        ow, oh = w1 - 2 * r, h1 - 2 * r
        oy, ox = ((o + d) % CELL for o in origin)       # the window's first pixel in its cell
        ncw, nch = -(-(w1 + ox) // CELL), -(-(h1 + oy) // CELL)
        cell_grid = dict(w1=w1, h1=h1, ncw=ncw, nch=nch, oy=oy, ox=ox)
        box = near
        if r:
            cells = rt.acquire(SUMS, nch, ncw)
            launch("hl_cells", ncw, nch, src=src, near=near, dst=cells, width=w, height=h, n=n, t=t, **cell_grid,
                   **sparse)
            box = rt.acquire(SUMS, nch, ncw)
            launch("hl_cell_box", ncw, nch, cells=cells, dst=box, **cell_grid, **sparse)
            rt.release(cells)
        dst = rt.acquire(3, oh, ow)
        launch("hl_apply", ow, oh, src=src, nearby=near, box=box, dst=dst, width=w, height=h, w1=w1, ncw=ncw,
               nch=nch, oy=oy, ox=ox, out_w=ow, out_h=oh, n=n, t=t, d=rt.constant(as_f32(self.display)),
               white=self.white, **sparse)
        rt.release(reach)
        rt.release(near)
        if r:
            rt.release(box)
        return dst


def reach_levels(rim: int, radius: int) -> dict[str, int]:
    """Blocks (of BLOCK px) around a clipped pixel's block within which each kernel works. Apply
    changes pixels within ``rim`` of a clipped one, so it works within ceil(rim / BLOCK) blocks and
    copies the rest; each kernel that feeds another works wherever that one works, widened by the
    reach of its reads there: the cells (:func:`cell_box_sums`) up to (k + 1) CELL - 1 px beyond
    the cells apply reads, near a block more (a cell may straddle a block edge), the near rows
    ``rim`` rows more. So no working pixel reads a value that was skipped.

    >>> reach_levels(4, 16)
    {'apply': 1, 'cells': 2, 'near': 3, 'near_rows': 4}
    >>> reach_levels(4, 0)
    {'apply': 1, 'cells': 1, 'near': 1, 'near_rows': 2}
    """
    def blocks(distance: int) -> int:
        return -(-distance // BLOCK)
    apply = max(1, blocks(rim))
    cells = apply + blocks((cell_radius(radius) + 1) * CELL - 1) if radius else apply
    near = cells + 1 if radius else apply
    return {"apply": apply, "cells": cells, "near": near, "near_rows": near + blocks(rim)}


def box_max(a: np.ndarray, r: int, axis: int) -> np.ndarray:
    """Maxima of 2 r + 1 consecutive entries along ``axis`` (the result is 2 r shorter)."""
    n = a.shape[axis]
    out = np.take(a, np.arange(0, n - 2 * r), axis=axis)
    for k in range(1, 2 * r + 1):
        out = np.maximum(out, np.take(a, np.arange(k, n - 2 * r + k), axis=axis))
    return out


def clipped_channels(y: np.ndarray, t: np.ndarray) -> np.ndarray:
    """H x W x 3 bool: channel c of y (H x W x 3, units of n) is clipped where y_c >= t_c, or,
    at pixels where another channel is, where y_c >= DIP t_c and y_c >= t_c at one of the 8
    neighbours (inside the array)."""
    hard = y >= t
    padded = np.pad(hard, ((1, 1), (1, 1), (0, 0)))
    h, w = hard.shape[:2]
    beside = np.zeros_like(hard)
    for dy in range(3):
        for dx in range(3):
            beside |= padded[dy:dy + h, dx:dx + w]
    return hard | (beside & (y >= DIP * t) & hard.any(axis=-1, keepdims=True))


def reference_weights(y: np.ndarray, t: np.ndarray, near: np.ndarray) -> np.ndarray:
    """H x W x 7 per pixel of y (H x W x 3, units of n) for thresholds t and the near mask:
    (w, w rho_0, w rho_1, w mean(y)) of the far references (bright, clearly unclipped, not near a
    clipped pixel), then (w, w rho_0, w rho_1) of the rim references (near, no channel clipped,
    bright); w ramps from 0 at LOW to 1 at REF of the threshold, rho_c = y_c / mean(y)."""
    m = np.max(y / t, axis=-1)
    ramp = np.clip((m - LOW) / (REF - LOW), 0.0, 1.0)
    far = np.where((m < REF) & ~near, ramp, 0.0)
    rim = np.where(near & (m < 1.0), ramp, 0.0)
    mean = y.mean(axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(mean > 0, 1.0 / mean, 0.0)
    return np.stack([far, far * y[..., 0] * inv, far * y[..., 1] * inv, far * mean,
                     rim, rim * y[..., 0] * inv, rim * y[..., 1] * inv], axis=-1)


def cell_radius(radius: int) -> int:
    """Cells on each side of a pixel's cell whose references it reads, so that they all lie within
    ``radius`` px of it (k CELL + CELL - 1 <= radius).

    >>> cell_radius(16), cell_radius(6)
    (3, 0)
    """
    return max(0, (radius - CELL + 1) // CELL)


def cell_box_sums(weights: np.ndarray, offset: tuple[int, int], radius: int) -> np.ndarray:
    """Box sums of ``weights`` (H x W x C) over cells: the sum over the (2 k + 1)^2 cells of
    CELL x CELL px around each pixel's cell (k = cell_radius(radius)), for the pixels ``radius`` or
    more from the edge ((H - 2 radius) x (W - 2 radius) x C). Cells lie on the image's grid of CELL
    px: ``offset`` (dy, dx) is the window's first pixel modulo CELL, so every tile sums the same
    cells; the cells a pixel reads lie within ``radius`` px of it, inside the window.

    >>> int(cell_box_sums(np.ones((40, 40, 1)), (0, 0), 16)[0, 0, 0])      # 7 x 7 cells of 16 px
    784
    """
    h, w, c = weights.shape
    oy, ox = offset
    ch, cw = -(-(h + oy) // CELL), -(-(w + ox) // CELL)
    padded = np.zeros((ch * CELL, cw * CELL, c))
    padded[oy:oy + h, ox:ox + w] = weights
    cells = padded.reshape(ch, CELL, cw, CELL, c).sum(axis=(1, 3))
    k = cell_radius(radius)
    cells = np.pad(cells, ((k, k), (k, k), (0, 0)))
    boxed = box_sum(box_sum(cells, k, axis=0), k, axis=1)                  # ch x cw x c
    rows = (np.arange(radius, h - radius) + oy) // CELL
    cols = (np.arange(radius, w - radius) + ox) // CELL
    return boxed[rows[:, None], cols[None, :]]


def box_sum(a: np.ndarray, r: int, axis: int) -> np.ndarray:
    """Sums of 2 r + 1 consecutive entries along ``axis`` (the result is 2 r shorter)."""
    c = np.cumsum(a, axis=axis)
    zero = np.zeros_like(np.take(c, [0], axis=axis))
    c = np.concatenate([zero, c], axis=axis)
    k = 2 * r + 1
    n = a.shape[axis]
    return np.take(c, np.arange(k, n + 1), axis=axis) - np.take(c, np.arange(0, n + 1 - k), axis=axis)


def chroma_of(sums: np.ndarray) -> np.ndarray:
    """rho^ (H x W x 3, mean 1) from box sums (w, w rho0, w rho1) with the neutral prior."""
    sw = sums[..., 0] + PRIOR
    return np.stack([(sums[..., 1] + PRIOR) / sw, (sums[..., 2] + PRIOR) / sw,
                     (3.0 * sums[..., 0] - sums[..., 1] - sums[..., 2] + PRIOR) / sw], axis=-1)


def agreement(a: np.ndarray, b: np.ndarray, display: np.ndarray) -> np.ndarray:
    """1 where two chromas a, b (... x 3, units of n) differ by at most AGREE_LO in every output
    channel (display @ (a - b)), 0 from AGREE_HI, linear between."""
    distance = np.abs((a - b) @ display.T).max(axis=-1)
    return np.clip((AGREE_HI - distance) / (AGREE_HI - AGREE_LO), 0.0, 1.0)


def trust_in_far(y: np.ndarray, clipped: np.ndarray, sums: np.ndarray, display: np.ndarray) -> np.ndarray:
    """H x W in [0, 1]: how far the far references' chroma may be trusted at each pixel. The
    product of its agreement with the rim's chroma, with the pixel's two free channels (one
    channel clipped), and of the brightness it implies against the references' own (RISE)."""
    far, rim = chroma_of(sums[..., :3]), chroma_of(sums[..., 4:7])
    free = ~clipped
    count = clipped.sum(axis=-1)
    trust = agreement(far, rim, display)
    fy, fr = np.where(free, y, 0.0), np.where(free, far, 0.0)
    scale = fr.sum(axis=-1, keepdims=True) / np.maximum(fy.sum(axis=-1, keepdims=True), 1e-9)
    trust = np.where(count == 1, trust * agreement(fy * scale, fr, display), trust)
    implied = fy.sum(axis=-1) / np.maximum(fr.sum(axis=-1), 1e-6)
    with np.errstate(divide="ignore", invalid="ignore"):
        rise = np.where(sums[..., 0] > 0, implied * sums[..., 0] / np.maximum(sums[..., 3], 1e-9), 0.0)
    rise_ok = np.clip((RISE_HI - rise) / (RISE_HI - RISE_LO), 0.0, 1.0)
    return np.where(count > 0, trust * rise_ok, trust)


def reconstruct(y: np.ndarray, clipped: np.ndarray, near: np.ndarray, sums: np.ndarray,
                display: np.ndarray = np.eye(3)) -> np.ndarray:
    """The reconstruction rule on y (H x W x 3, units of n), given the clipped channels, the near
    mask, the box sums of :func:`reference_weights` (H x W x 7) and the display matrix."""
    far = chroma_of(sums[..., :3])
    trust = trust_in_far(y, clipped, sums, display)
    rho = 1.0 + trust[..., None] * (far - 1.0)
    free = ~clipped
    count = clipped.sum(axis=-1)
    num = np.sum(np.where(free, y, 0.0), axis=-1)
    den = np.maximum(np.sum(np.where(free, rho, 0.0), axis=-1), 1e-6)
    bound = np.where(clipped & (rho >= RHO_MIN), y / np.maximum(rho, RHO_MIN), 0.0).max(axis=-1)
    estimate = np.maximum(num / den, bound)[..., None] * rho
    out = np.where(clipped, np.maximum(y, estimate), y)
    mean = y.mean(axis=-1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        own = np.where(mean > 0, y / mean, 1.0)
    keep = sums[..., 0] / (sums[..., 0] + EVIDENCE) * (1.0 - agreement(own, far, display))
    rim = y + (1.0 - keep)[..., None] * (mean * rho - y)
    out = np.where((near & (count == 0))[..., None], rim, out)
    return np.where((count == 3)[..., None], y.max(axis=-1, keepdims=True), out)


# ----------------------------------------------------------------------------------- from a raw

def channel_clip_dn(raw) -> np.ndarray:
    """(n_channels,) the level in DN at which each CFA channel clips: the camera's per-channel
    linear maximum where LibRaw reports one (``metadata['linear_max']``), else the white level."""
    levels = np.full(raw.cfa.n_channels, float(raw.white_level))
    linear_max = raw.metadata.get("linear_max")
    if linear_max is not None:
        values = np.asarray(linear_max, dtype=np.float64).reshape(-1)
        if values.size == raw.cfa.n_channels:
            good = np.isfinite(values) & (values > np.asarray(raw.black_level)) & (values <= raw.white_level)
            levels = np.where(good, values, levels)
    return levels


def clip_thresholds_dn(raw) -> np.ndarray:
    """(n_channels,) DN at or above which a sample counts as clipped (CLIP_FRACTION of the range)."""
    black = np.asarray(raw.black_level, dtype=np.float64)
    return black + CLIP_FRACTION * (channel_clip_dn(raw) - black)


def has_clipped(raw) -> bool:
    """Whether any sample of ``raw`` reached its channel's clip threshold. Float raws (noiseless
    simulations) are never clipped. Cost: one max over the mosaic, and one per CFA phase only when
    that max reaches the lowest threshold."""
    data = raw.data
    if data.dtype != np.uint16:
        return False
    thresholds = clip_thresholds_dn(raw)
    if float(data.max()) < float(thresholds.min()):
        return False
    p = raw.cfa.period
    pattern = np.asarray(raw.cfa.pattern)
    for dy in range(p):
        for dx in range(p):
            if float(data[dy::p, dx::p].max(initial=0)) >= thresholds[int(pattern[dy, dx])]:
                return True
    return False


def neutral_of(colour_matrix: np.ndarray, wb2: np.ndarray | None = None) -> np.ndarray:
    """n: the white-balanced camera values that the colour matrix and WB pass 2 take to grey,
    scaled to a largest entry of 1 (:func:`camera_neutral`)."""
    n = camera_neutral(colour_matrix, None if wb2 is None else 1.0 / np.asarray(wb2, dtype=np.float64))
    if n is None:
        raise ClispError("the colour matrix does not map a positive camera value to grey")
    return n / n.max()


def display_matrix(colour_matrix: np.ndarray, neutral: np.ndarray) -> np.ndarray:
    """3 x 3: camera values in units of the neutral n to output RGB, scaled so that the neutral
    (1, 1, 1) comes out with mean 1: the space in which highlight chromas are compared (the LMS
    matrix turns a small L - M difference into a large red one)."""
    a = np.asarray(colour_matrix, dtype=np.float64) @ np.diag(neutral)
    return a / float(a.sum(axis=1).mean())


def highlight_stage(raw, mode: str, wb2: np.ndarray | None = None, force: bool = False) -> Highlights | None:
    """The Highlights stage for ``raw`` (3-channel CFAs), or None for mode 'off', a raw without
    clipped samples (unless ``force``), or a colour matrix without a positive neutral."""
    if mode not in MODES:
        raise ClispError(f"unknown highlight mode {mode!r}; expected one of {', '.join(MODES)}")
    if mode == "off" or raw.cfa.n_channels != 3 or not (force or has_clipped(raw)):
        return None
    try:
        n = neutral_of(raw.colour_matrix, wb2)
    except ClispError:
        return None
    black = np.asarray(raw.black_level, dtype=np.float64)
    clip = (clip_thresholds_dn(raw) - black) / (float(raw.white_level) - black)   # normalised
    t = clip * raw.pass1_gains() / n                         # after WB pass 1, in units of n
    if mode == "clamp":
        return HighlightClamp(n, float(t.min()))
    return Highlights(n, MARGIN * t, float(t.min()), mode, display=display_matrix(raw.colour_matrix, n))


@dataclass
class HighlightClamp(Stage):
    """``clamp`` (preset fast): every channel capped at the brightest neutral no channel clips on,
    per pixel: x_c <- min(x_c, s n_c), halo 0, one pass. LibRaw's default: a blown white (every
    channel clipped) comes out neutral at s; a partly clipped pixel moves toward neutral but keeps
    some colour. ``neutral`` n and ``white`` s as in :class:`Highlights`."""

    neutral: np.ndarray
    white: float
    name = "highlights"

    def __post_init__(self) -> None:
        self.neutral = np.asarray(self.neutral, dtype=np.float64).reshape(3)
        self.white = float(self.white)

    matrix: np.ndarray | None = None
    """A 3 x 3 matrix applied after the clamp (the colour matrix fused in: :meth:`fuse`), or None."""

    def reference(self, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
        out = np.minimum(np.asarray(x, dtype=np.float64), self.white * self.neutral)
        return out if self.matrix is None else out @ np.asarray(self.matrix, dtype=np.float64).T

    def fuse(self, following: Stage) -> Stage | None:
        if self.matrix is None and type(following) is ColourMatrix:
            return HighlightClamp(self.neutral, self.white, np.asarray(following.matrix, dtype=np.float64))
        return None

    def enqueue(self, rt: Runtime, src: DeviceImage, origin: tuple[int, int]) -> DeviceImage:
        dst = rt.acquire(3, src.height, src.width)
        cap = self.white * self.neutral
        m = np.eye(3) if self.matrix is None else self.matrix
        rt.launch_named("highlights", "hl_clamp", src.width, src.height,
                        dict(src=src, dst=dst, width=src.width, height=src.height, cap0=cap[0], cap1=cap[1],
                             cap2=cap[2], m=rt.constant(as_f32(m))), {"MATRIX": int(self.matrix is not None)})
        return dst
