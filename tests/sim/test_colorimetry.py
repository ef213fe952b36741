"""clisp.sim.colorimetry: the sRGB curve's written-out polynomial constants."""
import pytest

from clisp.sim.colorimetry import SRGB_POLY, srgb_poly_defines, srgb_poly_fit


def test_srgb_poly_constants_are_the_fit():
    """SRGB_POLY, what the sRGB kernels get, is the Chebyshev fit it stands for (fitted again here:
    the same keys, each coefficient within 1e-9 of it, far below float32's resolution)."""
    fit = srgb_poly_fit()
    assert list(SRGB_POLY) == list(fit)
    for key, value in fit.items():
        assert SRGB_POLY[key] == pytest.approx(value, rel=1e-9, abs=1e-12), key
    assert srgb_poly_defines() == SRGB_POLY and srgb_poly_defines() is not SRGB_POLY
