"""Per-pixel affine steps on the raw mosaic: black/white normalisation and white balance pass 1.

Both compute ``out = (raw - offset[c]) * scale[c]`` with c the CFA channel of the pixel
(kernel ``raw_scale.cl: cfa_affine``, halo 0).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...cfa import CFA
from ...engine.runtime import DeviceImage, Runtime, launch_exact
from ...engine.stage import Stage, as_f32


@dataclass
class CfaAffine(Stage):
    """``out = (raw - offset[c]) * scale[c]`` per CFA channel c; H x W in, H x W float out."""

    cfa: CFA
    offset: np.ndarray
    scale: np.ndarray
    raw_dtype: np.dtype = field(default_factory=lambda: np.dtype(np.float32))
    name = "raw_scale"          # normalise and WB pass 1 fused (the subclasses name themselves)

    in_channels = 1
    out_channels = 1

    def reference(self, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
        channel = self.cfa.channel_map(x.shape[0], x.shape[1], origin)
        offset = np.asarray(self.offset, dtype=np.float64)[channel]
        scale = np.asarray(self.scale, dtype=np.float64)[channel]
        return (x.astype(np.float64) - offset) * scale

    def fuse(self, following: Stage) -> Stage | None:
        """Two affines compose into one; an affine folds into a following linear demosaic."""
        if isinstance(following, CfaAffine):
            scale = np.asarray(self.scale) * np.asarray(following.scale)
            offset = np.asarray(self.offset) + np.asarray(following.offset) / np.asarray(self.scale)
            return CfaAffine(self.cfa, offset, scale)
        as_filter = getattr(following, "as_phase_filter", None)
        if as_filter is not None:
            return as_filter().after_affine(self.offset, self.scale)
        return None

    def enqueue(self, rt: Runtime, src: DeviceImage, origin: tuple[int, int]) -> DeviceImage:
        raw_t = "ushort" if src.dtype == np.uint16 else "float"
        kernel = rt.kernel("raw_scale", "cfa_affine", {"RAW_T": raw_t, "CFA_PERIOD": self.cfa.period})
        dst = rt.acquire(1, src.height, src.width)
        launch_exact(rt, kernel, src.width, src.height, src.buffer, dst.buffer,
                  np.int32(src.width), np.int32(src.height), np.int32(origin[0]), np.int32(origin[1]),
                  rt.constant(self.cfa.pattern), rt.constant(as_f32(self.offset)),
                  rt.constant(as_f32(self.scale)))
        return dst


def normalize(cfa: CFA, black_level: np.ndarray, white_level: float) -> CfaAffine:
    """Black subtraction and white normalisation: DN -> [0, 1] relative to (white - black[c])."""
    black = np.asarray(black_level, dtype=np.float64)
    stage = Normalize(cfa, black, 1.0 / (float(white_level) - black))
    return stage


def white_balance1(cfa: CFA, gains: np.ndarray) -> CfaAffine:
    """White balance pass 1: per-channel gains on the normalised mosaic (equalises channels for demosaic)."""
    return WhiteBalance1(cfa, np.zeros(cfa.n_channels), np.asarray(gains, dtype=np.float64))


class Normalize(CfaAffine):
    """Black/white normalisation (see :func:`normalize`)."""

    name = "normalize"


class WhiteBalance1(CfaAffine):
    """White balance pass 1 (see :func:`white_balance1`)."""

    name = "white_balance1"
