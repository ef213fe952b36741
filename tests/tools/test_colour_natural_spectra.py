"""tools/colour_natural_spectra.py (issue 32, item 3) on scenes made in code: the Mallett 2019
upsampling must give back its input colour, a camera with the CIE observer's own responses must score
~0, and the LMS / Bayer cameras must be the ones clisp.sim.spectral fits on the ColorChecker."""
from __future__ import annotations

import sys
import warnings

import numpy as np

from paths import TOOLS

sys.path.insert(0, str(TOOLS))

import colour_natural_spectra as cns  # noqa: E402  (tools/ is not a package)
from clisp.sim.charts import dead_leaves  # noqa: E402
from clisp.sim.spectral import (_resample, camera_responses, reflectances, spectral_colorchecker,  # noqa: E402
                                srgb_to_reflectance, true_srgb)


def test_upsampling_is_colour_sciences_mallett2019():
    """The vectorised upsampling is RGB_to_sd_Mallett2019 at the integration grid."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        from colour.recovery import RGB_to_sd_Mallett2019
    rgb = np.array([[0.70, 0.19, 0.22], [0.05, 0.40, 0.90], [1.0, 1.0, 1.0]])
    ours = srgb_to_reflectance(rgb)
    for colour_rgb, spectrum in zip(rgb, ours):
        assert np.allclose(spectrum, _resample(RGB_to_sd_Mallett2019(colour_rgb)), atol=1e-9)
    assert ours.min() >= 0.0 and ours.max() <= 1.0 + 1e-6


def test_upsampling_round_trip_reproduces_the_input():
    """Spectra of a made-in-code scene, lit by D65 and seen by the CIE 1931 observer, come back to
    the scene's linear sRGB within a small CIEDE2000 (the 400..700 nm, 10 nm grid costs ~0.2)."""
    scene = dead_leaves(48, seed=5)
    truth = true_srgb(srgb_to_reflectance(scene.reshape(-1, 3)))
    de = cns.delta_e00(truth, scene.reshape(-1, 3))
    assert de.mean() < 0.4 and de.max() < 1.0


def test_cie_observer_camera_scores_zero_and_the_others_do_not():
    """The harness can tell a colorimetric camera from one that is not: the CIE observer's own
    responses through a ColorChecker-fitted matrix score ~0 (the white-preserving constraint leaves
    ~0.1), the D100 Bayer camera does not."""
    scene = dead_leaves(48, seed=7)
    cameras = [cns.cie_camera(), cns.Camera.of("bayer")]
    responses, truth = cns.spectral_image(scene, cameras)
    cie_mean, cie_p95 = cns.stats(cns.delta_e00(cns.direct(responses[0], cameras[0], None), truth))
    bayer_mean, _ = cns.stats(cns.delta_e00(cns.direct(responses[1], cameras[1], None), truth))
    assert cie_mean < 0.2 and cie_p95 < 0.4
    assert bayer_mean > 0.5


def test_cameras_are_clisp_spectral_ones():
    """LMS and Bayer responses, white balance and matrix are clisp.sim.spectral's (fitted on the
    ColorChecker only)."""
    refl = reflectances("colour")
    for kind in ("lms", "bayer"):
        camera = cns.Camera.of(kind)
        chart = spectral_colorchecker(kind)
        assert np.allclose(camera.responses(refl), camera_responses(refl, kind))
        assert np.allclose(camera.wb, chart.wb) and np.allclose(camera.matrix, chart.matrix)


def test_gain_8_goes_through_the_noise_model():
    """At gain 8 the direct path is noisy (seeded, so repeatable) and noiseless it is not."""
    scene = dead_leaves(32, seed=2)
    camera = cns.Camera.of("lms")
    (responses,), truth = cns.spectral_image(scene, [camera])
    quiet = cns.delta_e00(cns.direct(responses, camera, None), truth).mean()
    noisy = cns.direct(responses, camera, 8.0)
    assert np.array_equal(noisy, cns.direct(responses, camera, 8.0))
    assert cns.delta_e00(noisy, truth).mean() > quiet + 1.0
