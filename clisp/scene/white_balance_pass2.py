"""White balance pass 2: estimating the von Kries gains on linear sRGB (docs/model.md section 4).

Pass 1 (``raw_scale.white_balance1``, before demosaicking) equalises the raw channels so the
demosaic sees similar signal strengths; pass 2 (``colour.WhiteBalance2``, after the colour matrix)
is the colour-constancy step: diagonal gains on linear sRGB that map the scene illuminant to
white. This module only *estimates* the pass-2 gains; the stage applies them.

Methods (``estimate_wb2(raw, method)``):

``metadata``     known illuminant. With ``metadata['illuminant_white']`` (the illuminant's white in
                 pass-1-balanced camera units, e.g. from spectra): g_k = 1 / (M w)_k
                 (:func:`illuminant_gains`); D65 white w = (1, 1, 1) through the paper's P gives
                 (1.0000, 1.0101, 1.0753). Otherwise the raw's own ``wb2`` (identity for clisp's
                 RGB-sourced simulations, whose inverse ISP used exactly P and WB_LMS).
``gray_world``   g_k = mean(G) / mean(k) over the well-exposed pixels (:func:`gray_world_gains`).
``gray_pixels``  gray world restricted to near-neutral pixels, iterated (:func:`gray_pixel_gains`;
                 J.-Y. Huo et al., "Robust automatic white balance algorithm using gray color
                 points in images", IEEE Trans. Consumer Electronics 52(2), 2006): a pixel is gray
                 when (|U| + |V|) / Y < threshold in BT.601 YUV after the current gains.

The statistics come from the statistics pass's cell thumbnail (clisp.scene.statistics): one camera
triplet per CFA cell (the mean of each channel's samples in the cell, times the pass-1 gains), no
demosaic needed, so the estimate is cheap and independent of tiling. Gains are normalised so G = 1
unless stated.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import ClispError
from ..io.rawimage import RawImage
from .statistics import thumbnail

BT601 = np.array([0.299, 0.587, 0.114])
METHODS = ("metadata", "gray_world", "gray_pixels")
DARK_FRACTION = 0.01
"""Tiles whose luminance is below this fraction of the 99th percentile are dropped (noise)."""


def illuminant_gains(matrix: np.ndarray, white_cam: np.ndarray | None = None) -> np.ndarray:
    """Pass-2 gains g_k = 1 / (matrix @ w)_k that map the illuminant white to (1, 1, 1).

    ``w``: the illuminant's white in pass-1-balanced camera units (default (1, 1, 1): pass 1
    equalised the illuminant's white exactly). Not normalised (white stays white).

    >>> from clisp.sim.colorimetry import P_LMS
    >>> np.round(illuminant_gains(P_LMS), 4).tolist()
    [1.0, 1.0101, 1.0753]
    """
    w = np.ones(3) if white_cam is None else np.asarray(white_cam, dtype=np.float64)
    rgb = np.asarray(matrix, dtype=np.float64) @ w
    if np.any(rgb <= 0):
        raise ClispError(f"illuminant white maps to non-positive RGB {rgb}; cannot white-balance")
    return 1.0 / rgb


def _exposed(rgb: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Unclipped pixels whose luminance is above DARK_FRACTION of the bright end."""
    y = rgb @ BT601
    if not ok.any():
        raise ClispError("white balance: every pixel is clipped")
    bright = np.percentile(y[ok], 99)
    return ok & (y > DARK_FRACTION * bright) & np.all(rgb > 0, axis=-1)


def gray_world_gains(rgb: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """g_k = mean(G) / mean(k) over ``mask`` (all pixels if None) of linear RGB (..., 3); G = 1."""
    pix = rgb.reshape(-1, 3) if mask is None else rgb[mask]
    if pix.shape[0] == 0:
        raise ClispError("gray world: no usable pixels")
    means = pix.mean(axis=0)
    if np.any(means <= 0):
        raise ClispError(f"gray world: non-positive channel mean {means}")
    return means[1] / means


def gray_pixel_gains(rgb: np.ndarray, mask: np.ndarray | None = None, threshold: float = 0.3,
                     iterations: int = 8, min_fraction: float = 0.01) -> np.ndarray:
    """Gray world over near-neutral pixels, iterated (Huo et al. 2006); G = 1.

    Start from gray-world gains; at each iteration keep the pixels of ``mask`` whose BT.601
    (|U| + |V|) / Y < ``threshold`` after the current gains, and recompute gray world on them.
    Falls back to the previous gains when fewer than ``min_fraction`` of the pixels qualify.
    """
    pix = rgb.reshape(-1, 3) if mask is None else rgb[mask]
    gains = gray_world_gains(pix)
    for _ in range(iterations):
        bal = pix * gains
        y = bal @ BT601
        u = 0.492 * (bal[:, 2] - y)
        v = 0.877 * (bal[:, 0] - y)
        gray = (np.abs(u) + np.abs(v)) < threshold * y
        if gray.sum() < max(1, min_fraction * pix.shape[0]):
            break
        new = gray_world_gains(pix[gray])
        if np.allclose(new, gains, rtol=1e-6, atol=0):
            gains = new
            break
        gains = new
    return gains


def estimate_wb2(raw: RawImage, method: str = "metadata", statistics: Any = None, **options: Any) -> np.ndarray:
    """Pass-2 gains (3,) for ``raw`` by ``method`` (see module docstring). ``options`` go to the
    gray-pixel estimator (threshold, iterations, min_fraction). ``statistics``: the raw's
    clisp.scene.statistics.SceneStatistics, whose cell thumbnail (every k-th cell of at most 2^19)
    times the pass-1 gains is the thumbnail; None reads that thumbnail here."""
    if method not in METHODS:
        raise ClispError(f"unknown white balance pass 2 method {method!r}; expected one of {', '.join(METHODS)}")
    matrix = np.asarray(raw.colour_matrix, dtype=np.float64)
    if method == "metadata":
        white = (raw.metadata or {}).get("illuminant_white")
        return illuminant_gains(matrix, white) if white is not None else np.array(raw.wb2, dtype=np.float64)
    cells, clipped = statistics.thumbnail() if statistics is not None else \
        thumbnail(raw.data, raw.cfa, raw.black_level, raw.white_level)
    thumb, ok = cells.astype(np.float64) * raw.pass1_gains(), ~clipped
    rgb = thumb @ matrix.T
    mask = _exposed(rgb, ok)
    if method == "gray_world":
        return gray_world_gains(rgb, mask)
    return gray_pixel_gains(rgb, mask, **options)
