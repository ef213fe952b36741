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

The statistics come from a raw thumbnail (:func:`raw_thumbnail`): one camera triplet per CFA tile
(the mean of each channel's samples in the tile), no demosaic needed, so the estimate is cheap and
independent of tiling. Gains are normalised so G = 1 unless stated.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from ..cfa import CFA
from ..engine.streaming import window_source
from ..errors import ClispError
from ..io.rawimage import RawImage

BT601 = np.array([0.299, 0.587, 0.114])
METHODS = ("metadata", "gray_world", "gray_pixels")
CLIP_FRACTION = 0.98
"""A normalised raw sample at or above this counts as clipped; its CFA tile is dropped."""
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


THUMBNAIL_TILES = 2 ** 21
"""At most about this many CFA tiles enter the statistics; larger raws use every k-th tile row
and column (a memory-mapped 400 MP raw then reads ~1/12 of its rows)."""


def raw_thumbnail(data: np.ndarray, cfa: CFA, black_level: np.ndarray, white_level: float,
                  gains: np.ndarray, max_tiles: int = THUMBNAIL_TILES) -> tuple[np.ndarray, np.ndarray]:
    """(thumb, ok): one pass-1-balanced camera triplet per whole CFA tile, shape (H/p, W/p, n)
    (every k-th tile row and column when there are more than ``max_tiles`` tiles), the mean of
    each channel's samples in the tile; ``ok`` marks tiles with no clipped sample."""
    p = cfa.period
    h, w = data.shape[0] // p * p, data.shape[1] // p * p
    k = max(1, int(np.ceil(np.sqrt((h // p) * (w // p) / max_tiles))))
    black = np.broadcast_to(np.asarray(black_level, dtype=np.float64), (cfa.n_channels,))
    channel = cfa.channel_map(p, p)
    source = window_source(data)     # pread for mapped raw files: truncation is an error, not SIGBUS
    try:
        rows = np.concatenate([source.read(y, 0, p, w, p) for y in range(0, h, k * p)]) if k > 1 \
            else source.read(0, 0, h, w, p)
    finally:
        source.close()
    rows = rows.reshape(-1, p, w // p, p)[:, :, ::k]
    tiles = rows.astype(np.float64).transpose(0, 2, 1, 3)
    norm = (tiles - black[channel]) / (float(white_level) - black[channel])
    ok = ~(norm >= CLIP_FRACTION).any(axis=(2, 3))
    thumb = np.stack([norm[:, :, channel == c].mean(axis=2) * gains[c] for c in range(cfa.n_channels)], axis=-1)
    return thumb, ok


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
    clisp.scene.statistics.SceneStatistics, whose cell thumbnail (times the pass-1 gains) is then the
    thumbnail (every step-th cell of at most MAX_CELLS, 2^19, where :func:`raw_thumbnail` reads up to
    THUMBNAIL_TILES, 2^21); None reads the mosaic here."""
    if method not in METHODS:
        raise ClispError(f"unknown white balance pass 2 method {method!r}; expected one of {', '.join(METHODS)}")
    matrix = np.asarray(raw.colour_matrix, dtype=np.float64)
    if method == "metadata":
        white = (raw.metadata or {}).get("illuminant_white")
        return illuminant_gains(matrix, white) if white is not None else np.array(raw.wb2, dtype=np.float64)
    if statistics is not None:
        cells, clipped = statistics.thumbnail()
        thumb, ok = cells.astype(np.float64) * raw.pass1_gains(), ~clipped
    else:
        thumb, ok = raw_thumbnail(raw.data, raw.cfa, raw.black_level, raw.white_level, raw.pass1_gains())
    rgb = thumb @ matrix.T
    mask = _exposed(rgb, ok)
    if method == "gray_world":
        return gray_world_gains(rgb, mask)
    return gray_pixel_gains(rgb, mask, **options)
