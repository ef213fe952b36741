"""The residual-interpolation Bayer demosaics of clisp/modules/demosaic_ari/reference.py (NumPy references).

Small synthetic scenes only (no ../shared data): a sRGB-encoded dead-leaves chart and a fine
luminance texture under smooth chroma. Checked for every method: the CFA samples stay at their own sites, the result is
finite and clearly better than bilinear, a constant mosaic stays constant, and the four Bayer
phases agree: demosaicking a crop of the RGGB mosaic shifted by one row and/or column (a GRBG,
GBRG or BGGR mosaic) gives the whole mosaic's output away from the crop's edges.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest
from scipy import ndimage

from clisp.cfa import BAYER_PHASES, bayer_cfa
from clisp.sim.charts import dead_leaves
from clisp.sim.colorimetry import srgb_encode
from clisp.metrics import psnr
from clisp.modules.demosaic_ari import reference as bayer_ri

METHODS = {
    "ri": bayer_ri.demosaic_ri,
    "mlri": bayer_ri.demosaic_mlri,
    "mlri weighted": lambda m, p="RGGB": bayer_ri.demosaic_mlri(m, p, weighted=True),
    "ari": bayer_ri.demosaic_ari,
    "ari hybrid": bayer_ri.demosaic_ari_hybrid,
}
SHIFT = {"RGGB": (0, 0), "GRBG": (0, 1), "GBRG": (1, 0), "BGGR": (1, 1)}
"""Crop offset of the RGGB mosaic that gives each phase (written out, not taken from the module)."""


@lru_cache(maxsize=None)
def leaves(size: int = 96) -> np.ndarray:
    return srgb_encode(dead_leaves(size, seed=3))


def texture(h: int = 96, w: int = 96) -> np.ndarray:
    """Fine luminance texture (periods 5 to 17 px) under a slowly varying chroma: the inter-channel
    correlation that demosaics exploit and bilinear interpolation ignores."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    lum = 0.45 + 0.2 * np.sin(2 * np.pi * (x / 9.0 + y / 13.0)) + 0.1 * np.cos(2 * np.pi * (x / 5.0 - y / 17.0))
    return np.stack([lum + 0.08 * np.sin(2 * np.pi * x / 60.0), lum, lum + 0.06 * np.cos(2 * np.pi * y / 50.0)],
                    axis=-1)


def mosaic_of(image: np.ndarray, phase: str) -> np.ndarray:
    channel = bayer_cfa(phase).channel_map(*image.shape[:2])
    return np.take_along_axis(image, channel[..., None].astype(np.intp), axis=2)[..., 0]


def bilinear(m: np.ndarray, phase: str) -> np.ndarray:
    """Per-channel bilinear interpolation (normalised convolution of each channel's samples)."""
    channel = bayer_cfa(phase).channel_map(*m.shape)
    k = np.array([[0.25, 0.5, 0.25], [0.5, 1.0, 0.5], [0.25, 0.5, 0.25]])
    out = []
    for c in range(3):
        sites = (channel == c).astype(np.float64)
        out.append(ndimage.convolve(m * sites, k, mode="mirror") / ndimage.convolve(sites, k, mode="mirror"))
    return np.stack(out, axis=-1)


@pytest.mark.parametrize("phase", BAYER_PHASES)
@pytest.mark.parametrize("name", METHODS)
def test_keeps_samples_and_finite(name, phase):
    truth = leaves()
    m = mosaic_of(truth, phase)
    out = METHODS[name](m, phase)
    assert out.shape == truth.shape and out.dtype == np.float64
    assert np.all(np.isfinite(out))
    assert out.min() >= 0.0 and out.max() <= 1.0
    channel = bayer_cfa(phase).channel_map(*m.shape)
    at_sites = np.take_along_axis(out, channel[..., None].astype(np.intp), axis=2)[..., 0]
    np.testing.assert_allclose(at_sites, m, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", METHODS)
def test_beats_bilinear(name):
    # dead leaves: random disc colours, little inter-channel correlation, so only a small margin
    for truth, margin in ((texture(), 10.0), (leaves(), 0.2)):
        m = mosaic_of(truth, "RGGB")
        ours = psnr(METHODS[name](m, "RGGB"), truth, border=8, tone_mapped=False)
        base = psnr(bilinear(m, "RGGB"), truth, border=8, tone_mapped=False)
        assert ours > base + margin, f"{name}: {ours:.2f} dB vs bilinear {base:.2f} dB"


@pytest.mark.parametrize("name", METHODS)
def test_constant_stays_constant(name):
    m = np.full((40, 48), 0.37)
    np.testing.assert_allclose(METHODS[name](m, "GBRG"), 0.37, rtol=0, atol=1e-9)
    assert np.all(METHODS[name](np.zeros((40, 48)), "RGGB") == 0.0)


HALO = {"ri": 28, "mlri": 28, "mlri weighted": 28, "ari": 44, "ari hybrid": 44}
"""Context (px) an output pixel depends on (measured: beyond it a tile's output equals the whole
image's to rounding). Full ARI reaches much further (about 96 px to 1e-6, tools/demosaic_study.py --halo),
so the phase test runs ARI and the hybrid with 2 G iterations and 1 chroma iteration (reach 44 px)."""
PHASE_METHODS = {
    **METHODS,
    "ari": lambda m, p: bayer_ri.demosaic_ari(m, p, green_iterations=2, chroma_iterations=1),
    "ari hybrid": lambda m, p: bayer_ri.demosaic_ari(m, p, green_iterations=2, chroma_iterations=1,
                                                     green_merge="mean", chroma="mean"),
}
TOL = {"ri": 1e-7, "mlri": 1e-7, "mlri weighted": 1e-7, "ari": 1e-4, "ari hybrid": 1e-4}
"""Rounding, not halo: box sums are running sums whose rounding depends on the position along a row
(1e-8 measured for weighted MLRI); ARI's 1 / RMSE weights and per-pixel selections amplify it (up to
1.4e-5 measured). A wrong phase costs more than 0.05 (asserted below)."""


@pytest.mark.parametrize("name", METHODS)
def test_four_phases_agree(name):
    truth = leaves(128)
    m = mosaic_of(truth, "RGGB")
    method = PHASE_METHODS[name]
    whole = method(m, "RGGB")
    halo = HALO[name]
    for phase, (dy, dx) in SHIFT.items():
        crop = m[dy:, dx:][:m.shape[0] - 2, :m.shape[1] - 2]   # its top-left 2 x 2 block reads ``phase``
        out = method(crop, phase)
        inner = (slice(halo, crop.shape[0] - halo), slice(halo, crop.shape[1] - halo))
        ref = whole[dy:, dx:][:crop.shape[0], :crop.shape[1]]
        np.testing.assert_allclose(out[inner], ref[inner], rtol=0, atol=TOL[name], err_msg=f"{name} {phase}")
        # and the phase matters: the crop read as RGGB is a different (wrong) image
        if phase != "RGGB":
            wrong = method(crop, "RGGB")
            assert np.abs(wrong[inner] - ref[inner]).max() > 0.05


def test_rejects_bad_input():
    with pytest.raises(ValueError):
        bayer_ri.demosaic_mlri(np.zeros((8, 8)), "RGBG")
    with pytest.raises(ValueError):
        bayer_ri.demosaic_ri(np.zeros((8, 8, 3)))
    with pytest.raises(ValueError):
        bayer_ri.demosaic_ri(np.full((8, 8), np.nan))
