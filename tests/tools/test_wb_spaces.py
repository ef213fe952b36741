"""tools/wb_spaces.py (issue 42, the metric's floor) on scenes made in code: under D65 itself every
space leaves the D65 processing as it is, and under another light each space makes the light's own
white grey."""
from __future__ import annotations

import sys

import numpy as np

from paths import TOOLS

sys.path.insert(0, str(TOOLS))

import wb_spaces  # noqa: E402  (tools/ is not a package)
from colour_natural_spectra import Camera  # noqa: E402
from clisp.sim.charts import dead_leaves  # noqa: E402
from clisp.sim.spectral import WAVELENGTHS, illuminant_d65, srgb_to_reflectance  # noqa: E402


def _seen(camera: Camera, refl: np.ndarray, power: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    scale = float((illuminant_d65() @ camera.sens).max())
    return (refl * power) @ camera.sens / scale, (np.ones(WAVELENGTHS.size) * power) @ camera.sens / scale


def test_daylight_itself_is_left_as_it_is():
    """The 6504 K daylight is D65, and undoing it in any space is the plain D65 processing."""
    d65 = illuminant_d65()
    assert np.allclose(wb_spaces.light_spectrum("6504 K") / d65[WAVELENGTHS == 560],
                       d65 / d65[WAVELENGTHS == 560], rtol=2e-3)
    refl = srgb_to_reflectance(dead_leaves(32, seed=2).reshape(-1, 3))
    for kind in ("lms", "bayer"):
        camera = Camera.of(kind)
        raw, white = _seen(camera, refl, d65)
        for space, out in wb_spaces.undone(raw, white, camera).items():
            assert np.allclose(out, camera.to_srgb(raw), atol=1e-9), (kind, space)


def test_each_space_makes_the_lights_white_grey():
    """Under tungsten (CIE A) a perfect white comes out neutral whichever space undoes the light."""
    power = wb_spaces.light_spectrum("A")
    white_refl = np.ones((1, WAVELENGTHS.size))
    for kind in ("lms", "bayer"):
        camera = Camera.of(kind)
        raw, white = _seen(camera, white_refl, power)
        for space, out in wb_spaces.undone(raw, white, camera).items():
            assert np.ptp(out[0] / out[0].mean()) < 1e-9, (kind, space, out)
