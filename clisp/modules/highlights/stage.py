"""Highlight handling: colour where the sensor clipped (issue 14).

After white balance pass 1 each channel c clips at its own level ``L_c = clip_c * gain_c``
(normalised clip level times the pass-1 gain), so a blown white whose channels all clipped comes
out as (L_0, L_1, L_2): coloured. This stage runs right after the demosaic, on the white-balanced
camera channels (H x W x 3; LMS in LMS space), and decides per pixel from the demosaiced values.

Notation: ``n`` is the neutral of the camera space, the white-balanced camera values that the
colour matrix and white balance pass 2 take to a grey (n = M^-1 W2^-1 (1, 1, 1)); every channel is
measured in units of it, ``y_c = x_c / n_c`` (a neutral pixel has equal y). A channel is clipped
where ``y_c >= t_c``, ``t_c = CLIP_FRACTION L_c / n_c`` (the scene analysis' threshold,
clisp.scene.block_analysis, so a raw the analysis finds unclipped is left alone exactly).

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
from dataclasses import dataclass, field, replace
from functools import partial

import numpy as np

from ...errors import ClispError
from ...scene.noise import CLIP_FRACTION, NoiseEstimateError, raw_noise
from ...scene.statistics import PEAK, block_maxima
from ...engine import host_threads
from ...engine.runtime import DeviceImage, Runtime
from ...engine.stage import Stage, as_f32
from ...sim.colorimetry import SRGB_ENCODING
from ..colour.stage import ColourMatrix, ToneCurve, WhiteBalance2, camera_neutral, eight_per_item, srgb_source

MODES = ("clip", "reconstruct", "clamp", "off")
DEFAULT_MODE = "reconstruct"
"""``--highlights`` default (tools/bench_highlights.py; docs/RESULTS.md, "Highlights")."""

RADIUS = 16
"""How far (px) the bright unclipped pixels that give a clipped pixel its colour may lie: the
stage's halo beyond RIM; the cells it reads lie within it (:func:`cell_radius`)."""

SUMS = 12
"""Reference planes that ``reconstruct`` box-sums (:func:`reference_weights`): far (4), rim (5),
surface (3)."""

REFS = 18
"""Planes per cell that hl_box_cols makes from the box sums for hl_apply (highlights.cl)."""

CELL = 4
"""The references are summed over cells of CELL x CELL px on the image's grid, and a pixel's
reference colour over the (2 k + 1)^2 cells around its cell, k = :func:`cell_radius` (RADIUS 16:
7 x 7 cells, 28 px, reaching 12 to 15 px from the pixel): per-pixel box sums of the reference planes cost
more than the rest of the stage."""

REF = 0.9
"""A pixel is a colour reference only while every channel is below this share of its threshold
(the demosaic blends clipped samples into their neighbours' values just below the threshold)."""

LOW = 0.5
"""Reference weight ramps from 0 at this share of the threshold to 1 at REF."""

SURFACE_LOW = 0.05
SURFACE_FULL = 0.3
"""The surface references' weight ramps from 0 at SURFACE_LOW of the threshold to 1 at SURFACE_FULL:
the colour of the surface a specular highlight sits on, which is rarely bright enough to be a far
reference (a red sphere's diffuse L at 0.4 of its threshold), without the darkest pixels' noisy
chroma."""

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

ADD_PRIOR = 0.25
"""Weight of the prior toward the rim's whole difference chroma (s = 1) against the evidence of a
pixel's two free channels in :func:`additive_estimate` (relative to |Delta|^2)."""

ADD_LIMIT = 0.5
"""The additive chroma s Delta of :func:`additive_estimate` at most this share of the white b in
every output channel: the LMS matrix turns a small L - M difference into a large red one."""

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


MAP = 4
"""Side (mosaic px) of the cells of the clip map (:func:`clip_map`): a pixel's channel may count as
clipped only in a cell the map allows for it, one that holds a clipped sample the noise test calls
a true clip. The stage's kernels work only where such a cell lies near enough (Highlights.schedule),
so the stage works in proportion to the clipped area. On the stage's grid the cells are MAP_CELL
px (after the half-size binning, two by two of these)."""

MAP_CELL = 4
"""The map's cell side on the stage's grid (px): a multiple of CELL and at least RIM, so a
reference cell lies in one map cell and every pixel within RIM of a flag lies within a cell of it."""

WORK = 8
"""Side (px) of the work-groups of the list kernels (Highlights.schedule): WORK x WORK pixels each,
2 x 2 map cells (measured, PoCL, 2 cores: lists of 8 x 8 px run a copy at 1.4x the cost of a
whole-window launch per pixel; 4 x 4 would pay four times the groups)."""

TEST = 16
"""Side (mosaic px) of the blocks of the noise test (:func:`clip_map`): 4 x 4 map cells; 128
samples of a channel that holds half the sites (LMS L, Bayer G), 64 of a quarter, 32 of an eighth."""

NOISE_WINDOW = 3.0
"""The noise test counts a block's samples of a channel from NOISE_WINDOW sigma (the noise at the
clip threshold) under the threshold up: the samples a level near full scale puts there, few of
a darker surface beside it."""

MAP_GROW = 0
"""Cells around a cell of a truly clipped sample where its channel may count as clipped too."""

PILE_SHARE = 0.25
PILE_MIN = 20
"""saturation_dn: the pile of saturated samples reaches down while each DN value holds PILE_SHARE of
its largest count; under PILE_MIN clipped samples, the largest sample stands for it."""

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
    clip_map   (ny, nx) uint8 per cell of MAP_CELL px on the stage's grid, on the image's grid
               (:func:`clip_map`): bit c set where channel c may count as clipped; None:
               everywhere (a stage built by hand). Cells past the image's edge take the edge's
               (clamped lookups).
    weights    (3,) how much each channel's record counts where the free channels give a
               brightness (:func:`channel_weights`); None: equal.
    """

    neutral: np.ndarray
    threshold: np.ndarray
    white: float
    mode: str = DEFAULT_MODE
    radius: int = RADIUS
    rim: int = RIM
    display: np.ndarray | None = None
    clip_map: np.ndarray | None = field(default=None, repr=False)
    weights: np.ndarray | None = None
    name = "highlights"

    def __post_init__(self) -> None:
        if self.mode not in ("clip", "reconstruct"):
            raise ClispError(f"unknown highlight mode {self.mode!r}; expected clip or reconstruct")
        if not 1 <= self.rim <= MAP_CELL:
            raise ClispError(f"highlights: rim {self.rim} must be 1 to the map's cell of {MAP_CELL} px")
        self.neutral = np.asarray(self.neutral, dtype=np.float64).reshape(3)
        self.threshold = np.asarray(self.threshold, dtype=np.float64).reshape(3)
        self.white = float(self.white)
        self.display = np.eye(3) if self.display is None else np.asarray(self.display, dtype=np.float64).reshape(3, 3)
        if self.clip_map is not None:
            self.clip_map = np.ascontiguousarray(self.clip_map, dtype=np.uint8)
        self.weights = np.ones(3) if self.weights is None else np.asarray(self.weights, dtype=np.float64).reshape(3)

    @property
    def halo(self) -> int:
        return self.rim + (self.radius if self.mode == "reconstruct" else 0)

    @property
    def bytes_per_pixel(self) -> float:
        """Device bytes per input pixel: the output (3 float32 planes), flags, near rows and near
        (one byte each); reconstruct: the cell sums, their rows and what apply reads (2 SUMS + REFS
        float32 planes at 1 / CELL^2 of the pixels)."""
        return 12.0 + 3.0 + (4.0 * (2 * SUMS + REFS) / CELL ** 2 if self.mode == "reconstruct" else 0.0)

    def allowed(self, origin: tuple[int, int], shape: tuple[int, int]) -> np.ndarray:
        """H x W x 3 bool for a window of ``shape`` at ``origin``: where each channel may count as
        clipped (the clip map's cell of each pixel, clamped to the map's edge)."""
        h, w = shape
        if self.clip_map is None:
            return np.ones((h, w, 3), dtype=bool)
        ny, nx = self.clip_map.shape
        rows = np.clip((origin[0] + np.arange(h)) // MAP_CELL, 0, ny - 1)
        cols = np.clip((origin[1] + np.arange(w)) // MAP_CELL, 0, nx - 1)
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
        offset = tuple((o + d) % CELL for o in origin)     # the cell grid in image coordinates
        weights = reference_weights(y, t, near) * sampled(offset, y.shape[:2])[..., None]   # H x W x 7
        sums = cell_box_sums(weights, offset, r)
        crop = (slice(r, y.shape[0] - r), slice(r, y.shape[1] - r))
        saturated = clipped & ((y >= t / MARGIN) | (clipped.sum(axis=-1, keepdims=True) >= 2))
        return reconstruct(y[crop], clipped[crop], near[crop], sums, self.display, self.weights,
                           saturated[crop]) * n

    # ------------------------------------------------------------------------------- OpenCL

    def window_map(self, origin: tuple[int, int], height: int, width: int) -> tuple[np.ndarray, int, int]:
        """(the clip map's cells over a window of height x width at ``origin``, (ngy, ngx) uint8;
        py, px): window pixel (y, x) lies in cell ((y + py) // MAP_CELL, (x + px) // MAP_CELL)."""
        mc = MAP_CELL
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
        """The kernels' work over a window (host side, from the clip map).

        ``map``: the window's map cells with the channels they allow (bits 0-2), ``py``, ``px``
        (:meth:`window_map`). The lists of WORK px cells (gy << 16 | gx, window pixel (y, x) in
        cell ((y + wy) // WORK, (x + wx) // WORK)) each list kernel runs over: ``flags`` the
        cells holding a map cell that allows a channel (a seed; flags are 0 elsewhere), ``near``
        those holding a seed or a map cell beside one (every pixel within RIM <= MAP_CELL of a flag:
        hl_near, hl_apply), ``rows`` those and the cells above and below (the near rows hl_near
        reads, RIM <= WORK rows away). Reconstruct: the grid of reference cells (CELL px on the image's grid: ``ncw`` x
        ``nch``, the window less the rim's first pixel at (``oy``, ``ox``) of its cell) with
        ``cells``, bits WORK_BOX where hl_box_cols works (the cells within a map cell of a seed:
        every pixel apply reads the box at), WORK_ROWS those and k cells above and below
        (hl_box_rows, k = cell_radius(radius)), WORK_CELLS those and k cells to each side
        (hl_cells)."""
        cells, py, px = self.window_map(origin, height, width)
        seeds = cells != 0
        near = grow(seeds, 1)
        wy, wx = origin[0] % WORK, origin[1] % WORK
        pool = partial(work_cells, origin=origin, shape=(height, width))
        work = pool(near)
        plan = {"map": cells, "py": py, "px": px, "wy": wy, "wx": wx, "flags": cell_list(pool(seeds)),
                "near": cell_list(work), "rows": cell_list(grow(work, 1, axes=(0,)))}
        if self.mode == "reconstruct":
            d, k, mc = self.rim, cell_radius(self.radius), MAP_CELL
            w1, h1 = width - 2 * d, height - 2 * d
            oy, ox = ((o + d) % CELL for o in origin)      # the window less the rim's first pixel in its cell
            ncw, nch = -(-(w1 + ox) // CELL), -(-(h1 + oy) // CELL)
            # the map cell of each reference cell's first pixel (cells lie inside map cells)
            rows = np.clip((np.arange(nch) * CELL - oy + d + py) // mc, 0, cells.shape[0] - 1)
            cols = np.clip((np.arange(ncw) * CELL - ox + d + px) // mc, 0, cells.shape[1] - 1)
            box = near[rows[:, None], cols[None, :]]
            box_rows = grow(box, k, axes=(0,))
            plan.update(oy=oy, ox=ox, ncw=ncw, nch=nch, cells=(np.where(box, WORK_BOX, 0)
                        | np.where(box_rows, WORK_ROWS, 0)
                        | np.where(grow(box_rows, k, axes=(1,)), WORK_CELLS, 0)).astype(np.uint8))
        return plan

    def enqueue(self, rt: Runtime, src: DeviceImage, origin: tuple[int, int]) -> DeviceImage:
        w, h, d = src.width, src.height, self.rim
        r = self.radius if self.mode == "reconstruct" else 0
        ow, oh = w - 2 * (d + r), h - 2 * (d + r)
        defines = {"HL_RADIUS": r, "HL_RIM": d, "HL_MC": MAP_CELL, "HL_WC": WORK, "HL_REF": repr(REF) + "f",
                   "HL_LOW": repr(LOW) + "f", "HL_PRIOR": repr(PRIOR) + "f", "HL_DIP": repr(DIP) + "f",
                   "HL_MARGIN": repr(MARGIN) + "f", "HL_RHO_MIN": repr(RHO_MIN) + "f", "HL_CLIP": int(self.mode == "clip"),
                   "HL_AGREE_LO": repr(AGREE_LO) + "f", "HL_AGREE_HI": repr(AGREE_HI) + "f",
                   "HL_RISE_LO": repr(RISE_LO) + "f", "HL_RISE_HI": repr(RISE_HI) + "f",
                   "HL_EVIDENCE": repr(EVIDENCE) + "f", "HL_SUMS": SUMS, "HL_REFS": REFS, "HL_ADD_PRIOR": repr(ADD_PRIOR) + "f",
                   "HL_ADD_LIMIT": repr(ADD_LIMIT) + "f", "HL_SURFACE_LOW": repr(SURFACE_LOW) + "f",
                   "HL_SURFACE_FULL": repr(SURFACE_FULL) + "f", "HL_CELL": CELL,
                   "HL_CELL_R": cell_radius(self.radius), "HL_SAMPLES": len(SAMPLES),
                   "HL_SAMPLE_Y": "{" + ",".join(str(dy) for dy, _ in SAMPLES) + "}",
                   "HL_SAMPLE_X": "{" + ",".join(str(dx) for _, dx in SAMPLES) + "}", "HL_WORK_CELLS": WORK_CELLS,
                   "HL_WORK_ROWS": WORK_ROWS, "HL_WORK_BOX": WORK_BOX}
        uploads: list[DeviceImage] = []

        def upload(array: np.ndarray) -> DeviceImage:                # the window's tables, pooled
            uploads.append(rt.upload(array.reshape(1, -1) if array.ndim == 1 else array))
            return uploads[-1]

        def launch(kernel: str, gx: int, gy: int, /, **args: object) -> None:
            rt.launch_named("highlights", kernel, gx, gy, args, defines)

        def over(kernel: str, cells: np.ndarray, /, **args: object) -> None:      # one work-group per cell
            rt.launch_named("highlights", kernel, WORK, WORK * len(cells), dict(args, list=upload(cells), wy=plan["wy"],
                            wx=plan["wx"]), defines, group=(WORK, WORK))

        dst = rt.acquire(3, oh, ow)
        launch("hl_copy", ow, oh, src=src, dst=dst, width=w, height=h, out_w=ow, out_h=oh)
        plan = self.schedule(origin, h, w)
        if not len(plan["flags"]):
            return dst                                 # nothing may clip within the window: a copy
        n, t = rt.constant(as_f32(self.neutral)), rt.constant(as_f32(self.threshold))
        py, px = plan["py"], plan["px"]
        flags = rt.acquire(1, h, w, np.uint8)
        launch("hl_clear", w, h, dst=flags, width=w)
        over("hl_flags", plan["flags"], src=src, cells=upload(plan["map"]), dst=flags, width=w, height=h,
             ngx=plan["map"].shape[1], py=py, px=px, n=n, t=t)
        w1, h1 = w - 2 * d, h - 2 * d
        rows = rt.acquire(1, h, w1, np.uint8)
        over("hl_near_rows", plan["rows"], flags=flags, dst=rows, width=w, height=h, w1=w1)
        near = rt.acquire(1, h1, w1, np.uint8)                   # on the window less the rim
        launch("hl_clear", w1, h1, dst=near, width=w1)
        over("hl_near", plan["near"], rows=rows, dst=near, w1=w1, h1=h1)
        rt.release(rows)
        box, grid = near, {"ncw": 1, "nch": 1, "oy": 0, "ox": 0}
        if r:
            grid = {k: plan[k] for k in ("ncw", "nch", "oy", "ox")}
            ncw, nch = grid["ncw"], grid["nch"]
            work = dict(grid, cells=upload(plan["cells"]))
            sums = rt.acquire(SUMS, nch, ncw)
            launch("hl_cells", ncw, nch, src=src, near=near, dst=sums, width=w, height=h, w1=w1, h1=h1, n=n, t=t,
                   **work)
            rows = rt.acquire(SUMS, nch, ncw)
            launch("hl_box_rows", ncw, nch, sums=sums, dst=rows, **work)
            rt.release(sums)
            box = rt.acquire(REFS, nch, ncw)
            launch("hl_box_cols", ncw, nch, rows=rows, dst=box, d=rt.constant(as_f32(self.display)), **work)
            rt.release(rows)
        over("hl_apply", plan["near"], src=src, flags=flags, nearby=near, box=box, dst=dst, width=w, height=h,
             w1=w1, out_w=ow, out_h=oh, n=n, t=t, d=rt.constant(as_f32(self.display)),
             wt=rt.constant(as_f32(self.weights)), h=rt.constant(as_f32(white_of(self.display))), white=self.white,
             **grid)
        rt.release(flags)
        rt.release(near)
        if r:
            rt.release(box)
        for image in uploads:
            rt.release(image)
        return dst


SAMPLES = ((0, 0), (1, 2), (2, 1), (3, 3))
"""The pixels of each CELL x CELL cell (dy, dx, on the image's grid) whose reference weights the
cell sums: one in four, on every CFA phase of the Bayer and LMS patterns (R, G, G, B; L, M, S, L),
so a demosaic's error at one phase does not colour the references; the SUMS planes of weights
cost a quarter (the cells were the stage's largest kernel on the D30 DNG). The box over 7 x 7
cells still sums 196 pixels."""

WORK_CELLS = 32
"""Bit of a reference cell (Highlights.schedule) where hl_cells sums the reference weights."""
WORK_ROWS = 8
"""Bit of a reference cell where hl_box_rows sums the reference sums along its row of cells."""
WORK_BOX = 16
"""Bit of a reference cell where hl_box_cols completes the box of cells (hl_apply reads it)."""


def grow(mask: np.ndarray, k: int, axes: tuple[int, ...] = (0, 1)) -> np.ndarray:
    """``mask`` (2-D bool) grown by k entries along ``axes`` (a (2 k + 1)-wide maximum, zeros past
    the edges)."""
    out = mask
    for axis in axes:
        pad = [(0, 0)] * mask.ndim
        pad[axis] = (k, k)
        out = box_max(np.pad(out, pad), k, axis)
    return out


def work_cells(mask: np.ndarray, origin: tuple[int, int], shape: tuple[int, int]) -> np.ndarray:
    """A window's map cells (MAP_CELL px, :meth:`Highlights.window_map`) to its WORK px cells: a
    work cell is set where a map cell it holds is (both grids on the image's)."""
    out = mask.astype(np.uint8)
    for axis, (o, n) in enumerate(zip(origin, shape)):
        first, groups = o // MAP_CELL, o // WORK
        index = (first + np.arange(out.shape[axis])) * MAP_CELL // WORK - groups   # the work cell of each map cell
        count = (o % WORK + n - 1) // WORK + 1
        starts = np.searchsorted(index, np.arange(count))
        out = np.maximum.reduceat(out, starts, axis=axis)
    return out.astype(bool)


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
    (default y_c >= t_c; the stage: that, where the clip map allows c), or, at pixels where another
    channel is, where y_c >= DIP t_c and c is hard at one of the 8 neighbours (inside the array)."""
    hard = y >= t if hard is None else hard
    padded = np.pad(hard, ((1, 1), (1, 1), (0, 0)))
    h, w = hard.shape[:2]
    beside = np.zeros_like(hard)
    for dy in range(3):
        for dx in range(3):
            beside |= padded[dy:dy + h, dx:dx + w]
    return hard | (beside & (y >= DIP * t) & hard.any(axis=-1, keepdims=True))


def reference_weights(y: np.ndarray, t: np.ndarray, near: np.ndarray) -> np.ndarray:
    """H x W x SUMS per pixel of y (H x W x 3, units of n) for thresholds t and the near mask:
    (w, w rho_0, w rho_1, w mean(y)) of the far references (bright, clearly unclipped, not near a
    clipped pixel), (w, w rho_0, w rho_1, w (y_0 - mean(y)), w (y_1 - mean(y))) of the rim
    references (near, no channel clipped, bright), (w, w rho_0, w rho_1) of the surface
    references (not near, clearly unclipped, of any brightness but the darkest). w ramps from 0 at
    LOW to 1 at REF of the threshold (surface: from SURFACE_LOW to SURFACE_FULL), rho_c = y_c / mean(y)."""
    m = np.max(y / t, axis=-1)
    ramp = np.clip((m - LOW) / (REF - LOW), 0.0, 1.0)
    far = np.where((m < REF) & ~near, ramp, 0.0)
    rim = np.where(near & (m < 1.0), ramp, 0.0)
    surface = np.where((m < REF) & ~near, np.clip((m - SURFACE_LOW) / (SURFACE_FULL - SURFACE_LOW), 0.0, 1.0), 0.0)
    mean = y.mean(axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = np.where(mean > 0, 1.0 / mean, 0.0)
    return np.stack([far, far * y[..., 0] * inv, far * y[..., 1] * inv, far * mean,
                     rim, rim * y[..., 0] * inv, rim * y[..., 1] * inv,
                     rim * (y[..., 0] - mean), rim * (y[..., 1] - mean),
                     surface, surface * y[..., 0] * inv, surface * y[..., 1] * inv], axis=-1)


def sampled(offset: tuple[int, int], shape: tuple[int, int]) -> np.ndarray:
    """H x W, 1.0 at the pixels whose reference weights the cells sum (SAMPLES, on the grid of
    cells that starts ``offset`` (dy, dx) px before the array's first pixel), else 0.0.

    >>> sampled((0, 0), (4, 4)).astype(int).tolist()
    [[1, 0, 0, 0], [0, 0, 1, 0], [0, 1, 0, 0], [0, 0, 0, 1]]
    """
    mask = np.zeros((CELL, CELL))
    for dy, dx in SAMPLES:
        mask[dy, dx] = 1.0
    rows = (np.arange(shape[0]) + offset[0]) % CELL
    cols = (np.arange(shape[1]) + offset[1]) % CELL
    return mask[rows[:, None], cols[None, :]]


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


def rim_difference(sums: np.ndarray, display: np.ndarray) -> np.ndarray:
    """Delta (H x W x 3, summing to 0, units of n): the part of the rim references' mean difference
    chroma (y_c - mean(y), pulled toward 0 by the prior of PRIOR pixels of none) that lies along the
    surface references' chroma surface - 1, a >= 0 times it (least squares after the display
    matrix). What a specular highlight adds to the surface is white, so its rim is white plus the
    surface's colour; what a light's rim has besides (the demosaic's false colour) is left out."""
    sw = sums[..., 4] + PRIOR
    d0, d1 = sums[..., 7] / sw, sums[..., 8] / sw
    delta = np.stack([d0, d1, -d0 - d1], axis=-1)
    c = chroma_of(sums[..., 9:12]) - 1.0
    dd, dc = delta @ display.T, c @ display.T
    cc = (dc * dc).sum(axis=-1)
    a = np.where(cc > 1e-12, np.maximum((dd * dc).sum(axis=-1), 0.0) / np.maximum(cc, 1e-12), 0.0)
    return a[..., None] * c


def additive_estimate(y: np.ndarray, clipped: np.ndarray, delta: np.ndarray, display: np.ndarray,
                      weights: np.ndarray = np.ones(3), saturated: np.ndarray | None = None) -> np.ndarray:
    """The additive (difference) chroma estimate of every channel, b + s Delta (H x W x 3), at
    pixels with one or two clipped channels: a specular highlight is white (b) added to the surface
    colour, whose difference chroma the unclipped rim around it shows (Delta, :func:`rim_difference`).

    s, how much of the rim's chroma the pixel holds: with one clipped channel, from its two free
    channels u, v, (y_u - y_v) against (Delta_u - Delta_v), least squares with a prior ADD_PRIOR
    toward 1 (the free channels of a red surface's highlight, G and B, cannot tell; those of a
    white beside teal say 0), kept in [0, 1]; with two, 0 (one free channel cannot tell a white
    beside a coloured surface from a highlight on it: the least bright neutral the records allow,
    as before issue 43). Bounded so the colour matrix cannot blow
    it up: s Delta at most ADD_LIMIT times b in every output channel (display @ s Delta). b: the
    free channels' mean less s Delta, at least every saturated channel's record less s Delta_c (a
    clipped record bounds the truth from below; ``saturated`` as in :func:`reconstruct`, None: all
    of ``clipped``)."""
    saturated = clipped if saturated is None else saturated
    free = ~clipped
    count = clipped.sum(axis=-1)
    fy, fd = np.where(free, y, 0.0), np.where(free, delta, 0.0)
    pair = 2.0 * (fy * fd).sum(axis=-1) - fy.sum(axis=-1) * fd.sum(axis=-1)        # (y_u - y_v)(D_u - D_v)
    spread = 2.0 * (fd * fd).sum(axis=-1) - fd.sum(axis=-1) ** 2                  # (D_u - D_v)^2
    prior = ADD_PRIOR * (delta * delta).sum(axis=-1)
    one = np.clip((pair + prior) / np.maximum(spread + prior, 1e-12), 0.0, 1.0)
    s = np.where(count == 1, one, 0.0)
    wfree = np.maximum(np.where(free, weights, 0.0).sum(axis=-1), 1e-12)
    b0 = np.maximum(np.where(free, weights * (y - s[..., None] * delta), 0.0).sum(axis=-1) / wfree, 0.0)
    size = np.abs((s[..., None] * delta) @ display.T).max(axis=-1)
    s = np.where(size > ADD_LIMIT * b0, s * ADD_LIMIT * b0 / np.maximum(size, 1e-12), s)
    sd = s[..., None] * delta
    b = np.maximum(np.where(free, weights * (y - sd), 0.0).sum(axis=-1) / wfree,
                   np.where(saturated, y - sd, -np.inf).max(axis=-1))
    return b[..., None] + sd


def white_of(display: np.ndarray) -> np.ndarray:
    """(3,) h = D^T D 1 / |D 1|^2 (D the display matrix): h . y is the neutral b that
    :func:`surface_projection` fits to y where the surface has no chroma."""
    d1 = np.asarray(display, dtype=np.float64).sum(axis=1)
    return display.T @ d1 / float(d1 @ d1)


def surface_projection(y: np.ndarray, far: np.ndarray, display: np.ndarray) -> np.ndarray:
    """y (H x W x 3, units of n) as white plus a surface's colour ``far`` (chroma, mean 1, the
    surface references'): b + s (far - 1) with
    0 <= s <= mean(y) (the surface's part is at most the pixel's brightness, so a surface whose
    chroma is a little noise keeps no false colour along it), the least-squares fit after the
    display matrix (where differences are seen): what of a rim pixel a specular highlight on that
    surface explains; the rest (the demosaic's false colour beside a clipped light) is left out."""
    c = far - 1.0
    dy, dc = y @ display.T, c @ display.T
    d1 = display.sum(axis=1)                                     # display @ (1, 1, 1)
    a11 = float(d1 @ d1)
    a12 = dc @ d1
    e = dc - (a12 / a11)[..., None] * d1                         # dc's part across d1
    ee, a22 = (e * e).sum(axis=-1), (dc * dc).sum(axis=-1)
    ok = (a22 > 1e-12) & (ee > 1e-6 * a22)
    s = np.where(ok, np.clip((dy * e).sum(axis=-1) / np.where(ok, ee, 1.0), 0.0, y.mean(axis=-1)), 0.0)
    b = (dy @ d1 - a12 * s) / a11
    return b[..., None] + s[..., None] * c


def reconstruct(y: np.ndarray, clipped: np.ndarray, near: np.ndarray, sums: np.ndarray,
                display: np.ndarray = np.eye(3), weights: np.ndarray = np.ones(3),
                saturated: np.ndarray | None = None) -> np.ndarray:
    """The reconstruction rule on y (H x W x 3, units of n), given the clipped channels, the near
    mask, the box sums of :func:`reference_weights` (H x W x SUMS), the display matrix, the
    free channels' weights (:func:`channel_weights`) and the clipped channels whose record bounds
    the truth from below (``saturated``; None: all of ``clipped``). The stage passes those whose
    record is itself a clipped value (at or above the clip threshold t_c / MARGIN), and every
    clipped record of a pixel with two clipped channels (its one free channel cannot tell a colour,
    so the records are the evidence): with two free channels, a record under the threshold is the
    demosaic's interpolation across the clip's edge, which can lie above the truth as well as below
    it, and the free channels' estimate decides (README.md, issue 43)."""
    saturated = clipped if saturated is None else saturated
    far = chroma_of(sums[..., :3])
    trust = trust_in_far(y, clipped, sums, display)
    rho = 1.0 + trust[..., None] * (far - 1.0)
    free = ~clipped
    count = clipped.sum(axis=-1)
    num = np.sum(np.where(free, weights * y, 0.0), axis=-1)
    den = np.maximum(np.sum(np.where(free, weights * rho, 0.0), axis=-1), 1e-6)
    bound = np.where(saturated & (rho >= RHO_MIN), y / np.maximum(rho, RHO_MIN), 0.0).max(axis=-1)
    ratio = np.maximum(num / den, bound)[..., None] * rho
    additive = additive_estimate(y, clipped, rim_difference(sums, display), display, weights, saturated)
    estimate = trust[..., None] * ratio + (1.0 - trust[..., None]) * additive
    out = np.where(clipped, np.where(saturated, np.maximum(y, estimate), estimate), y)
    mean = y.mean(axis=-1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        own = np.where(mean > 0, y / mean, 1.0)
    keep = sums[..., 0] / (sums[..., 0] + EVIDENCE) * (1.0 - agreement(own, far, display))
    rim = y + (1.0 - keep)[..., None] * (surface_projection(y, chroma_of(sums[..., 9:12]), display) - y)
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


def clip_map(raw, noise=None, peaks: np.ndarray | None = None) -> ClipMap | None:
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
    past its samples). Cost: one maximum per TEST block over the mosaic (``peaks``: those maxima
    from the statistics pass, clisp.scene.statistics.SceneStatistics.peaks, which reads the mosaic
    anyway; None: taken here, after one maximum over the mosaic, ten times cheaper, has shown that
    some sample reaches the lowest threshold); the counts only in the blocks that reach it."""
    data = raw.data
    if data.dtype != np.uint16 or raw.cfa.n_channels != 3:
        return None
    thr = clip_thresholds_dn(raw)
    if peaks is None or PEAK != TEST or peaks.shape != (-(-data.shape[0] // TEST), -(-data.shape[1] // TEST)):
        if host_threads.maximum(data) < float(thr.min()):      # nothing clipped: no block maxima
            return None
        peaks = block_maxima(data, TEST)
    found = np.argwhere(peaks >= thr.min())
    if not len(found):
        return None
    by, bx = found[:, 0], found[:, 1]
    blocks = gather_blocks(data, by, bx, TEST)                     # n x TEST x TEST samples
    channel = block_channels(raw.cfa, by, bx, TEST)               # n x TEST x TEST channel indices
    clip_dn = np.array([saturation_dn(blocks[(channel == c) & (blocks >= thr[c])], thr[c])
                        for c in range(3)])             # where each channel's samples pile up
    sigma = threshold_sigma(raw, noise, clip_dn)
    nby, nbx = peaks.shape
    half = TEST // MAP
    clipped = np.zeros((nby, nbx, 3), dtype=bool)
    true = np.zeros((nby, nbx, 3), dtype=bool)
    cells = np.zeros((nby * half, nbx * half, 3), dtype=bool)
    for c in range(3):
        own = channel == c
        hit = own & (blocks >= thr[c])
        k = np.count_nonzero(hit.reshape(len(hit), -1), axis=1)
        clipped[by, bx, c] = k > 0
        if sigma is None or sigma[c] <= 0:
            true[by, bx, c] = k > 0
        else:
            at = own & (blocks >= clip_dn[c])                          # at the saturation: censored
            kc = np.count_nonzero(at.reshape(len(hit), -1), axis=1)
            n = np.count_nonzero((own & (blocks >= clip_dn[c] - NOISE_WINDOW * sigma[c])).reshape(len(hit), -1), axis=1)
            q = noise_clip_share(0.0)
            excess = kc > n * q + NOISE_Z * np.sqrt(n * q * (1.0 - q)) + 0.5
            true[by, bx, c] = (k > 0) & (((n == kc) & (kc > 0)) | excess)
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
        bits |= grow(cells[..., c] & up[..., c], MAP_GROW).astype(np.uint8) << c
    return ClipMap(np.ascontiguousarray(bits[:ny, :nx]), clipped, true)


def saturation_dn(samples: np.ndarray, threshold: float) -> float:
    """Where a channel's samples at or over its clip ``threshold`` (DN) pile up: the lowest value
    of the pile's top, walking down from its most frequent value while each value holds at least
    PILE_SHARE of that count (a sensor whose saturation varies from pixel to pixel piles a few DN
    wide: the Canon D30 about 4053-4070 for R; the simulator and most cameras at one value, the
    white level). With fewer than PILE_MIN samples, the largest.

    >>> saturation_dn(np.array([1010, 1015] + [1022] * 3 + [1023] * 40), 1003)         # the simulator
    1023.0
    >>> counts = [1, 2, 5, 20, 40, 60, 80, 90, 80, 60, 40, 20, 10, 5, 2, 1]
    >>> saturation_dn(np.repeat(np.arange(4050, 4066), counts), 4015)                  # a ragged pile
    4054.0
    """
    samples = np.asarray(samples).ravel()
    samples = samples[samples >= threshold]
    if samples.size == 0:
        return float(threshold)
    if samples.size < PILE_MIN:
        return float(samples.max())
    base = int(math.floor(threshold))
    counts = np.bincount(samples.astype(np.int64) - base)
    v = int(np.argmax(counts))
    floor = PILE_SHARE * counts[v]
    while v > 0 and counts[v - 1] >= floor:
        v -= 1
    return float(base + v)


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


def gather_blocks(data: np.ndarray, by: np.ndarray, bx: np.ndarray, b: int) -> np.ndarray:
    """The b x b blocks (by, bx) of a mosaic, n x b x b, zeros past its edge."""
    h, w = data.shape
    if h % b == 0 and w % b == 0:
        return data.reshape(h // b, b, w // b, b)[by, :, bx, :]
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
    if host_threads.maximum(data) < float(thresholds.min()):
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
                    scale: int = 1, peaks: np.ndarray | None = None) -> Stage | None:
    """The highlight stage for ``raw`` (3-channel CFAs), or None for mode 'off', a raw without
    clipped samples, one whose clipped samples are all the noise of whites at full scale
    (:func:`clip_map`; ``clip`` and ``reconstruct``), unless ``force``, or a colour matrix without
    a positive neutral. ``noise``: the raw's channel noise for the noise test (ChannelNoise); None:
    the raw's own (clisp.scene.noise.raw_noise: its sensor model, else estimated; a raw too
    small to estimate it gets no test). ``scale``: mosaic px per pixel of the stage's grid (2 after
    the half-size binning). ``peaks``: the statistics pass's block maxima (:func:`clip_map`), if any."""
    if mode not in MODES:
        raise ClispError(f"unknown highlight mode {mode!r}; expected one of {', '.join(MODES)}")
    if mode == "off" or raw.cfa.n_channels != 3:
        return None
    bits = None
    if mode == "clamp":
        if not (force or has_clipped(raw)):
            return None
    else:
        found = clip_map(raw, raw_noise_or_none(raw) if noise is None else noise, peaks)
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
    if bits is not None and scale * MAP_CELL != MAP:             # the map's cells on the stage's grid
        f = scale * MAP_CELL // MAP
        ny, nx = -(-bits.shape[0] // f), -(-bits.shape[1] // f)
        pooled = np.zeros((ny * f, nx * f), dtype=np.uint8)
        pooled[:bits.shape[0], :bits.shape[1]] = bits
        bits = np.bitwise_or.reduce(np.bitwise_or.reduce(pooled.reshape(ny, f, nx, f), axis=3), axis=1)
    return Highlights(n, MARGIN * t, float(t.min()), mode, display=display_matrix(raw.colour_matrix, n),
                      clip_map=bits, weights=channel_weights(raw, n))


def channel_weights(raw, neutral: np.ndarray) -> np.ndarray:
    """(3,) the weight of each channel's record where the free channels give a clipped pixel's
    brightness: its share of the CFA's sites over its noise variance in units of the neutral
    (WB pass-1 gain over n, squared), largest 1. The LMS camera's S, on an eighth of the sites with
    3.1 times L's gain, counts 1/40 of L: the demosaic puts it well off at a light's edge (a white
    disc beside teal lost 0.6 of red where S pulled the brightness down); Bayer's R and B count
    about 1/7 of G.

    >>> import clisp
    >>> raw = clisp.simulate(np.full((8, 8, 3), 0.5), cfa="lms", gain=1, seed=0).raw
    >>> np.round(channel_weights(raw, np.ones(3)), 3).tolist()
    [1.0, 0.505, 0.025]
    """
    gain = raw.pass1_gains() / np.asarray(neutral, dtype=np.float64)
    w = raw.cfa.densities() / gain ** 2
    return w / w.max()


def raw_noise_or_none(raw):
    """The raw's channel noise (clisp.scene.noise.raw_noise), None where it cannot be estimated."""
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
    """A 3 x 3 matrix applied after the clamp (the colour matrix and white balance pass 2 fused
    in: :meth:`fuse`), or None."""
    tone: ToneCurve | None = None
    """The tone curve fused in after the matrix (its codes, layout and bits), or None: a raw with
    clipped samples keeps this stage between the demosaic and the colour matrix, so the curve
    cannot join the demosaic's filter and joins the clamp instead (README.md)."""

    @property
    def out_dtype(self) -> np.dtype:
        return self.tone.out_dtype if self.tone is not None else np.dtype(np.float32)

    @property
    def interleaved(self) -> bool:                 # type: ignore[override]
        return self.tone is not None and self.tone.interleaved

    @property
    def writes_into(self) -> bool:                 # type: ignore[override]
        return self.tone is not None

    def reference(self, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
        out = np.minimum(np.asarray(x, dtype=np.float64), self.white * self.neutral)
        out = out if self.matrix is None else out @ np.asarray(self.matrix, dtype=np.float64).T
        return out if self.tone is None else self.tone.reference(out, origin)

    def fuse(self, following: Stage) -> Stage | None:
        if self.tone is not None:
            return None
        if type(following) is ColourMatrix or (self.matrix is not None and type(following) is WhiteBalance2):
            m = np.asarray(following.matrix, dtype=np.float64)
            return replace(self, matrix=m if self.matrix is None else m @ self.matrix)
        if isinstance(following, ToneCurve):
            return replace(self, tone=following)
        return None

    def with_interleaved_output(self) -> HighlightClamp | None:
        return replace(self, tone=self.tone.with_interleaved_output()) if self.tone is not None else None

    def enqueue(self, rt: Runtime, src: DeviceImage, origin: tuple[int, int],
                out: DeviceImage | None = None) -> DeviceImage:
        cap = self.white * self.neutral
        m = np.eye(3) if self.matrix is None else self.matrix
        args = dict(src=src, width=src.width, height=src.height, cap0=cap[0], cap1=cap[1], cap2=cap[2],
                    m=rt.constant(as_f32(m)))
        defines = {"MATRIX": int(self.matrix is not None)}
        if self.tone is None:
            dst = rt.acquire(3, src.height, src.width)
            rt.launch_named("highlights", "hl_clamp", src.width, src.height, dict(args, dst=dst), defines)
            return dst
        t = self.tone
        defines.update(ENCODE_SRGB=1, QUANTIZE=int(t.quantize), CODE_BITS=t.bits, INTERLEAVED=int(t.interleaved),
                       **SRGB_ENCODING)
        dst = out if out is not None else rt.acquire(3, src.height, src.width, self.out_dtype)
        if t.interleaved and src.width >= 8 and eight_per_item(rt):
            rt.launch_named("highlights", "hl_clamp8", -(-src.width // 8), src.height, dict(args, dst=dst),
                            defines, srgb_source(rt), exact=False)
        else:
            rt.launch_named("highlights", "hl_clamp", src.width, src.height, dict(args, dst=dst), defines,
                            srgb_source(rt))
        dst.interleaved = t.interleaved
        return dst
