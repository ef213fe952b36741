"""Colour constants of the paper and the sRGB transfer functions (SPEC.md sections 0 and 2).

All matrices map white-balanced camera values to linear sRGB (D65), column vectors.
"""
from __future__ import annotations

import numpy as np

P_LMS = np.array([[4.73, -3.87, 0.14],
                  [-0.60, 1.75, -0.16],
                  [0.07, -0.26, 1.12]])
"""Paper eq. (1): white-balanced LMS -> linear sRGB."""

B_BAYER = np.array([[1.81, -0.53, -0.28],
                    [-0.30, 1.38, -0.08],
                    [-0.13, -0.33, 1.46]])
"""The paper's typical Bayer matrix: white-balanced camera RGB -> linear sRGB."""

WB_LMS = np.array([1.0000, 1.2191, 3.1397])
"""Paper's LMS white-balance multipliers (applied to raw channels)."""

WB_BAYER = np.array([1.8123, 1.0000, 1.8799])
"""Paper's Bayer white-balance multipliers (applied to raw channels)."""

XYZ_TO_SRGB = np.array([[3.2404542, -1.5371385, -0.4985314],
                        [-0.9692660, 1.8760108, 0.0415560],
                        [0.0556434, -0.2040259, 1.0572252]])
"""CIE XYZ (D65) -> linear sRGB (IEC 61966-2-1)."""


def camera_constants(kind: str) -> tuple[np.ndarray, np.ndarray]:
    """(colour matrix, WB multipliers) of the paper's simulated sensor for ``kind`` 'lms' or 'bayer'."""
    if kind == "lms":
        return P_LMS, WB_LMS
    if kind == "bayer":
        return B_BAYER, WB_BAYER
    raise ValueError(f"unknown CFA kind {kind!r}")


SRGB_ENCODING = {"SRGB_THRESHOLD": 0.0031308, "SRGB_SLOPE": 12.92, "SRGB_SCALE": 1.055,
                 "SRGB_INV_GAMMA": 1.0 / 2.4, "SRGB_OFFSET": 0.055}
"""IEC 61966-2-1 encoding constants, shared by the NumPy reference and the kernel's defines."""


SRGB_LUT_STEPS_LOG2 = 7
"""Table nodes per octave of the float exponent: 2^7 = 128 (mantissa bits used as the index)."""

SRGB_LUT_OCTAVES = 9
"""The table covers [2^-9, 1]; 2^-9 = 0.00195 lies below SRGB_THRESHOLD (0.0031308), where the
linear segment takes over."""


def srgb_table() -> tuple[np.ndarray, dict[str, int]]:
    """The sRGB transfer function at the float32 values whose low 23 - SRGB_LUT_STEPS_LOG2 mantissa
    bits are zero, from 2^-SRGB_LUT_OCTAVES up to and past 1.0, as float32 (for kernels/srgb.h),
    with the defines that index it."""
    shift = 23 - SRGB_LUT_STEPS_LOG2
    base = (127 - SRGB_LUT_OCTAVES) << SRGB_LUT_STEPS_LOG2
    count = (SRGB_LUT_OCTAVES << SRGB_LUT_STEPS_LOG2) + 2
    nodes = ((np.arange(count, dtype=np.uint32) + base) << shift).view(np.float32).astype(np.float64)
    k = SRGB_ENCODING
    values = k["SRGB_SCALE"] * np.power(nodes, k["SRGB_INV_GAMMA"]) - k["SRGB_OFFSET"]
    return values.astype(np.float32), {"SRGB_LUT_SHIFT": shift, "SRGB_LUT_BASE": base}


def srgb_table_source() -> str:
    """OpenCL source defining SRGB_LUT and its index constants (to precede kernels/srgb.h)."""
    values, defines = srgb_table()
    lines = [f"#define {key} {value}" for key, value in defines.items()]
    body = ",".join(f"{v:.9e}f" for v in values.tolist())
    lines.append(f"__constant float SRGB_LUT[{len(values)}] = {{{body}}};")
    return "\n".join(lines)


def srgb_encode(x: np.ndarray) -> np.ndarray:
    """Linear -> sRGB-encoded (IEC 61966-2-1), after clipping to [0, 1]. Same shape and dtype."""
    k = SRGB_ENCODING
    x = np.clip(x, 0.0, 1.0)
    encoded = np.where(x <= k["SRGB_THRESHOLD"], k["SRGB_SLOPE"] * x,
                       k["SRGB_SCALE"] * np.power(x, k["SRGB_INV_GAMMA"]) - k["SRGB_OFFSET"])
    return encoded.astype(x.dtype)


def quantize16(encoded: np.ndarray) -> np.ndarray:
    """Encoded values in [0, 1] (clipped) to the nearest 16-bit code, uint16 (as kernels/srgb.h)."""
    return np.floor(np.clip(encoded, 0.0, 1.0) * 65535.0 + 0.5).astype(np.uint16)


def srgb_decode(v: np.ndarray) -> np.ndarray:
    """sRGB-encoded in [0, 1] -> linear (IEC 61966-2-1). Same shape and dtype."""
    v = np.asarray(v)
    return np.where(v <= 0.04045, v / 12.92, np.power((v + 0.055) / 1.055, 2.4)).astype(v.dtype)
