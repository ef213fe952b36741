"""Diffraction-limited optics of the simulated camera (docs/model.md section 2, "Optics").

The lens is modelled as an Airy PSF, ``PSF(r) = [2 J1(k r) / (k r)]^2`` with
``k = 3.831706 / r0`` (``r0`` = radius of the first dark ring in pixels; the paper's
"Airy disc diameter 2 px" is ``r0 = 1``). The discrete kernel integrates the PSF over
each pixel's 1 x 1 area, so it also models the pixel aperture.
"""
from __future__ import annotations

import numpy as np

from ..errors import ClispError

AIRY_FIRST_ZERO = 3.831706
"""First zero of the Bessel function J1: the first dark ring lies at k r = 3.831706."""


def airy_psf(r: np.ndarray, r0: float = 1.0) -> np.ndarray:
    """Airy intensity ``[2 J1(k r)/(k r)]^2`` (peak 1 at r = 0) at radii ``r`` in pixels; same shape."""
    kr = (AIRY_FIRST_ZERO / r0) * np.asarray(r, dtype=np.float64)
    safe = np.where(kr > 0.0, kr, 1.0)
    from scipy.special import j1       # scipy is imported where used: it costs 0.15 s of start-up
    return np.where(kr > 0.0, (2.0 * j1(safe) / safe) ** 2, 1.0)


def airy_kernel(r0: float = 1.0, radius: int = 4, subsamples: int = 16) -> np.ndarray:
    """Pixel-integrated Airy kernel, (2*radius+1) x (2*radius+1) float64, sum 1.

    Each tap is the mean of the PSF over the pixel's 1 x 1 area, sampled on a
    ``subsamples`` x ``subsamples`` grid of cell midpoints. With the defaults the centre
    3 x 3 is ~[[.01096, .05252, .01096], [.05252, .68125, .05252], [.01096, .05252, .01096]].
    """
    if not (np.isfinite(r0) and r0 > 0):
        raise ClispError(f"Airy first-zero radius r0 must be a positive number of pixels, got {r0!r}")
    if int(radius) < 0 or int(subsamples) < 1:
        raise ClispError(f"Airy kernel needs radius >= 0 and subsamples >= 1, got {radius!r}, {subsamples!r}")
    radius, subsamples = int(radius), int(subsamples)
    side = 2 * radius + 1
    offsets = (np.arange(subsamples) + 0.5) / subsamples - 0.5
    coords = (np.arange(-radius, radius + 1)[:, None] + offsets[None, :]).ravel()
    psf = airy_psf(np.hypot(coords[:, None], coords[None, :]), r0)
    kernel = psf.reshape(side, subsamples, side, subsamples).mean(axis=(1, 3))
    return kernel / kernel.sum()


def _check_kernel(kernel: np.ndarray) -> np.ndarray:
    """Validate a 2-D, odd-sized, finite kernel and return it as float64."""
    kernel = np.asarray(kernel, dtype=np.float64)
    if kernel.ndim != 2 or kernel.shape[0] % 2 == 0 or kernel.shape[1] % 2 == 0:
        raise ClispError(f"optics kernel must be a 2-D array with odd sides, got shape {kernel.shape}")
    if not np.all(np.isfinite(kernel)):
        raise ClispError("optics kernel contains NaN or infinite values")
    return kernel


def blur_channel(channel: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Convolve one H x W plane with ``kernel`` (mirror boundaries); returns H x W float64."""
    kernel = _check_kernel(kernel)
    from scipy import ndimage          # deferred: 0.15 s of start-up, as above
    return ndimage.convolve(np.asarray(channel, dtype=np.float64), kernel, mode="mirror")


def apply_optics(image: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Blur each channel of an H x W x C linear image with ``kernel``; returns H x W x C float64.

    Boundaries use whole-sample symmetric reflection (scipy ``mode='mirror'``).
    """
    image = np.asarray(image)
    if image.ndim != 3:
        raise ClispError(f"apply_optics expects an H x W x C image, got shape {image.shape}")
    kernel = _check_kernel(kernel)
    out = np.empty(image.shape, dtype=np.float64)
    for c in range(image.shape[2]):
        out[..., c] = blur_channel(image[..., c], kernel)
    return out
