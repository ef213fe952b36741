"""Shared plumbing of the plain-NumPy Bayer demosaics (bayer_rcd, bayer_gbtf): phase handling,
CFA-phase-preserving mirror padding, shifted views and site masks.

Every such demosaic works on an RGGB window: :func:`rggb_window` mirror-pads the H x W mosaic
(``np.pad`` mode ``reflect``: about the edge pixel, not repeating it, so pixel -k takes the value of
pixel k, which has the same CFA colour) by ``margin`` pixels, plus one row / column on the top /
left for the phases whose (0, 0) is not red, so that the window's (0, 0) is a red site. The
algorithm then runs on the whole window with :func:`at` (periodic shifts); what the shifts wrap
around stays within ``margin`` of the window's edge as long as ``margin`` is at least the
algorithm's halo, and :func:`crop` cuts the H x W image back out.
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from clisp.errors import ClispError

R, G, B = 0, 1, 2

RED_SITE = {"RGGB": (0, 0), "GRBG": (0, 1), "GBRG": (1, 0), "BGGR": (1, 1)}
"""(row, column) of the red site within the 2 x 2 tile of each Bayer phase."""


def rggb_window(mosaic: np.ndarray, pattern: str, margin: int) -> tuple[np.ndarray, tuple[int, int]]:
    """Mirror-padded float64 copy of the H x W ``mosaic`` whose pixel (0, 0) is a red site.

    Returns (window, (y0, x0)): the image is ``window[y0:y0 + H, x0:x0 + W]``. ``margin`` must be even.
    """
    pattern = pattern.upper()
    if pattern not in RED_SITE:
        raise ClispError(f"unsupported Bayer phase {pattern!r}; expected one of {', '.join(RED_SITE)}")
    if margin % 2:
        raise ClispError(f"margin must be even to keep the CFA phase, got {margin}")
    mosaic = np.asarray(mosaic, dtype=np.float64)
    if mosaic.ndim != 2:
        raise ClispError(f"expected an H x W mosaic, got shape {mosaic.shape}")
    dy, dx = RED_SITE[pattern]
    y0, x0 = margin + dy, margin + dx
    return np.pad(mosaic, ((y0, margin), (x0, margin)), mode="reflect"), (y0, x0)


def crop(image: np.ndarray, origin: tuple[int, int], shape: tuple[int, int]) -> np.ndarray:
    """The H x W (x C) image at ``origin`` of a window made by :func:`rggb_window`."""
    y0, x0 = origin
    return np.ascontiguousarray(image[y0:y0 + shape[0], x0:x0 + shape[1]])


def at(a: np.ndarray, dy: int, dx: int) -> np.ndarray:
    """``b[y, x] = a[y + dy, x + dx]`` (periodic at the window's edges, see the module docstring)."""
    return np.roll(a, (-dy, -dx), axis=(0, 1))


def rggb_masks(shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Boolean (red, green, blue) site masks of an RGGB window of ``shape`` (H, W, ...)."""
    ys = np.arange(shape[0])[:, None] % 2
    xs = np.arange(shape[1])[None, :] % 2
    red = (ys == 0) & (xs == 0)
    blue = (ys == 1) & (xs == 1)
    return red, ~(red | blue), blue


def box_sum(a: np.ndarray, size: int) -> np.ndarray:
    """Sum over the centred size x size window (periodic, like :func:`at`). Direct separable sums,
    not running sums, so a pixel's value does not depend on where the window starts."""
    ones = np.ones(size)
    return ndimage.correlate1d(ndimage.correlate1d(a, ones, axis=0, mode="wrap"), ones, axis=1, mode="wrap")
