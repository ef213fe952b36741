"""Flat-tile demosaic: wide per-channel means plus the local luminance residual (issue 13).

On a tile whose luminance and chroma show no detail above the noise (clisp.scene.block_analysis: a sky, a
wall), the guided demosaic and the 3-level chroma denoiser end up doing the same thing: the
luminance keeps its fine, noise-level texture (the guided demosaic's flat-field target) and the
chroma becomes a wide local mean. This stage computes that directly, in four short kernels, and
replaces demosaic + chroma denoiser on such tiles (clisp.pipeline.skip's ``flat`` path)::

    cell_c(i, j)  = mean of channel c's samples in cell (i, j)          S x S cells on image multiples of S
    box_c(i, j)   = mean of cell_c over the (2 Rc + 1)^2 cells around (i, j)
    mean_c(p)     = bilinear interpolation of box_c at p (cell i's value sits at the centroid of
                    channel c's sites in it)
    d(p)          = sum_{q in 3 x 3 around p, c(q) in detail} k(q - p) (x(q) - mean_{c(q)}(p)) / sum k
    out_c(p)      = mean_c(p) + d(p)

x is the white-balanced, normalised mosaic (H x W, white ~ 1), c(q) the CFA channel of q, P the CFA
period, S = CELL_PX (a multiple of P), Rc the box radius in cells (``cells``; RADIUS_PX / S). Means are taken on the cell
grid, so the wide window costs a few operations per pixel, and a linear gradient is reproduced
exactly (box means and bilinear interpolation are both exact on linear functions). k: 4 at the
centre, ``axial`` on the 4 axial and ``diagonal`` on the 4 diagonal neighbours; ``detail`` = the
channels that carry luminance (LMS: L and M, not the sparse S, as the guided demosaic's Y; Bayer:
all three). d is added to every channel, so the fine texture is neutral. The weights are chosen
per CFA so that the grain matches the full path's on flat fields (AXIAL; flat / full luminance
error variance on a 12 MP sky: LMS 0.89-0.91 with axial 2, Bayer 0.68-0.70 with 0.5; README.md).

Input: the white-balanced mosaic window (H x W, float32); output: the camera channels
(H - 2 halo) x (W - 2 halo) x n_channels, halo = (Rc + 2) S. Chroma noise left: the mean of about
n_c (S / P)^2 (2 Rc + 1)^2 samples. On a linear gradient the output is exact for Bayer; for LMS the
residual's support (no S sites) is not symmetric everywhere, an error of 0.2 px times the gradient.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...cfa import CFA
from ...errors import ClispError
from ...engine.runtime import DeviceImage, Runtime, launch_exact
from ...engine.stage import Stage, as_f32, image_extent
from ..common.box import enqueue_box

PLUS_CENTRE = 4.0
"""Centre weight of the 3 x 3 luminance-residual kernel."""

AXIAL = {"lms": 2.0, "bayer": 0.5}
"""Axial weight of the residual kernel per CFA layout (clisp.cfa: the flat path stands in for the layout's
demosaic, so lms-bayer takes Bayer's; module doc: matches the full path's grain); other layouts 1."""

RADIUS_PX = 24
"""Half side of the mean window in pixels; ``cells`` = round(RADIUS_PX / CELL_PX)."""

CELL_PX = 4
"""Side S of the cells the means are taken on, px (a multiple of the CFA period: 2 or 4)."""


def detail_channels(cfa: CFA) -> np.ndarray:
    """(n_channels,) 1 for the channels whose samples enter the luminance residual d, else 0: all but
    the sparse channel 2 (S, on 1/8 of the pixels) of the LMS layout; every channel of the others
    (lms-bayer's S is as dense as Bayer's B)."""
    mask = np.ones(cfa.n_channels, dtype=np.int32)
    if cfa.layout == "lms":
        mask[2] = 0
    return mask


ANCHOR = 2
"""Cells past the image's edges are point-reflected about the mean of the 2 ANCHOR + 1 edge cells
(not the edge cell alone, whose noise the reflection would double in every reflected cell)."""


def anchor(first: int, last: int) -> int:
    """K: the reflection anchors average 2K + 1 cells (ANCHOR, fewer on a narrow grid)."""
    return max(0, min(ANCHOR, (last - first) // 2))


def reflect_terms(i: int, first: int, last: int) -> list[tuple[int, float]]:
    """f'(i) = sum weight f(index) over the returned terms: f(i) for first <= i <= last, else the
    point reflection 2 mean(f(c - K .. c + K)) - f(2 c - i) about c = first + K (or last - K), the
    index 2 c - i clamped to first .. last (reached only by windows narrower than min_inside_px)."""
    if first <= i <= last:
        return [(i, 1.0)]
    k = anchor(first, last)
    c = first + k if i < first else last - k
    mirror = min(max(2 * c - i, first), last)       # clamped: a narrow window holds no cell beyond
    return [(c + d, 2.0 / (2 * k + 1)) for d in range(-k, k + 1)] + [(mirror, -1.0)]


def reflect_cells(cells: np.ndarray, i0: int, i1: int, j0: int, j1: int) -> np.ndarray:
    """(n, cy, cx) cell means with the cells outside rows i0..i1 / columns j0..j1 (past the image's
    edges) replaced by point reflections (:func:`reflect_terms`), separably along y and x: linear
    functions are continued exactly, so box means near the image's edges are not biased by the
    tiler's mirror padding (which would shift a gradient's mean by up to R / 2 px times the
    gradient)."""
    n, cy, cx = cells.shape
    out = np.empty_like(cells)
    for i in range(cy):
        for j in range(cx):
            out[:, i, j] = sum(wy * wx * cells[:, iy, jx] for iy, wy in reflect_terms(i, i0, i1)
                               for jx, wx in reflect_terms(j, j0, j1))
    return out


@dataclass
class DemosaicFlat(Stage):
    """H x W white-balanced mosaic -> (H - 2 halo) x (W - 2 halo) x n_channels camera image for
    tiles without detail (module doc). ``cells``: box radius Rc in cells (0: RADIUS_PX / CELL_PX);
    ``axial``: weight of the axial neighbours in d (negative: AXIAL of the CFA layout);
    Cells past the image's edges are point-reflected (:func:`reflect_cells`) instead of read from
    the tiler's mirror padding: the image's (H, W) comes with each window's origin
    (:class:`clisp.engine.stage.Origin`, from the planner); a bare (y, x) origin means no edges."""

    cfa: CFA
    cells: int = 0
    axial: float = -1.0
    diagonal: float = 0.0
    unread: np.ndarray | None = field(default=None, compare=False)
    """Optional (rows, cols) bool per ``block`` x ``block`` px block of the image (multiples of
    ``block``): blocks whose output nobody reads (a mixed tile's texture blocks, where the detail
    path's output replaces this one: clisp.pipeline.skip). Their pixels are written 0, not computed."""
    block: int = 64
    name = "demosaic_flat"
    in_channels = 1
    out_channels = 3

    def __post_init__(self) -> None:
        if CELL_PX % self.cfa.period:
            raise ClispError(f"flat demosaic cells of {CELL_PX} px do not fit the CFA period {self.cfa.period}")
        if self.cells <= 0:
            self.cells = max(1, round(RADIUS_PX / CELL_PX))
        if self.axial < 0:
            self.axial = AXIAL.get(self.cfa.layout, 1.0)
        if self.cfa.n_channels != 3:
            raise ClispError(f"the flat demosaic writes 3 channels; {self.cfa.name} has {self.cfa.n_channels}")

    @property
    def halo(self) -> int:
        return (self.cells + 2) * CELL_PX

    @property
    def min_inside_px(self) -> int:
        """Pixels of image a window must hold along an axis where it meets the image's edge, so
        that the point reflection of every cell an output inside the image reads stays within the
        window's cells inside the image: 2 ANCHOR + Rc + 2 whole cells, plus one for the cell grid's
        alignment. Windows narrower than this get clamped reflections (the skip planner does not
        send such tiles to the flat path)."""
        return (2 * ANCHOR + self.cells + 3) * CELL_PX

    @property
    def cell_pattern(self) -> np.ndarray:
        """(S, S) channel of each pixel of a cell (the CFA pattern tiled)."""
        reps = CELL_PX // self.cfa.period
        return np.tile(self.cfa.pattern, (reps, reps))

    @property
    def counts(self) -> np.ndarray:
        """(n_channels,) sites of each channel in one cell."""
        return np.bincount(self.cell_pattern.ravel(), minlength=self.cfa.n_channels).astype(np.float64)

    @property
    def centroids(self) -> np.ndarray:
        """(n_channels, 2) mean (row, column) offset of each channel's sites within a cell, px: the
        point of the cell a channel's cell mean belongs to."""
        sites = [np.argwhere(self.cell_pattern == c).mean(axis=0) for c in range(self.cfa.n_channels)]
        return np.asarray(sites, dtype=np.float64)

    @property
    def bytes_per_pixel(self) -> float:
        return 4.0 * (1 + self.cfa.n_channels)              # window and output; cell grids are small

    def grid(self, h: int, w: int, origin: tuple[int, int]) -> tuple[int, int, int, int]:
        """(ay, ax, cy, cx): window offset of the first whole cell and the number of cells."""
        ay, ax = (-origin[0]) % CELL_PX, (-origin[1]) % CELL_PX
        return ay, ax, (h - ay) // CELL_PX, (w - ax) // CELL_PX

    def inside(self, h: int, w: int, origin: tuple[int, int]) -> tuple[int, int, int, int]:
        """(i0, i1, j0, j1): the first and last cell rows and columns of the window's cell grid that
        lie wholly inside the image (the whole grid where ``origin`` carries no image)."""
        ay, ax, cy, cx = self.grid(h, w, origin)
        image = image_extent(origin)
        if image is None:
            return 0, cy - 1, 0, cx - 1
        (ih, iw), s = image, CELL_PX
        i0, j0 = max(0, -(-(-origin[0] - ay) // s)), max(0, -(-(-origin[1] - ax) // s))
        i1 = min(cy, (ih - origin[0] - ay) // s) - 1
        j1 = min(cx, (iw - origin[1] - ax) // s) - 1
        if i1 < i0 or j1 < j0:
            raise ClispError("flat demosaic: a window without one whole cell inside the image")
        return i0, i1, j0, j1

    def taps(self) -> list[tuple[int, int, float]]:
        """(dy, dx, weight) of the 3 x 3 luminance-residual kernel, row-major."""
        return [(dy, dx, PLUS_CENTRE if dy == dx == 0 else (self.axial if dy == 0 or dx == 0 else self.diagonal))
                for dy in (-1, 0, 1) for dx in (-1, 0, 1)]

    def residual_tables(self) -> tuple[np.ndarray, np.ndarray]:
        """Per CFA phase (P * P rows): a (9,) the residual's normalised tap weights k detail / K and
        b (n_channels,) the weight of each channel's mean, so that d = a . x(3 x 3) - b . mean."""
        p, n = self.cfa.period, self.cfa.n_channels
        use = detail_channels(self.cfa)
        a = np.zeros((p * p, 9))
        b = np.zeros((p * p, n))
        for py in range(p):
            for px in range(p):
                for t, (dy, dx, k) in enumerate(self.taps()):
                    c = int(self.cfa.pattern[(py + dy) % p, (px + dx) % p])
                    a[py * p + px, t] = k * use[c]
                    b[py * p + px, c] += k * use[c]
                total = a[py * p + px].sum()
                a[py * p + px] /= total
                b[py * p + px] /= total
        return a, b

    def reference(self, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
        h, w = x.shape
        s, rc, hb, n = CELL_PX, self.cells, self.halo, self.cfa.n_channels
        ay, ax, cy, cx = self.grid(h, w, origin)
        channel = self.cfa.channel_map(h, w, origin)
        x = x.astype(np.float64)
        cells = np.zeros((n, cy, cx))
        for py in range(s):
            for px in range(s):
                c = int(channel[ay + py, ax + px])
                cells[c] += x[ay + py:ay + py + cy * s:s, ax + px:ax + px + cx * s:s]
        cells /= self.counts[:, None, None]
        cells = reflect_cells(cells, *self.inside(h, w, origin))
        k = 2 * rc + 1
        rows = sum(cells[:, :, j:cx - 2 * rc + j] for j in range(k))
        box = sum(rows[:, i:cy - 2 * rc + i] for i in range(k)) / (k * k)   # box cell i = cell i + rc
        oh, ow = h - 2 * hb, w - 2 * hb
        means = np.empty((n, oh, ow))
        for c in range(n):
            uy = (np.arange(oh) + hb - ay - self.centroids[c, 0]) / s - rc
            ux = (np.arange(ow) + hb - ax - self.centroids[c, 1]) / s - rc
            iy, ix = np.floor(uy).astype(int), np.floor(ux).astype(int)
            fy, fx = (uy - iy)[:, None], (ux - ix)[None, :]
            b = box[c]
            means[c] = ((1 - fy) * ((1 - fx) * b[iy][:, ix] + fx * b[iy][:, ix + 1])
                        + fy * ((1 - fx) * b[iy + 1][:, ix] + fx * b[iy + 1][:, ix + 1]))
        use = detail_channels(self.cfa)
        num = np.zeros((oh, ow))
        den = np.zeros((oh, ow))
        for dy, dx, kw in self.taps():
            ch = channel[hb + dy:hb + dy + oh, hb + dx:hb + dx + ow]
            xv = x[hb + dy:hb + dy + oh, hb + dx:hb + dx + ow]
            m = np.take_along_axis(means, ch[None].astype(np.intp), axis=0)[0]
            kk = kw * use[ch]
            num += kk * (xv - m)
            den += kk
        out = np.moveaxis(means, 0, -1) + (num / den)[..., None]
        out[self.unread_pixels(origin[0] + hb, origin[1] + hb, oh, ow)] = 0.0
        return out

    def unread_pixels(self, y0: int, x0: int, h: int, w: int) -> np.ndarray:
        """(h, w) bool: the pixels of the image region at (y0, x0) in an :attr:`unread` block."""
        if self.unread is None:
            return np.zeros((h, w), dtype=bool)
        by = np.arange(y0, y0 + h) // self.block
        bx = np.arange(x0, x0 + w) // self.block
        rows, cols = self.unread.shape
        inside = ((by >= 0) & (by < rows))[:, None] & ((bx >= 0) & (bx < cols))[None, :]
        return inside & self.unread[np.clip(by, 0, rows - 1)][:, np.clip(bx, 0, cols - 1)]

    def defines(self) -> dict[str, object]:
        return {"CFA_PERIOD": self.cfa.period, "CELL": CELL_PX, "CELLS": self.cells, "NCH": self.cfa.n_channels}

    def enqueue(self, rt: Runtime, src: DeviceImage, origin: tuple[int, int]) -> DeviceImage:
        if np.dtype(src.dtype) != np.float32:
            raise ClispError("the flat demosaic reads the white-balanced float32 mosaic")
        rc, hb, n = self.cells, self.halo, self.cfa.n_channels
        i32 = np.int32
        ay, ax, cy, cx = self.grid(src.height, src.width, origin)
        defines = self.defines()
        cells = rt.acquire(n, cy, cx)
        launch_exact(rt, rt.kernel("demosaic_flat", "flat_cells", defines), cx, cy, src.buffer, cells.buffer,
                     i32(src.width), i32(ay), i32(ax), i32(cx), i32(cy),
                     rt.constant(np.ascontiguousarray(self.cell_pattern, dtype=np.int8)),
                     rt.constant(as_f32(1.0 / self.counts)))
        i0, i1, j0, j1 = self.inside(src.height, src.width, origin)
        if (i0, i1, j0, j1) != (0, cy - 1, 0, cx - 1):
            mirrored = rt.acquire(n, cy, cx)
            launch_exact(rt, rt.kernel("demosaic_flat", "flat_reflect", defines), cx, cy, cells.buffer, mirrored.buffer,
                         i32(cx), i32(cy), i32(i0), i32(i1), i32(j0), i32(j1), i32(anchor(i0, i1)),
                         i32(anchor(j0, j1)))
            rt.release(cells)
            cells = mirrored
        bw, bh = cx - 2 * rc, cy - 2 * rc
        box_count = np.float32(2 * rc + 1) ** 2
        box = enqueue_box(rt, cells, rc, rc, scale=np.float32(1.0) / box_count, release_src=True)
        oh, ow = src.height - 2 * hb, src.width - 2 * hb
        centroid = rt.constant(as_f32(self.centroids))
        rows = rt.acquire(n, oh, bw)
        rt.launch_named("demosaic_flat", "flat_rows", bw, oh, dict(
            box=box, rows=rows, bw=bw, bh=bh, oh=oh, halo=hb, ay=ay, centroid=centroid), defines)
        rt.release(box)
        dst = rt.acquire(n, oh, ow)
        a, b = self.residual_tables()
        unread = self.unread if self.unread is not None else np.zeros((1, 1), dtype=bool)
        rt.launch_named("demosaic_flat", "flat_output", -(-ow // CELL_PX), oh, dict(
            src=src, rows=rows, dst=dst, width=src.width, bw=bw, ow=ow, oh=oh, halo=hb, ax=ax,
            oy=origin[0], ox=origin[1], a=rt.constant(as_f32(a)), b=rt.constant(as_f32(b)),
            centroid=centroid, unread=rt.constant(unread.astype(np.uint8)), unread_w=unread.shape[1],
            unread_h=unread.shape[0] if self.unread is not None else 0, block=self.block), defines)
        rt.release(rows)
        return dst
