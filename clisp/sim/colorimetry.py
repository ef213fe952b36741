"""Colour constants of the paper and the sRGB transfer functions (docs/model.md: conventions and section 4).

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
    """(colour matrix, WB multipliers) of the paper's simulated sensor for the spectral kind ``kind``
    (clisp.cfa ``CFA.spectral``): 'lms', or 'rgb' (also named 'bayer', the RGB Bayer CFA's kind). The
    constants follow the filters, not their layout: L, M, S on the Bayer layout take the LMS ones."""
    if kind == "lms":
        return P_LMS, WB_LMS
    if kind in ("rgb", "bayer"):
        return B_BAYER, WB_BAYER
    raise ValueError(f"unknown CFA kind {kind!r}")


SRGB_ENCODING = {"SRGB_THRESHOLD": 0.0031308, "SRGB_SLOPE": 12.92, "SRGB_SCALE": 1.055,
                 "SRGB_INV_GAMMA": 1.0 / 2.4, "SRGB_OFFSET": 0.055}
"""IEC 61966-2-1 encoding constants, shared by the NumPy reference and the kernel's defines."""


SRGB_POLY_DEGREES = (6, 5)
"""Degrees of the two polynomials of clisp/modules/colour/srgb.h: m^(5/12) on [1, 2) and 2^f on [0, 1).
Evaluated in float32 they put the curve within 0.02 of a 16-bit code (5 and 5: 0.09; 4 and 5: 0.6)."""


def _chebyshev_fit(fn, lo: float, hi: float, degree: int, prefix: str) -> dict[str, float]:
    """Defines ``{prefix}_SCALE``, ``{prefix}_OFFSET`` (u = t * scale + offset maps [lo, hi] to
    [-1, 1]) and ``{prefix}0..`` (power-basis coefficients in u) of the Chebyshev fit of fn."""
    from numpy.polynomial import chebyshev     # deferred: 3 ms of start-up; used when the sRGB kernels build
    t = np.cos(np.linspace(0.0, np.pi, 20001)) * (hi - lo) / 2 + (hi + lo) / 2
    scale, offset = 2.0 / (hi - lo), -(hi + lo) / (hi - lo)
    coefficients = chebyshev.cheb2poly(chebyshev.chebfit(t * scale + offset, fn(t), degree))
    defines = {f"{prefix}_SCALE": scale, f"{prefix}_OFFSET": offset}
    defines.update({f"{prefix}{i}": float(c) for i, c in enumerate(coefficients)})
    return defines


SRGB_POLY = {
    "SRGB_M_SCALE": 2.0, "SRGB_M_OFFSET": -3.0,
    "SRGB_M0": 1.2491765614159531, "SRGB_M1": 0.17349806032483545, "SRGB_M2": -0.01686858426068129,
    "SRGB_M3": 0.002957095985751344, "SRGB_M4": -0.0006346843237356093, "SRGB_M5": 0.00017266937067188148,
    "SRGB_M6": -4.524187018461095e-05,
    "SRGB_F_SCALE": 2.0, "SRGB_F_OFFSET": -1.0,
    "SRGB_F0": 1.4142136691449845, "SRGB_F1": 0.4901290902263858, "SRGB_F2": 0.08493097498438115,
    "SRGB_F3": 0.009811685023203794, "SRGB_F4": 0.0008552490163495446, "SRGB_F5": 5.922210706845672e-05,
}
"""The defines of clisp/modules/colour/srgb.h: :func:`srgb_poly_fit`'s result, written out (the fit
took 50 ms of every process that encodes sRGB; tests/sim/test_colorimetry.py fits it again and
compares), so every machine's kernels get the same constants."""


def srgb_poly_fit() -> dict[str, float]:
    """The fits SRGB_M* of SRGB_SCALE * m^SRGB_INV_GAMMA on [1, 2) and SRGB_F* of 2^f on [0, 1)
    (see SRGB_POLY_DEGREES), as defines: what SRGB_POLY holds."""
    k = SRGB_ENCODING
    gamma = k["SRGB_INV_GAMMA"]
    return {**_chebyshev_fit(lambda m: k["SRGB_SCALE"] * m ** gamma, 1.0, 2.0, SRGB_POLY_DEGREES[0], "SRGB_M"),
            **_chebyshev_fit(lambda f: 2.0 ** f, 0.0, 1.0, SRGB_POLY_DEGREES[1], "SRGB_F")}


def srgb_poly_defines() -> dict[str, float]:
    """Defines for clisp/modules/colour/srgb.h (SRGB_POLY)."""
    return dict(SRGB_POLY)


def srgb_encode(x: np.ndarray) -> np.ndarray:
    """Linear -> sRGB-encoded (IEC 61966-2-1), after clipping to [0, 1]. Same shape and dtype."""
    k = SRGB_ENCODING
    x = np.clip(x, 0.0, 1.0)
    encoded = np.where(x <= k["SRGB_THRESHOLD"], k["SRGB_SLOPE"] * x,
                       k["SRGB_SCALE"] * np.power(x, k["SRGB_INV_GAMMA"]) - k["SRGB_OFFSET"])
    return encoded.astype(x.dtype)


def quantize16(encoded: np.ndarray) -> np.ndarray:
    """Encoded values in [0, 1] (clipped) to the nearest 16-bit code, uint16 (as clisp/modules/colour/srgb.h)."""
    return np.floor(np.clip(encoded, 0.0, 1.0) * 65535.0 + 0.5).astype(np.uint16)


def quantize8(encoded: np.ndarray) -> np.ndarray:
    """Encoded values in [0, 1] (clipped) to the nearest 8-bit code, uint8 (as clisp/modules/colour/srgb.h).

    >>> quantize8(np.array([0.0, 0.5, 1.0, 1.2])).tolist()
    [0, 128, 255, 255]
    """
    return np.floor(np.clip(encoded, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def srgb_decode(v: np.ndarray) -> np.ndarray:
    """sRGB-encoded in [0, 1] -> linear (IEC 61966-2-1). Same shape and dtype."""
    v = np.asarray(v)
    return np.where(v <= 0.04045, v / 12.92, np.power((v + 0.055) / 1.055, 2.4)).astype(v.dtype)
