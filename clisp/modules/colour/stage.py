"""Per-pixel colour steps on 3-channel images (kernels in ``colour.cl``, halo 0).

ColourMatrix: white-balanced camera channels -> linear sRGB. WhiteBalance2: von Kries gains on
linear sRGB (colour constancy, docs/model.md section 4), a diagonal matrix through the same kernel.
ToneCurve: clip to [0, 1] and sRGB-encode (by polynomial, clisp/modules/colour/srgb.h), optionally to 16-bit codes,
for integer outputs.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ...sim.colorimetry import SRGB_ENCODING, quantize8, quantize16, srgb_encode, srgb_poly_defines
from ...engine.runtime import DeviceImage, Runtime, launch_exact
from ...engine.stage import Stage, as_f32


@dataclass
class ColourMatrix(Stage):
    """out[..., i] = sum_j matrix[i, j] * in[..., j]; H x W x 3 -> H x W x 3, linear."""

    matrix: np.ndarray
    name = "colour_matrix"

    def reference(self, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
        return np.einsum("ij,hwj->hwi", np.asarray(self.matrix, dtype=np.float64), x.astype(np.float64))

    def fuse(self, following: Stage) -> Stage | None:
        if isinstance(following, ColourMatrix):
            return ColourMatrix(np.asarray(following.matrix) @ np.asarray(self.matrix))
        return None

    def enqueue(self, rt: Runtime, src: DeviceImage, origin: tuple[int, int]) -> DeviceImage:
        kernel = rt.kernel("colour", "apply_matrix3", SRGB_ENCODING)
        dst = rt.acquire(3, src.height, src.width)
        launch_exact(rt, kernel, src.width, src.height, src.buffer, dst.buffer, np.int32(src.width),
                  np.int32(src.height), rt.constant(as_f32(self.matrix)))
        return dst


class WhiteBalance2(ColourMatrix):
    """White balance pass 2: diagonal gains on linear sRGB."""

    name = "white_balance2"

    def __init__(self, gains: np.ndarray) -> None:
        super().__init__(np.diag(np.asarray(gains, dtype=np.float64)))


def camera_neutral(colour_matrix: np.ndarray, target: np.ndarray | None = None) -> np.ndarray | None:
    """The white-balanced camera values (3,) that ``colour_matrix`` (3 x 3, camera to linear sRGB)
    takes to ``target`` (default (1, 1, 1): grey); None where the matrix is singular or the answer
    is not positive and finite.

    >>> camera_neutral(np.diag([2.0, 1.0, 0.5])).tolist()
    [0.5, 1.0, 2.0]
    """
    try:
        n = np.linalg.solve(np.asarray(colour_matrix, dtype=np.float64), np.ones(3) if target is None else target)
    except np.linalg.LinAlgError:
        return None
    return n if np.all(np.isfinite(n)) and np.all(n > 0) else None


def srgb_source(rt: Runtime) -> str:
    """Program text that defines ``encode_srgb`` and ``quantize16`` (the polynomial's constants, then
    clisp/modules/colour/srgb.h); pass as ``generated`` to :meth:`Runtime.kernel`. Made once per
    process (it read the header on every tile)."""
    global _SRGB_SOURCE
    if _SRGB_SOURCE is None:
        constants = [f"#define {key} {value!r}f" for key, value in srgb_poly_defines().items()]
        _SRGB_SOURCE = "\n".join(constants + [rt.header("srgb.h")])
    return _SRGB_SOURCE


_SRGB_SOURCE: str | None = None


@dataclass
class ToneCurve(Stage):
    """Linear sRGB -> sRGB-encoded in [0, 1] (clip, then IEC 61966-2-1); H x W x 3.

    ``quantize``: output codes of ``bits`` (16: uint16, for TIFF/PNG; 8: uint8, for JPEG) instead
    of float32, so the device downloads the file's own bytes and the writer converts nothing.
    ``interleaved``: write H x W x 3 (the host layout; set by the pipeline when this is the last
    stage)."""

    quantize: bool = False
    interleaved: bool = False
    bits: int = 16
    name = "tone_curve"
    writes_into = True

    def __post_init__(self) -> None:
        if self.bits not in (8, 16):
            raise ValueError(f"ToneCurve codes have 8 or 16 bits, not {self.bits}")

    @property
    def out_dtype(self) -> np.dtype:
        if not self.quantize:
            return np.dtype(np.float32)
        return np.dtype(np.uint8 if self.bits == 8 else np.uint16)

    def reference(self, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
        encoded = srgb_encode(x.astype(np.float64))
        if not self.quantize:
            return encoded
        return quantize8(encoded) if self.bits == 8 else quantize16(encoded)

    def with_interleaved_output(self) -> "ToneCurve":
        return replace(self, interleaved=True)

    def enqueue(self, rt: Runtime, src: DeviceImage, origin: tuple[int, int],
                out: DeviceImage | None = None) -> DeviceImage:
        defines = {**SRGB_ENCODING, "QUANTIZE": int(self.quantize), "CODE_BITS": self.bits,
                   "INTERLEAVED": int(self.interleaved)}
        dst = out if out is not None else rt.acquire(3, src.height, src.width, self.out_dtype)
        if self.interleaved and src.width >= 8 and eight_per_item(rt):
            kernel = rt.kernel("colour", "srgb_encode8", defines, srgb_source(rt))
            rt.launch(kernel, -(-src.width // 8), src.height, src.buffer, dst.buffer, src.width, src.height)
        else:
            kernel = rt.kernel("colour", "srgb_encode", defines, srgb_source(rt))
            launch_exact(rt, kernel, src.width, src.height, src.buffer, dst.buffer, src.width, src.height)
        dst.interleaved = self.interleaved
        return dst


def eight_per_item(rt: Runtime) -> bool:
    """Whether the interleaved tone curve takes eight pixels per work-item (kernel srgb_encode8): on
    CPU devices, where PoCL scatters a scalar kernel's interleaved stores (24 MP to 16-bit codes:
    177 MP/s scalar; README.md); GPUs keep one pixel per lane (coalesced by the hardware)."""
    return bool(rt.device.type & rt.cl.device_type.CPU)


def tone_curve_for(output: str, interleaved: bool = False) -> ToneCurve | None:
    """The ToneCurve that ends a pipeline of ``output`` ('linear': none; 'srgb': encoded float32;
    'srgb16' / 'srgb8': 16- or 8-bit codes).

    >>> tone_curve_for("srgb8").out_dtype, tone_curve_for("linear")
    (dtype('uint8'), None)
    """
    if output == "linear":
        return None
    return ToneCurve(quantize=output in ("srgb16", "srgb8"), interleaved=interleaved,
                     bits=8 if output == "srgb8" else 16)
