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

import math
from dataclasses import dataclass, field

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


MAP = 8
"""Side (mosaic px) of the cells of the clip map (:func:`clip_map`): a pixel's channel may count as
clipped only in a cell the map allows for it, within a cell of a clipped sample that the noise
test calls a true clip. The kernels' work lists are made of these cells (on the stage's grid:
MAP / scale px, scale 2 after the half-size binning), so the stage works in proportion to the
clipped area."""

TEST = 16
"""Side (mosaic px) of the blocks of the noise test (:func:`clip_map`): 2 x 2 map cells; 128
samples of a channel that holds half the sites (LMS L, Bayer G), 64 of a quarter, 32 of an eighth."""

NOISE_WINDOW = 3.0
"""The noise test counts a block's samples of a channel from NOISE_WINDOW sigma (the noise at the
clip threshold) under the threshold up: the samples a level near full scale puts there, few of
a darker surface beside it."""

NOISE_Z = 3.0
"""Sigmas (of the binomial count) by which a block's clipped samples may exceed what the noise
around a level at full scale gives, before the block counts as truly clipped."""


@dataclass
class Highlights(Stage):
    """Clipped-highlight handling on white-balanced camera channels (see the module docstring).

    neutral    (3,) n: the camera values that come out grey.
    threshold  (3,) MARGIN t_c in units of n (y_c >= it: channel c clipped, where the clip map
               allows it).
    white      s = min_c t_c, the neutral level of ``clip`` (units of n).
    mode       'clip' or 'reconstruct'.
    radius     R of 'reconstruct' (its halo beyond the rim).
    rim        RIM: the false-colour rim around clipped pixels (px).
    display    (3, 3) camera values in units of n to output RGB (:func:`display_matrix`), where
               'reconstruct' compares chromas; None: the identity.
    clip_map   (ny, nx) uint8 per cell of ``map_cell`` px on the image's grid (:func:`clip_map`):
               bit c set where channel c may count as clipped; None: everywhere (a stage built
               by hand). Cells past the image's edge take the edge's (clamped lookups).
    map_cell   the map's cell side on the stage's grid (px): MAP, MAP / 2 after the half-size
               binning; a multiple of CELL, at least ``rim``.
    """

    neutral: np.ndarray
    threshold: np.ndarray
    white: float
    mode: str = DEFAULT_MODE
    radius: int = RADIUS
    rim: int = RIM
    display: np.ndarray | None = None
    clip_map: np.ndarray | None = field(default=None, repr=False)
    map_cell: int = MAP
    name = "highlights"

    def __post_init__(self) -> None:
        if self.mode not in ("clip", "reconstruct"):
            raise ClispError(f"unknown highlight mode {self.mode!r}; expected clip or reconstruct")
        if self.map_cell % CELL or not 1 <= self.rim <= self.map_cell:
            raise ClispError(f"highlights: rim {self.rim} must be 1 to the map's cell of {self.map_cell} px, "
                             f"a multiple of {CELL} px")
        self.neutral = np.asarray(self.neutral, dtype=np.float64).reshape(3)
        self.threshold = np.asarray(self.threshold, dtype=np.float64).reshape(3)
        self.white = float(self.white)
        self.display = np.eye(3) if self.display is None else np.asarray(self.display, dtype=np.float64).reshape(3, 3)
        if self.clip_map is not None:
            self.clip_map = np.ascontiguousarray(self.clip_map, dtype=np.uint8)

    @property
    def halo(self) -> int:
        return self.rim + (self.radius if self.mode == "reconstruct" else 0)

    @property
    def bytes_per_pixel(self) -> float:
        """Device bytes per input pixel: the output (3 float32 planes), flags, near rows and near
        (one byte each); reconstruct: the cell and cell-box sums (SUMS float32 planes each at
        1 / CELL^2 of the pixels)."""
        return 12.0 + 3.0 + (2 * 4.0 * SUMS / CELL ** 2 if self.mode == "reconstruct" else 0.0)

    def allowed(self, origin: tuple[int, int], shape: tuple[int, int]) -> np.ndarray:
        """H x W x 3 bool for a window of ``shape`` at ``origin``: where each channel may count as
        clipped (the clip map's cell of each pixel, clamped to the map's edge)."""
        h, w = shape
        if self.clip_map is None:
            return np.ones((h, w, 3), dtype=bool)
        ny, nx = self.clip_map.shape
        rows = np.clip((origin[0] + np.arange(h)) // self.map_cell, 0, ny - 1)
        cols = np.clip((origin[1] + np.arange(w)) // self.map_cell, 0, nx - 1)
        bits = self.clip_map[rows[:, None], cols[None, :]]
        return ((bits[..., None] >> np.arange(3, dtype=np.uint8)) & 1).astype(bool)

    # ------------------------------------------------------------------------------- reference

    def reference(self, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
        n, t, d, r = self.neutral, self.threshold, self.rim, self.radius
        y = np.asarray(x, dtype=np.float64) / n
        hard = (y >= t) & self.allowed(origin, y.shape[:2])
        near = box_max(box_max(hard.any(axis=-1).astype(np.float64), d, 1), d, 0) > 0   # window - 2d
        clipped = clipped_channels(y, t, hard)
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

    def window_map(self, origin: tuple[int, int], height: int, width: int) -> tuple[np.ndarray, int, int]:
        """(the clip map's cells over a window of height x width at ``origin``, (ngy, ngx) uint8;
        py, px): window pixel (y, x) lies in cell ((y + py) // map_cell, (x + px) // map_cell)."""
        mc = self.map_cell
        gy0, gx0 = origin[0] // mc, origin[1] // mc
        py, px = origin[0] - gy0 * mc, origin[1] - gx0 * mc
        ngy, ngx = (py + height - 1) // mc + 1, (px + width - 1) // mc + 1
        if self.clip_map is None:
            return np.full((ngy, ngx), 7, dtype=np.uint8), py, px
        ny, nx = self.clip_map.shape
        rows = np.clip(gy0 + np.arange(ngy), 0, ny - 1)
        cols = np.clip(gx0 + np.arange(ngx), 0, nx - 1)
        return np.ascontiguousarray(self.clip_map[rows[:, None], cols[None, :]]), py, px

    def schedule(self, origin: tuple[int, int], height: int, width: int) -> dict[str, object]:
        """The kernels' work over a window (host side, from the clip map): the window's cells with
        their bits (0-2: the channels allowed; WORK_CELLS: hl_cells works there; WORK_BOX:
        hl_cell_box does) and the lists of cells (gy << 16 | gx) each list kernel runs over:
        ``flags`` where a channel is allowed (the seeds; flags are 0 elsewhere), ``near`` the seeds
        and the cells around them (every pixel within RIM <= map_cell of a flag: hl_near, hl_apply),
        ``rows`` those and a cell above and below (the near rows hl_near reads), and the cells of
        the reference sums apply reads (within (k + 1) CELL - 1 px of its cells)."""
        cells, py, px = self.window_map(origin, height, width)
        seeds = cells != 0
        near = grow(seeds, 1)
        rows = grow(near, 1, axes=(0,))
        work = cells.copy()
        if self.mode == "reconstruct":
            reach = -(-((cell_radius(self.radius) + 1) * CELL - 1) // self.map_cell)
            work |= np.where(grow(near, reach), WORK_CELLS, 0).astype(np.uint8)
            work |= np.where(near, WORK_BOX, 0).astype(np.uint8)
        return {"cells": work, "py": py, "px": px, "flags": cell_list(seeds), "rows": cell_list(rows),
                "near": cell_list(near)}

    def enqueue(self, rt: Runtime, src: DeviceImage, origin: tuple[int, int]) -> DeviceImage:
        w, h, d = src.width, src.height, self.rim
        r = self.radius if self.mode == "reconstruct" else 0
        ow, oh = w - 2 * (d + r), h - 2 * (d + r)
        defines = {"HL_RADIUS": r, "HL_RIM": d, "HL_MC": self.map_cell, "HL_REF": repr(REF) + "f",
                   "HL_LOW": repr(LOW) + "f", "HL_PRIOR": repr(PRIOR) + "f", "HL_DIP": repr(DIP) + "f",
                   "HL_RHO_MIN": repr(RHO_MIN) + "f", "HL_CLIP": int(self.mode == "clip"),
                   "HL_AGREE_LO": repr(AGREE_LO) + "f", "HL_AGREE_HI": repr(AGREE_HI) + "f",
                   "HL_RISE_LO": repr(RISE_LO) + "f", "HL_RISE_HI": repr(RISE_HI) + "f",
                   "HL_EVIDENCE": repr(EVIDENCE) + "f", "HL_SUMS": SUMS, "HL_CELL": CELL,
                   "HL_CELL_R": cell_radius(self.radius), "HL_WORK_CELLS": WORK_CELLS, "HL_WORK_BOX": WORK_BOX}

        def launch(kernel: str, gx: int, gy: int, /, **args: object) -> None:
            rt.launch_named("highlights", kernel, gx, gy, args, defines)

        def over(kernel: str, cells: np.ndarray, /, **args: object) -> None:      # one work-group per cell
            mc = self.map_cell
            rt.launch_named("highlights", kernel, mc, mc * len(cells), dict(args, list=rt.constant(cells)), defines,
                            group=(mc, mc))

        dst = rt.acquire(3, oh, ow)
        launch("hl_copy", ow, oh, src=src, dst=dst, width=w, height=h, out_w=ow, out_h=oh)
        plan = self.schedule(origin, h, w)
        if not len(plan["flags"]):
            return dst                                 # nothing may clip within the window: a copy
        n, t = rt.constant(as_f32(self.neutral)), rt.constant(as_f32(self.threshold))
        cells, py, px = rt.constant(plan["cells"]), plan["py"], plan["px"]
        ngx = plan["cells"].shape[1]
        flags = rt.acquire(1, h, w, np.uint8)
        launch("hl_clear", w, h, dst=flags, width=w)
        over("hl_flags", plan["flags"], src=src, cells=cells, dst=flags, width=w, height=h, ngx=ngx, py=py, px=px,
             n=n, t=t)
        w1, h1 = w - 2 * d, h - 2 * d
        rows = rt.acquire(1, h, w1, np.uint8)
        over("hl_near_rows", plan["rows"], flags=flags, dst=rows, width=w, height=h, w1=w1, py=py, px=px)
        near = rt.acquire(1, h1, w1, np.uint8)                   # on the window less the rim
        launch("hl_clear", w1, h1, dst=near, width=w1)
        over("hl_near", plan["near"], rows=rows, dst=near, w1=w1, h1=h1, py=py, px=px)
        rt.release(rows)
        oy, ox = ((o + d) % CELL for o in origin)       # the window's first pixel in its cell
        ncw, nch = -(-(w1 + ox) // CELL), -(-(h1 + oy) // CELL)
        cell_grid = dict(w1=w1, h1=h1, ncw=ncw, nch=nch, oy=oy, ox=ox, cells=cells, ngx=ngx, py=py, px=px)
        box = near
        if r:
            sums = rt.acquire(SUMS, nch, ncw)
            launch("hl_cells", ncw, nch, src=src, near=near, dst=sums, width=w, height=h, n=n, t=t, **cell_grid)
            box = rt.acquire(SUMS, nch, ncw)
            launch("hl_cell_box", ncw, nch, sums=sums, dst=box, **cell_grid)
            rt.release(sums)
        over("hl_apply", plan["near"], src=src, flags=flags, nearby=near, box=box, dst=dst, width=w, height=h,
             w1=w1, ncw=ncw, nch=nch, oy=oy, ox=ox, out_w=ow, out_h=oh, n=n, t=t,
             d=rt.constant(as_f32(self.display)), white=self.white, py=py, px=px)
        rt.release(flags)
        rt.release(near)
        if r:
            rt.release(box)
        return dst


WORK_CELLS = 8
"""Bit of a window cell (Highlights.schedule) where hl_cells sums the reference weights."""
WORK_BOX = 16
"""Bit of a window cell where hl_cell_box sums the cells around each cell (hl_apply reads them)."""


def grow(mask: np.ndarray, k: int, axes: tuple[int, ...] = (0, 1)) -> np.ndarray:
    """``mask`` (2-D bool) grown by k entries along ``axes`` (a (2 k + 1)-wide maximum, zeros past
    the edges)."""
    out = mask
    for axis in axes:
        pad = [(0, 0)] * mask.ndim
        pad[axis] = (k, k)
        out = box_max(np.pad(out, pad), k, axis)
    return out


def cell_list(mask: np.ndarray) -> np.ndarray:
    """The cells of a 2-D bool mask as int32 gy << 16 | gx, row by row.

    >>> cell_list(np.array([[0, 1], [1, 0]], bool)).tolist()
    [1, 65536]
    """
    gy, gx = np.nonzero(mask)
    return ((gy.astype(np.int64) << 16) | gx).astype(np.int32)


def box_max(a: np.ndarray, r: int, axis: int) -> np.ndarray:
    """Maxima of 2 r + 1 consecutive entries along ``axis`` (the result is 2 r shorter)."""
    n = a.shape[axis]
    out = np.take(a, np.arange(0, n - 2 * r), axis=axis)
    for k in range(1, 2 * r + 1):
        out = np.maximum(out, np.take(a, np.arange(k, n - 2 * r + k), axis=axis))
    return out


def clipped_channels(y: np.ndarray, t: np.ndarray, hard: np.ndarray | None = None) -> np.ndarray:
    """H x W x 3 bool: channel c of y (H x W x 3, units of n) is clipped where it is ``hard``
    (default y_c >= t_c; the stage: that, where the clip map allows c), and at pixels with a hard
    channel also where y_c >= t_c (a channel the map calls the noise of a white at full scale is,
    beside a true clip, a lower bound on the truth as a clipped one is), or where y_c >= DIP t_c and
    c is hard at one of the 8 neighbours (inside the array)."""
    over = y >= t
    hard = over if hard is None else hard
    padded = np.pad(hard, ((1, 1), (1, 1), (0, 0)))
    h, w = hard.shape[:2]
    beside = np.zeros_like(hard)
    for dy in range(3):
        for dx in range(3):
            beside |= padded[dy:dy + h, dx:dx + w]
    return hard | ((over | (beside & (y >= DIP * t))) & hard.any(axis=-1, keepdims=True))


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


# ----------------------------------------------------------------------------------- the clip map

@dataclass
class ClipMap:
    """Where a raw's samples clip, and where that is a true clip (:func:`clip_map`).

    bits     (ny, nx) uint8 per MAP px cell of the mosaic: bit c set where channel c may count as
             clipped (the stage's ``clip_map``).
    clipped  (by, bx, 3) bool per TEST px block: a sample of channel c at or over its threshold.
    true     (by, bx, 3) bool: those the noise test calls a true clip (grown into clipped
             neighbours), all of ``clipped`` without a noise model.
    """

    bits: np.ndarray
    clipped: np.ndarray
    true: np.ndarray


def clip_map(raw, noise=None) -> ClipMap | None:
    """The clip map of ``raw`` (3-channel CFA, integer samples), or None where no sample reached
    its channel's threshold (:func:`clip_thresholds_dn`). ``noise``: the white-balanced channels'
    noise (clisp.sim.noise.ChannelNoise: var_c(s) = shot_c s + floor_c), None: every clipped block
    is a true clip.

    The noise test, per TEST px block and channel: a white surface at or just under full scale
    clips part of its samples by noise alone, and is left as it is. With sigma the noise at the
    threshold T (in DN) and the samples from T - NOISE_WINDOW sigma up (the ``bright`` ones, k of
    them at or over T, u under it), a level mu at most the clip level C clips at most a share
    q_C = Q((T - C) / sigma) / Q((T - C) / sigma - NOISE_WINDOW) of them (Q the Gaussian tail;
    the share grows with mu, so C bounds it for any mix of levels up to C). The block is a true
    clip of channel c where it holds a clipped sample and
        u = 0                                  (nothing but clipped samples near the clip), or
        k > n q_C + NOISE_Z sqrt(n q_C (1 - q_C)) + 0.5   (more clipped than noise allows),
    n = k + u; a light past the clip clips every sample of its inside. True blocks grow into the 8
    neighbouring blocks that hold a clipped sample of the channel (a light's edge, whose samples
    through the clip a block of its own would count as a brighter surface's noise).

    The map: a MAP px cell allows channel c where it holds a clipped sample of c in a true block,
    and in the 8 cells around such a cell (the demosaic carries a clipped channel a few pixels
    past its samples). Cost: one maximum per TEST block over the mosaic; the counts only in the
    blocks that reach the lowest threshold."""
    data = raw.data
    if data.dtype != np.uint16 or raw.cfa.n_channels != 3:
        return None
    thr = clip_thresholds_dn(raw)
    peaks = block_peaks(data, TEST)
    found = np.argwhere(peaks >= thr.min())
    if not len(found):
        return None
    by, bx = found[:, 0], found[:, 1]
    blocks = gather_blocks(data, by, bx, TEST)                     # n x TEST x TEST samples
    channel = block_channels(raw.cfa, by, bx, TEST)               # n x TEST x TEST channel indices
    sigma = threshold_sigma(raw, noise, thr)
    clip_dn = channel_clip_dn(raw)
    nby, nbx = peaks.shape
    half = TEST // MAP
    clipped = np.zeros((nby, nbx, 3), dtype=bool)
    true = np.zeros((nby, nbx, 3), dtype=bool)
    cells = np.zeros((nby * half, nbx * half, 3), dtype=bool)
    for c in range(3):
        own = channel == c
        hit = own & (blocks >= thr[c])
        k = hit.sum(axis=(1, 2))
        clipped[by, bx, c] = k > 0
        if sigma is None or sigma[c] <= 0:
            true[by, bx, c] = k > 0
        else:
            n = (own & (blocks >= thr[c] - NOISE_WINDOW * sigma[c])).sum(axis=(1, 2))
            q = noise_clip_share((thr[c] - clip_dn[c]) / sigma[c])
            excess = k > n * q + NOISE_Z * np.sqrt(n * q * (1.0 - q)) + 0.5
            true[by, bx, c] = (k > 0) & ((n == k) | excess)
        cells[by[:, None, None] * half + np.arange(half)[None, :, None],
              bx[:, None, None] * half + np.arange(half)[None, None, :], c] = \
            hit.reshape(-1, half, MAP, half, MAP).any(axis=(2, 4))
    for c in range(3):
        true[..., c] |= grow(true[..., c], 1) & clipped[..., c]
    h, w = data.shape
    ny, nx = -(-h // MAP), -(-w // MAP)
    up = np.repeat(np.repeat(true, half, axis=0), half, axis=1)
    bits = np.zeros((nby * half, nbx * half), dtype=np.uint8)
    for c in range(3):
        bits |= grow(cells[..., c] & up[..., c], 1).astype(np.uint8) << c
    return ClipMap(np.ascontiguousarray(bits[:ny, :nx]), clipped, true)


def noise_clip_share(t: float) -> float:
    """q_C of :func:`clip_map`: the share of the samples from NOISE_WINDOW sigma under the
    threshold up that reach it, for a level ``-t`` sigma over the threshold (t = (T - C) / sigma).

    >>> round(noise_clip_share(-0.02 / 0.012), 3)        # gain 1 of the simulator: sigma 1.2 %
    0.952
    """
    def tail(z: float) -> float:
        return 0.5 * math.erfc(z / math.sqrt(2.0))
    return tail(t) / max(tail(t - NOISE_WINDOW), 1e-300)


def threshold_sigma(raw, noise, thr: np.ndarray) -> np.ndarray | None:
    """(3,) the noise std (DN) of each channel at its clip threshold, from ``noise`` (white-balanced
    units), or None without one."""
    if noise is None:
        return None
    black = np.asarray(raw.black_level, dtype=np.float64)
    span = float(raw.white_level) - black
    gains = raw.pass1_gains()
    level = (thr - black) / span * gains
    return np.array([math.sqrt(max(float(noise.variance(c, level[c])), 0.0)) / gains[c] * span[c] for c in range(3)])


def block_peaks(data: np.ndarray, b: int) -> np.ndarray:
    """The largest sample of each b x b block of a mosaic (blocks on its grid from (0, 0); the
    last row and column of blocks may be cut by its edge): ceil(H / b) x ceil(W / b)."""
    h, w = data.shape
    hf, wf = h // b * b, w // b * b
    out = np.zeros((-(-h // b), -(-w // b)), dtype=data.dtype)
    if hf and wf:
        out[:h // b, :w // b] = data[:hf, :wf].reshape(h // b, b, w // b, b).max(axis=(1, 3))
    for rows, cols, at in (((0, h), (wf, w), (slice(None), -1)), ((hf, h), (0, w), (-1, slice(None)))):
        part = data[rows[0]:rows[1], cols[0]:cols[1]]
        if part.size:
            padded = np.zeros((-(-part.shape[0] // b) * b, -(-part.shape[1] // b) * b), dtype=data.dtype)
            padded[:part.shape[0], :part.shape[1]] = part
            peaks = padded.reshape(padded.shape[0] // b, b, padded.shape[1] // b, b).max(axis=(1, 3))
            out[at] = np.maximum(out[at], peaks.reshape(-1))
    return out


def gather_blocks(data: np.ndarray, by: np.ndarray, bx: np.ndarray, b: int) -> np.ndarray:
    """The b x b blocks (by, bx) of a mosaic, n x b x b, zeros past its edge."""
    h, w = data.shape
    rows = by[:, None] * b + np.arange(b)[None, :]                # n x b
    cols = bx[:, None] * b + np.arange(b)[None, :]
    inside = (rows[:, :, None] < h) & (cols[:, None, :] < w)
    out = data[np.minimum(rows, h - 1)[:, :, None], np.minimum(cols, w - 1)[:, None, :]]
    return np.where(inside, out, 0).astype(data.dtype)


def block_channels(cfa, by: np.ndarray, bx: np.ndarray, b: int) -> np.ndarray:
    """The CFA channel of every sample of the b x b blocks (by, bx): n x b x b (or 1 x b x b where b
    is a multiple of the CFA's period, as every block then has the same)."""
    p = cfa.period
    pattern = np.asarray(cfa.pattern)
    if b % p == 0:
        return cfa.channel_map(b, b)[None]
    rows = (by[:, None] * b + np.arange(b)[None, :]) % p
    cols = (bx[:, None] * b + np.arange(b)[None, :]) % p
    return pattern[rows[:, :, None], cols[:, None, :]]


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


def highlight_stage(raw, mode: str, wb2: np.ndarray | None = None, force: bool = False, noise=None,
                    scale: int = 1) -> Stage | None:
    """The highlight stage for ``raw`` (3-channel CFAs), or None for mode 'off', a raw without
    clipped samples, one whose clipped samples are all the noise of whites at full scale
    (:func:`clip_map`; ``clip`` and ``reconstruct``), unless ``force``, or a colour matrix without
    a positive neutral. ``noise``: the raw's channel noise for the noise test (ChannelNoise); None:
    the raw's own (clisp.noise_estimate.raw_noise: its sensor model, else estimated; a raw too
    small to estimate it gets no test). ``scale``: mosaic px per pixel of the stage's grid (2 after
    the half-size binning)."""
    if mode not in MODES:
        raise ClispError(f"unknown highlight mode {mode!r}; expected one of {', '.join(MODES)}")
    if mode == "off" or raw.cfa.n_channels != 3:
        return None
    bits = None
    if mode == "clamp":
        if not (force or has_clipped(raw)):
            return None
    else:
        found = clip_map(raw, raw_noise_or_none(raw) if noise is None else noise)
        if found is not None and found.bits.any():
            bits = found.bits
        elif not force:
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
    return Highlights(n, MARGIN * t, float(t.min()), mode, display=display_matrix(raw.colour_matrix, n),
                      clip_map=bits, map_cell=MAP // scale)


def raw_noise_or_none(raw):
    """The raw's channel noise (clisp.noise_estimate.raw_noise), None where it cannot be estimated."""
    from ...noise_estimate import NoiseEstimateError, raw_noise
    try:
        return raw_noise(raw)
    except NoiseEstimateError:
        return None


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
