"""White balance ``auto``'s light (clisp.scene.illuminant): the lights, the block statistics, the estimate."""
from __future__ import annotations

import numpy as np
import pytest

from clisp.cfa import bayer_cfa
from clisp.scene.illuminant import CameraLights, block_statistics, estimate_light, light_srgb
from clisp.sim.simulate import simulate
from clisp.scene.white_balance import gray_world_gains, reference_channel, with_white_balance


def _lit(scene: np.ndarray, kelvin: float) -> tuple[np.ndarray, np.ndarray]:
    """(scene times the light of ``kelvin`` on the locus, largest channel 1; that light)."""
    w = light_srgb(np.array(kelvin))
    w = w / w.max()
    return scene * w, w


def _output_angle(raw, gains: np.ndarray, light: np.ndarray) -> float:
    """Degrees between the linear sRGB a white surface gets with ``gains`` and with the light's own
    multipliers (the colour cast ``gains`` leave on a neutral, as the output shows it)."""
    lights = CameraLights(raw.colour_matrix, raw.wb)
    white = lights.balanced(light) / raw.wb                          # the raw's response to white
    a = (white * gains) @ raw.colour_matrix.T
    true = lights.gains(light)
    b = (white * true / true[reference_channel(raw.cfa)]) @ raw.colour_matrix.T
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))


def _espresso(height: int = 192, width: int = 256) -> np.ndarray:
    """Linear sRGB under D65: warm wood with grain over the frame, a brown saucer and a white cup
    (shaded, one side brighter) on it: the photo whose old ``auto`` came out cyan (issue 42)."""
    rng = np.random.default_rng(4)
    y, x = np.mgrid[0:height, 0:width]
    grain = 0.8 + 0.2 * np.sin(x / 3.0 + 3.0 * np.sin(y / 17.0)) + 0.03 * rng.standard_normal((height, width))
    scene = grain[..., None] * np.array([0.42, 0.20, 0.07])
    saucer = ((y - 100) / 60.0) ** 2 + ((x - 128) / 90.0) ** 2 <= 1.0
    scene[saucer] = np.array([0.20, 0.09, 0.04]) * grain[saucer][:, None]
    cup = ((y - 90) / 40.0) ** 2 + ((x - 128) / 45.0) ** 2 <= 1.0
    shade = np.clip(1.0 - 0.5 * (x - 128) / 45.0, 0.35, 1.0)
    scene[cup] = np.array([0.80, 0.80, 0.78]) * shade[cup][:, None]
    return scene


def _grey_chart(height: int = 192, width: int = 256) -> np.ndarray:
    """Linear sRGB: six neutral patches (reflectance 0.04..0.9) on a mid-grey board, gently shaded."""
    y, x = np.mgrid[0:height, 0:width]
    scene = np.full((height, width), 0.18) * (1.0 - 0.2 * x / width)
    for i, level in enumerate((0.9, 0.59, 0.36, 0.19, 0.09, 0.04)):
        scene[60:130, 12 + 40 * i:44 + 40 * i] = level
    return scene[..., None] * np.ones(3)


def test_the_lights_are_daylight_at_d65_and_warm_below() -> None:
    d65 = light_srgb(np.array(6504.0))
    assert np.allclose(d65 / d65[1], 1.0, atol=0.01)
    warm, cool = light_srgb(np.array(3000.0)), light_srgb(np.array(9000.0))
    assert warm[0] > warm[1] > warm[2] and cool[2] > cool[1] > cool[0]
    seam = light_srgb(np.array([3990.0, 4000.0, 4010.0]))           # the locus is continuous where it joins
    assert np.abs(np.diff(seam / seam[:, 1:2], axis=0)).max() < 0.01
    lights = CameraLights(np.array([[1.6, -0.4, -0.2], [-0.3, 1.5, -0.2], [0.0, -0.5, 1.5]]), np.array([2.0, 1.0, 1.5]))
    assert np.allclose(lights.gains(np.ones(3)), [2.0, 1.0, 1.5])    # D65 white: the daylight multipliers


def test_block_statistics_leave_clipped_cells_out() -> None:
    cfa = bayer_cfa("RGGB")
    data = np.full((64, 64), 200.0)
    data[0:2, 0:2] = 1023.0                                          # one clipped cell
    stats = block_statistics(data, cfa, np.zeros(3), 1023.0, block=4)
    assert stats.count.shape == (8, 8) and stats.clipped[0, 0] == 1 and stats.count[0, 0] == 15
    assert np.allclose(stats.sum[0, 0], 15 * 200.0 / 1023.0)
    assert stats.grey_weight.sum() == 0                              # a flat field has no edges


@pytest.mark.parametrize("kind", ["bayer", "lms"])
def test_one_warm_surface_does_not_turn_cyan(kind) -> None:
    """Wood fills the frame under D65; the white cup and the prior keep ``auto`` near daylight,
    where gray world takes the wood for the light (a cyan cast of many degrees; the grey pixels of
    ``auto`` before issue 42 were 35 degrees off on the Bayer raw)."""
    raw = simulate(_espresso(), kind, gain=1, optics="none", seed=2).raw
    estimate = estimate_light(block_statistics(raw.data, raw.cfa, raw.black_level, raw.white_level),
                              CameraLights(raw.colour_matrix, raw.wb), reference_channel(raw.cfa))
    assert 4800.0 < estimate.temperature < 9000.0
    assert _output_angle(raw, estimate.gains, np.ones(3)) < 3.0
    world = gray_world_gains(raw.data, raw.cfa, raw.black_level, raw.white_level)   # the wood's colour as the light
    assert _output_angle(raw, world, np.ones(3)) > 10.0


@pytest.mark.parametrize("kelvin", [2856.0, 3200.0])
def test_a_tungsten_lit_grey_chart_is_found(kelvin) -> None:
    scene, light = _lit(_grey_chart(), kelvin)
    raw = simulate(scene, "bayer", gain=4, optics="none", seed=5).raw
    estimate = estimate_light(block_statistics(raw.data, raw.cfa, raw.black_level, raw.white_level),
                              CameraLights(raw.colour_matrix, raw.wb), reference_channel(raw.cfa))
    assert abs(1e6 / estimate.temperature - 1e6 / kelvin) < 15.0      # mired
    assert _output_angle(raw, estimate.gains, light) < 1.5
    assert estimate.confidence > 0.5 and "grey edges" in estimate.describe()


def test_auto_says_what_it_found_and_why() -> None:
    scene, _ = _lit(_grey_chart(), 3200.0)
    raw = simulate(scene, "lms", gain=1, optics="none", seed=1).raw
    auto = with_white_balance(raw, "auto")
    assert auto.metadata["wb_source"].startswith("auto (") and auto.metadata["wb_source"].endswith(" K)")
    line = auto.metadata["wb_explain"]
    assert line.startswith("white balance auto: ") and "confidence" in line and "decided by" in line
    assert auto.wb[reference_channel(raw.cfa)] == 1.0
