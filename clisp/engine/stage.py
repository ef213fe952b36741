"""The stage contract shared by every processing step.

A stage maps an input window to an output window that is smaller by ``halo`` pixels on every
side (and, for a stage of ``downscale`` > 1, the half-size binning, on a grid ``downscale`` times coarser).
It has two faces with the same meaning:

* ``reference(x, origin)``: NumPy, float64-capable, the definition of correct. Raw stages take and
  return H x W mosaics; RGB stages take and return H x W x 3.
* ``enqueue(rt, src, origin) -> DeviceImage``: the OpenCL kernel(s); images are planar on the device
  (C planes of H x W float32), so every read along x is coalesced.

``origin`` is the image coordinate of the input window's pixel (0, 0). It may be negative near the
image edge: the tiler pads the raw input once (CFA-preserving mirror, see tiling.py), so a stage
never special-cases borders and tiled output equals whole-image output. The image and its edges
belong to the planner: it passes each window's ``origin`` as an :class:`Origin`, which also carries
the whole image's (H, W), so a stage whose rule at the image's edges differs from the mirror
padding (the flat demosaic's point-reflected cells) reads them there; no stage is built with them.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from typing import Any, ClassVar

import numpy as np

from .runtime import DeviceImage, Runtime


class Origin(tuple):
    """A window's origin: the image coordinate (y, x) of its pixel (0, 0), used as a plain 2-tuple,
    and ``image``, the whole image's (H, W) as the planner knows it (None for a bare window, e.g. a
    stage run by hand or the noise calibration's fields: no image edges).

    >>> o = Origin(-8, 16, image=(100, 200))
    >>> y, x = o
    >>> (y, x, o.image, advance(o, 2), advance(o, 2).image)
    (-8, 16, (100, 200), (-6, 18), (100, 200))
    """

    image: tuple[int, int] | None

    def __new__(cls, y: int, x: int, image: tuple[int, int] | None = None) -> "Origin":
        origin = super().__new__(cls, (int(y), int(x)))
        origin.image = None if image is None else (int(image[0]), int(image[1]))
        return origin


def advance(origin: tuple[int, int], halo: int, downscale: int = 1) -> tuple[int, int]:
    """The origin of a stage's output window: ``origin`` moved in by ``halo`` on both axes, keeping
    the image an :class:`Origin` carries; for a stage of ``downscale`` > 1 (input pixels per output
    pixel, :attr:`Stage.downscale`) divided by it, in the output's grid, whose image is the input's
    divided by ``downscale`` and rounded up. The planner keeps ``origin + halo`` a multiple of ``downscale``.

    >>> o = advance(Origin(-3, 5, image=(9, 20)), 1, downscale=2)
    >>> (o, o.image)
    ((-1, 3), (5, 10))
    """
    y, x = origin[0] + halo, origin[1] + halo
    image = image_extent(origin)
    s = downscale
    if s == 1:
        return Origin(y, x, image)
    if y % s or x % s:
        raise ValueError(f"origin {tuple(origin)} + halo {halo} is not on the grid of downscale {s}")
    return Origin(y // s, x // s, None if image is None else (-(-image[0] // s), -(-image[1] // s)))


def image_extent(origin: tuple[int, int]) -> tuple[int, int] | None:
    """The whole image's (H, W) that ``origin`` carries (an :class:`Origin` from the planner), else None."""
    return origin.image if isinstance(origin, Origin) else None


class Stage(ABC):
    """One configured processing step. Subclasses are small dataclasses of parameters."""

    name: ClassVar[str] = "stage"
    in_channels: ClassVar[int] = 3
    out_channels: ClassVar[int] = 3

    @property
    def out_dtype(self) -> np.dtype:
        """Element type of the stage's output: float32, or uint16 for a stage that ends in 16-bit
        codes (ToneCurve(quantize=True))."""
        return np.dtype(np.float32)

    @property
    def halo(self) -> int:
        """Pixels of input needed on each side of an output pixel."""
        return 0

    @property
    def downscale(self) -> int:
        """Input pixels per output pixel along each axis: 1 for every stage that keeps the pixel
        grid; 2 for the half-size binning (clisp.modules.half_size). Its ``halo`` is in input
        pixels; output pixel (i, j) stands for the input's ``downscale`` x ``downscale`` block at
        (halo + downscale i, halo + downscale j) of its window (see :func:`advance`)."""
        return 1

    @property
    def align(self) -> int:
        """Tile origins must be multiples of this (px). The planner always also aligns to the CFA
        period, so 1 means "the CFA period"; a multi-resolution stage (e.g. a 2x pyramid over a
        4x4 CFA) declares 8."""
        return 1

    @property
    def bytes_per_pixel(self) -> float:
        """Device bytes this stage keeps per pixel of its input window: its output and every
        intermediate buffer (they stay in the runtime's pool). Used by the tile planner only.
        The default, four float32 images as wide as the stage's widest side, is conservative for
        single-kernel stages; stages with more intermediates override it."""
        return 16.0 * max(self.in_channels, self.out_channels)

    @abstractmethod
    def reference(self, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
        """NumPy reference on an input window; returns the window shrunk by ``halo`` on every side
        (and divided by ``downscale``: :meth:`output_shape`)."""

    writes_into = False
    """Whether :meth:`enqueue` takes ``out=``, an interleaved image of exactly its output shape to
    write (Runtime.host_image: the host's own band buffer), instead of acquiring one."""

    interleaved = False
    """Whether the stage's output is pixel-interleaved (H x W x C on the device) rather than planar;
    stages that can do both have it as a field."""

    cfa_kinds: ClassVar[tuple[str, ...] | None] = None
    """The CFA layouts ('lms', 'bayer': clisp.cfa ``CFA.layout``) a demosaic serves; None: any. lms-bayer
    has the 'bayer' layout."""

    @classmethod
    def for_raw(cls, raw: Any) -> "Stage":
        """The stage configured for ``raw`` (a clisp.io.rawimage.RawImage), as the pipeline builds a
        demosaic: from the raw's CFA. Stages that adapt to the raw (its noise, its colour matrix)
        override it."""
        return cls(raw.cfa)  # type: ignore[call-arg]

    @abstractmethod
    def enqueue(self, rt: Runtime, src: DeviceImage, origin: tuple[int, int]) -> DeviceImage:
        """Enqueue the kernel on ``src``; returns a new pooled device image (``src`` is not released)."""

    def fuse(self, following: "Stage") -> "Stage | None":
        """One stage equal to ``following`` applied after this one, or None when they do not fuse.

        Fusion is a schedule choice for the OpenCL path; the reference always runs stage by stage.
        """
        return None

    def with_interleaved_output(self) -> "Stage | None":
        """This stage writing H x W x C (the host layout) instead of planes, if it can; as the
        last stage of a tile that saves a separate interleave pass. None when it cannot."""
        return None

    def output_shape(self, height: int, width: int) -> tuple[int, int]:
        """Output window size for an input window of ``height x width``: less ``halo`` on every
        side, divided by ``downscale``."""
        return (height - 2 * self.halo) // self.downscale, (width - 2 * self.halo) // self.downscale


def fuse_stages(stages: list[Stage]) -> list[Stage]:
    """Greedily fuse neighbouring stages (see :meth:`Stage.fuse`)."""
    fused: list[Stage] = []
    for stage in stages:
        merged = fused[-1].fuse(stage) if fused else None
        if merged is None:
            fused.append(stage)
        else:
            fused[-1] = merged
    return fused


def as_f32(values: np.ndarray) -> np.ndarray:
    """Contiguous float32 copy of small host constants for kernel arguments."""
    return np.ascontiguousarray(values, dtype=np.float32)
