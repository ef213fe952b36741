"""Quality metrics (docs/model.md section 5): PSNR, gray-panel SNR and CIEDE2000.

Inputs are H x W x 3 LINEAR sRGB (D65) arrays, white = 1.0. Boxes are ``(y0, y1, x0, x1)``.
"""
from __future__ import annotations

import warnings

import numpy as np

from .sim.colorimetry import srgb_encode

Box = tuple[int, int, int, int]


def _check_pair(output: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Both as float64 H x W x 3 arrays of equal shape."""
    a, b = np.asarray(output, dtype=np.float64), np.asarray(truth, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"expected two H x W x 3 images of equal shape, got {a.shape} and {b.shape}")
    return a, b


def _crop(image: np.ndarray, border: int, region: Box | None) -> np.ndarray:
    """``region`` if given (border ignored), else ``image`` less ``border`` px on every side."""
    if region is not None:
        y0, y1, x0, x1 = region
        return image[y0:y1, x0:x1]
    if border <= 0:
        return image
    if 2 * border >= min(image.shape[:2]):
        raise ValueError(f"border {border} leaves nothing of a {image.shape[:2]} image")
    return image[border:-border, border:-border]


def tone_map(image: np.ndarray) -> np.ndarray:
    """The tone map (docs/model.md, conventions): clip to [0, 1], then sRGB-encode. Same shape."""
    return srgb_encode(np.clip(image, 0.0, 1.0))


def psnr(output: np.ndarray, truth: np.ndarray, border: int = 10, tone_mapped: bool = True,
         region: Box | None = None) -> float:
    """PSNR in dB = 10 log10(1 / MSE), MSE over all pixels and the 3 channels (docs/model.md section 5).

    Both images are clipped to [0, 1]; with ``tone_mapped`` they are then sRGB-encoded, otherwise the
    score is in the linear domain. ``border`` px are cropped on every side of the full image; a
    ``region`` (y0, y1, x0, x1) scores that crop instead (no border applied). Identical inputs give inf.
    """
    a, b = _check_pair(output, truth)
    a, b = _crop(a, border, region), _crop(b, border, region)
    if a.size == 0:
        raise ValueError("empty region")
    if tone_mapped:
        a, b = tone_map(a), tone_map(b)
    else:
        a, b = np.clip(a, 0.0, 1.0), np.clip(b, 0.0, 1.0)
    mse = float(np.mean((a - b) ** 2))
    return float("inf") if mse == 0.0 else float(10.0 * np.log10(1.0 / mse))


def panel_snr(output: np.ndarray, rois: list[Box]) -> np.ndarray:
    """(len(rois), 3) SNR in dB = 20 log10(mean / std) per ROI and channel on the LINEAR image.

    std is the population standard deviation (ddof=0); a flat ROI gives inf, a non-positive mean nan.
    """
    image = np.asarray(output, dtype=np.float64)
    out = np.empty((len(rois), 3))
    with np.errstate(divide="ignore", invalid="ignore"):
        for k, (y0, y1, x0, x1) in enumerate(rois):
            patch = image[y0:y1, x0:x1].reshape(-1, image.shape[2])
            mean, std = patch.mean(axis=0), patch.std(axis=0)
            out[k] = 20.0 * np.log10(mean / std)
    return out


def gray_panel_snr(output: np.ndarray, gray_rois: list[Box]) -> np.ndarray:
    """(len(gray_rois),) gray-panel SNR in dB: panel_snr averaged over R, G, B (docs/model.md
    section 5; the paper's Table 2)."""
    return panel_snr(output, gray_rois).mean(axis=1)


def _colour():
    """Import colour-science lazily and without its matplotlib warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        import colour            # deferred: colour-science costs about 0.6 s of start-up
    return colour


def linear_srgb_to_lab(image: np.ndarray) -> np.ndarray:
    """... x 3 linear sRGB -> CIE L*a*b* (D65). Same shape.

    The reference white is the XYZ of sRGB (1, 1, 1) under the IEC 61966-2-1 matrix, so that white maps
    exactly to (100, 0, 0).
    """
    colour = _colour()
    space = colour.RGB_COLOURSPACES["sRGB"]
    xyz = colour.RGB_to_XYZ(np.asarray(image, dtype=np.float64), space)
    white = colour.XYZ_to_xy(colour.RGB_to_XYZ(np.ones(3), space))
    return colour.XYZ_to_Lab(xyz, white)


def ciede2000(output: np.ndarray, truth: np.ndarray, region: Box | None = None,
              clip: bool = True) -> float:
    """Mean CIEDE2000 colour difference over the pixels of ``region`` (whole image if None).

    Linear sRGB -> XYZ -> Lab (D65); with ``clip`` both images are first clipped to [0, 1].
    """
    a, b = _check_pair(output, truth)
    a, b = _crop(a, 0, region), _crop(b, 0, region)
    if clip:
        a, b = np.clip(a, 0.0, 1.0), np.clip(b, 0.0, 1.0)
    de = _colour().delta_E(linear_srgb_to_lab(a), linear_srgb_to_lab(b), method="CIE 2000")
    return float(np.mean(de))
