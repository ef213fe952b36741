"""Block blend: the detail path's output joined to the flat path's inside one tile (issue 30).

clisp.pipeline.skip lets a tile take two paths at the granularity of the scene analysis's blocks: the flat
path (DemosaicFlat and the plain colour matrix) over the whole tile, the detail path (the preset's
demosaic and chroma denoiser) only on rectangles around the blocks with texture. This module
decides, per pixel, how much of each the output is, and joins them.

Rule. T = the texture blocks (``mask``: ``block`` x ``block`` px on image multiples of ``block``;
a block has texture when the analysis sees detail, chroma or clipping above the noise), d(p) the
Chebyshev distance in px from pixel p to the nearest texture block (0 inside one):

    w(p) = clamp((reach + ramp - d(p)) / ramp, 0, 1),    out(p) = flat(p) + w(p) (detail(p) - flat(p))

``reach`` is the flat path's halo: the flat path's output at p reads the raw within ``reach`` of p,
so it is used (w < 1) only where no texture lies within its reach, and there it is as good as the
detail path (clisp.pipeline.skip.FLAT_LOSES_TO). ``ramp``: the width of the cross-fade, so the two paths'
different grain meets without a step. Exact where the weight is 0 or 1 (the kernel selects, it does
not mix). The detail path must run wherever w > 0: on the texture blocks dilated by
:attr:`BlockBlend.reach_blocks` blocks (:meth:`BlockBlend.support`).

Example: one texture block at block (0, 1) of 64 px, reach 32, ramp 32: pixel (0, 63) is 1 px
from it (w = 1), pixel (0, 20) is 44 px away (w = 0.625), pixel (0, 0) 64 px (w = 0).

>>> b = BlockBlend(np.array([[False, True, False]]), block=64, reach=32, ramp=32)
>>> b.weight(0, 0, 1, 64)[0, [63, 20, 0]].tolist()
[1.0, 0.625, 0.0]
>>> b.support().astype(int).tolist()
[[1, 1, 1]]
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...engine.runtime import DeviceImage, Runtime


@dataclass(frozen=True, eq=False)
class BlockBlend:
    """The texture mask of one image and the cross-fade's geometry (px)."""

    mask: np.ndarray
    block: int
    reach: int
    ramp: int

    @property
    def reach_blocks(self) -> int:
        """Blocks around a pixel's own in which a texture block can give it w > 0."""
        return -(-(self.reach + self.ramp) // self.block)

    def support(self) -> np.ndarray:
        """Blocks where w may be > 0 (bool, the mask's shape): the mask dilated by
        :attr:`reach_blocks` blocks along both axes (a square)."""
        k = self.reach_blocks
        rows, cols = self.mask.shape
        padded = np.zeros((rows + 2 * k, cols + 2 * k), dtype=bool)
        padded[k:k + rows, k:k + cols] = self.mask
        out = np.zeros_like(self.mask, dtype=bool)
        for dy in range(2 * k + 1):
            for dx in range(2 * k + 1):
                out |= padded[dy:dy + rows, dx:dx + cols]
        return out

    def weight(self, y0: int, x0: int, h: int, w: int) -> np.ndarray:
        """w(p) (float64, h x w) on the image region at (y0, x0): the reference of the kernel's weight."""
        gy = np.arange(y0, y0 + h)[:, None]
        gx = np.arange(x0, x0 + w)[None, :]
        b, k = self.block, self.reach_blocks
        rows, cols = self.mask.shape
        d = np.full((h, w), float(self.reach + self.ramp))
        for oy in range(-k, k + 1):
            by = gy // b + oy
            dy = np.maximum(np.maximum(by * b - gy, gy - (by * b + b - 1)), 0)
            for ox in range(-k, k + 1):
                bx = gx // b + ox
                dx = np.maximum(np.maximum(bx * b - gx, gx - (bx * b + b - 1)), 0)
                inside = (by >= 0) & (by < rows) & (bx >= 0) & (bx < cols)
                hit = inside & self.mask[np.clip(by, 0, rows - 1), np.clip(bx, 0, cols - 1)]
                d = np.where(hit, np.minimum(d, np.maximum(dy, dx)), d)
        return np.clip((self.reach + self.ramp - d) / self.ramp, 0.0, 1.0)

    def reference(self, flat: np.ndarray, detail: np.ndarray, off: tuple[int, int], at: tuple[int, int]) -> None:
        """Join in place: ``flat`` (the tile, h x w x 3) takes ``detail`` (a rectangle, h' x w' x 3,
        whose pixel (0, 0) is the tile's ``off`` and the image's ``at``) by the weights."""
        h, w = detail.shape[:2]
        wt = self.weight(at[0], at[1], h, w)[..., None]
        region = flat[off[0]:off[0] + h, off[1]:off[1] + w]
        region[...] = np.where(wt >= 1.0, detail, np.where(wt <= 0.0, region, region + wt * (detail - region)))

    def enqueue(self, rt: Runtime, flat: DeviceImage, detail: DeviceImage, off: tuple[int, int],
                at: tuple[int, int]) -> None:
        """The kernel of :meth:`reference` on planar device images (3 planes each; ``flat`` written
        in place)."""
        rows, cols = self.mask.shape
        rt.launch_named("block_blend", "blend_detail", detail.width, detail.height, dict(
            flat=flat, detail=detail, mask=rt.constant(self.mask.astype(np.uint8)), tile_w=flat.width,
            tile_h=flat.height, out_w=detail.width, out_h=detail.height, off_y=off[0], off_x=off[1],
            rect_y=at[0], rect_x=at[1], mask_w=cols, mask_h=rows, block=self.block,
            reach_blocks=self.reach_blocks, reach=self.reach, ramp=self.ramp), exact=False)  # in place: once each


def rectangles(support: np.ndarray, halo: int, block: int, tile: tuple[int, int, int, int],
               image: tuple[int, int]) -> list[tuple[int, int, int, int]]:
    """Rectangles (y0, x0, h, w: image px, inside ``tile``) that cover the tile's ``support``
    blocks, chosen to cost little: the bounding box of the support is cut along an empty row or
    column of blocks wherever the two parts' windows ((h + 2 halo) (w + 2 halo) px each) cost less
    than the whole's, recursively (a guillotine cut). Empty when the tile holds no support.

    >>> s = np.zeros((4, 8), dtype=bool); s[0, 0] = s[3, 7] = True
    >>> rectangles(s, 10, 64, (0, 0, 256, 512), (256, 512))
    [(0, 0, 64, 64), (192, 448, 64, 64)]
    """
    ty, tx, th, tw = tile
    r0, r1 = ty // block, min(support.shape[0], -(-(ty + th) // block))
    c0, c1 = tx // block, min(support.shape[1], -(-(tx + tw) // block))
    out: list[tuple[int, int, int, int]] = []

    def to_px(a: int, b: int, c: int, d: int) -> tuple[int, int, int, int]:
        y0, y1 = max(ty, a * block), min(ty + th, b * block, image[0])
        x0, x1 = max(tx, c * block), min(tx + tw, d * block, image[1])
        return y0, x0, y1 - y0, x1 - x0

    def cost(a: int, b: int, c: int, d: int) -> int:
        _, _, h, w = to_px(a, b, c, d)
        return (h + 2 * halo) * (w + 2 * halo)

    def split(a: int, b: int, c: int, d: int) -> None:
        sub = support[a:b, c:d]
        if not sub.any():
            return
        rows, cols = np.flatnonzero(sub.any(axis=1)), np.flatnonzero(sub.any(axis=0))
        a, b, c, d = a + rows[0], a + rows[-1] + 1, c + cols[0], c + cols[-1] + 1
        best, cut = cost(a, b, c, d), None
        for axis, lo, hi in ((0, a, b), (1, c, d)):
            line = support[a:b, c:d].any(axis=1 - axis)
            for i in range(1, hi - lo):
                if not line[i - 1] or line[i]:
                    continue                                  # cut at the start of an empty run only
                j = i
                while j < hi - lo and not line[j]:
                    j += 1
                parts = ((a, lo + i, c, d), (lo + j, b, c, d)) if axis == 0 else ((a, b, c, lo + i), (a, b, lo + j, d))
                total = sum(cost(*p) for p in parts)
                if total < best:
                    best, cut = total, parts
        if cut is None:
            out.append(to_px(a, b, c, d))
        else:
            for part in cut:
                split(*part)

    split(r0, r1, c0, c1)
    return [tuple(int(v) for v in r) for r in out if r[2] > 0 and r[3] > 0]  # type: ignore[misc]
