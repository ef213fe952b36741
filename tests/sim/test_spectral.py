"""Spectral scenes: sensitivities, white balance, fitted matrices and the spectral chart path."""
from __future__ import annotations

import numpy as np
import pytest

from paths import SHARED_DATA
import clisp
from clisp.sim.colorimetry import P_LMS
from clisp.errors import ClispError
from clisp.sim.spectral import (WAVELENGTHS, camera_responses, fit_colour_matrix, patch_delta_e, reflectances,
                                sensitivities, sensitivity_kind, simulate_spectral, spectral_colorchecker, true_srgb,
                                white_balance)


def test_shapes_and_white() -> None:
    assert sensitivities("lms").shape == sensitivities("bayer").shape == (WAVELENGTHS.size, 3)
    refl = reflectances()
    assert refl.shape == (24, WAVELENGTHS.size) and np.all((refl > 0) & (refl < 1))
    white = camera_responses(np.ones((1, WAVELENGTHS.size)), "lms")[0]
    assert white.max() == pytest.approx(1.0)
    # D65 integrated at 10 nm over 400..700 nm sits within 0.003 of the sRGB white point
    assert true_srgb(np.ones((1, WAVELENGTHS.size)))[0] == pytest.approx([1.0, 1.0, 1.0], abs=5e-3)


def test_lms_white_balance_matches_photon_counting() -> None:
    # Stockman-Sharpe cones with photon counting give M 1.216-1.224 (paper 1.2191), S about 2.3 (paper 3.14)
    wb = white_balance("lms")
    assert wb[0] == 1.0 and wb[1] == pytest.approx(1.2191, abs=0.01) and wb[2] == pytest.approx(2.3, abs=0.1)
    assert white_balance("bayer")[1] == 1.0


def test_neutral_patches_are_neutral_and_match_spec() -> None:
    srgb = true_srgb(reflectances())[18:24][::-1]        # panels 1 (black) .. 6 (white)
    spec_y = [0.0315, 0.0882, 0.1906, 0.3649, 0.5900, 0.8807]   # from the 2014 chart's xyY, not Ohta's spectra
    assert np.allclose(srgb.mean(axis=1), spec_y, rtol=0.08)
    assert np.all(np.ptp(srgb, axis=1) < 0.05 * srgb.mean(axis=1) + 2e-3)


def test_fitted_matrix_preserves_white_and_resembles_eq1() -> None:
    rng = np.random.default_rng(0)
    cam, srgb = rng.random((30, 3)), rng.random((30, 3))
    assert np.allclose(fit_colour_matrix(cam, srgb).sum(axis=1), 1.0)
    lms = spectral_colorchecker("lms")
    assert np.allclose(lms.matrix.sum(axis=1), 1.0)
    assert np.abs(lms.matrix - P_LMS).max() < 0.5          # eq. (1) is close to, not equal to, the fit


@pytest.mark.parametrize("cfa, limit", [("lms", 1.0), ("bayer", 3.0), ("lms-bayer", 1.0)])
def test_noiseless_colour_error(cfa: str, limit: float) -> None:
    """The spectral chart through each CFA; LMS on the Bayer layout takes the cones' sensitivities
    (sensitivity_kind: the channels, not the layout), so its colour error is the LMS camera's."""
    sim = simulate_spectral(cfa, gain=None)
    out = clisp.process(sim.raw)
    de = patch_delta_e(out, sim.truth, spectral_colorchecker(sensitivity_kind(sim.raw.cfa)).rois)
    assert de.shape == (24,) and de.mean() < limit


def test_noisy_and_reproducible() -> None:
    a, b = simulate_spectral("bayer", gain=8, seed=4), simulate_spectral("bayer", gain=8, seed=4)
    assert a.raw.data.dtype == np.uint16 and np.array_equal(a.raw.data, b.raw.data)
    assert a.raw.metadata["scene"].startswith("spectral colorchecker")


ISETCAM = SHARED_DATA


@pytest.mark.skipif(not (ISETCAM / "spectral" / "isetcam" / "macbethChart.mat").is_file(),
                    reason="no ../shared/data/spectral/isetcam")
def test_isetcam_chart_in_reading_order() -> None:
    ours, theirs = reflectances(), reflectances("isetcam", ISETCAM)
    nearest = ((ours[:, None] - theirs[None]) ** 2).sum(axis=-1).argmin(axis=1)
    assert np.array_equal(nearest, np.arange(24))


def test_bad_kind_and_source() -> None:
    with pytest.raises(ClispError):
        sensitivities("rgbw")
    with pytest.raises(ClispError):
        reflectances("nowhere")
    with pytest.raises(ClispError, match="macbethChart"):
        reflectances("isetcam", "/nonexistent")


def test_cli_spectral(tmp_path) -> None:
    from clisp.app.cli import main
    from clisp.io.imageio import read_image
    raw_path, truth_path = tmp_path / "s.dng", tmp_path / "t.exr"
    assert main(["simulate", "--spectral", "colorchecker", "--cfa", "lms", "--noiseless",
                 "-o", str(raw_path), "--truth", str(truth_path)]) == 0
    raw = clisp.read_raw(raw_path)
    assert raw.metadata["scene"].startswith("spectral colorchecker") and raw.data.dtype == np.float32
    out = clisp.process(raw)
    truth, _ = read_image(truth_path)
    de = patch_delta_e(out, truth, spectral_colorchecker("lms").rois)
    assert de.mean() < 1.0
    assert main(["simulate", "-o", str(tmp_path / "x.dng")]) == 2          # neither SCENE nor --spectral
    assert not (tmp_path / "x.dng").exists()
