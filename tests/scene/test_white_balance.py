"""White balance pass 1 on the raw mosaic: gray world, grey pixels (``--wb auto``), the choice."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from clisp.cfa import bayer_cfa, lms_cfa
from clisp.errors import ClispError
from clisp.sim.simulate import simulate
from clisp.scene.white_balance import gray_world_gains, grey_pixel_gains, reference_channel, with_white_balance
from clisp.io.rawimage import NO_CAMERA_WB
from clisp.scene.measure import measure_scene
from clisp.scene.noise import has_noise_model


@pytest.mark.parametrize("cfa", [bayer_cfa("GRBG"), lms_cfa()], ids=lambda c: c.name)
def test_gray_world_recovers_channel_gains(cfa) -> None:
    rng = np.random.default_rng(1)
    true_gains = np.array([2.0, 1.0, 1.6]) if cfa.kind == "bayer" else np.array([1.0, 1.2, 3.1])
    scene = rng.uniform(0.05, 0.4, size=(64, 96))           # the same grey world in every channel
    channel = cfa.channel_map(64, 96)
    data = 64 + 900 * scene / true_gains[channel]
    data[10:14, 20:24] = 1023                               # a clipped highlight must not bias it
    gains = gray_world_gains(data, cfa, np.full(3, 64.0), 1023)
    assert np.allclose(gains, true_gains, rtol=0.03)


def test_all_clipped_is_an_error() -> None:
    with pytest.raises(ClispError, match="clipped"):
        gray_world_gains(np.full((8, 8), 1023.0), bayer_cfa(), np.zeros(3), 1023)


# --------------------------------------------------------------------------------------------
# --wb: grey pixels (auto), daylight, multipliers
# --------------------------------------------------------------------------------------------

def _wood_and_steel(height: int = 192, width: int = 256) -> np.ndarray:
    """A scene gray world gets wrong (linear sRGB, H x W x 3): a textured orange surface over
    three quarters of the frame (grain: shading that changes all channels in proportion) and a
    neutral object with edges (grey and white bars on black) on the rest."""
    rng = np.random.default_rng(7)
    y, x = np.mgrid[0:height, 0:width]
    grain = 0.75 + 0.25 * np.sin(x / 5.0 + 2.0 * np.sin(y / 23.0)) + 0.03 * rng.standard_normal((height, width))
    scene = grain[..., None] * np.array([0.45, 0.22, 0.08])
    steel = x >= 3 * width // 4
    bars = np.where((y // 12) % 2 == 0, 0.02, 0.2 + 0.6 * ((y // 24) % 3) / 2.0)
    scene[steel] = bars[steel][:, None] * np.ones(3)
    return scene


def _angle(gains: np.ndarray, truth: np.ndarray) -> float:
    """Angle in degrees between the illuminants (1 / gains) two sets of multipliers imply."""
    a, b = 1.0 / np.asarray(gains), 1.0 / np.asarray(truth)
    return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1.0, 1.0))))


@pytest.mark.parametrize("kind", ["bayer", "lms"])
def test_grey_pixels_find_the_light_where_gray_world_does_not(kind) -> None:
    """The simulated raw's multipliers are the known (D65) ones: grey pixels come within 2 degrees
    of them on the wood-and-steel scene, gray world (pulled by the orange) is off by more than 5."""
    raw = simulate(_wood_and_steel(), kind, gain=4, optics="none", seed=3).raw
    gains, how = grey_pixel_gains(raw.data, raw.cfa, raw.black_level, raw.white_level)
    assert how == "auto (grey pixels)"
    assert gains[reference_channel(raw.cfa)] == 1.0
    assert _angle(gains, raw.wb) < 2.0
    assert _angle(gray_world_gains(raw.data, raw.cfa, raw.black_level, raw.white_level), raw.wb) > 5.0


def test_a_flat_field_falls_back_to_gray_world() -> None:
    raw = simulate(np.full((64, 64, 3), 0.3), "bayer", gain=None, optics="none").raw
    gains, how = grey_pixel_gains(raw.data, raw.cfa, raw.black_level, raw.white_level)
    assert how.startswith("gray world")
    assert np.allclose(gains, gray_world_gains(raw.data, raw.cfa, raw.black_level, raw.white_level))


def test_with_white_balance_choices() -> None:
    raw = simulate(_wood_and_steel(64, 96), "bayer", gain=4, optics="none").raw
    assert with_white_balance(raw, "camera") is raw
    daylight = with_white_balance(raw, "daylight")                # a simulation: its own D65 multipliers
    assert np.allclose(daylight.wb, raw.wb) and daylight.metadata["wb_source"] == "daylight"
    chosen = with_white_balance(raw, "4,2,3")
    assert np.allclose(chosen.wb, [2.0, 1.0, 1.5]) and chosen.metadata["wb_source"] == "multipliers (--wb)"
    assert np.array_equal(chosen.data, raw.data) and raw.metadata.get("wb_source") is None   # raw untouched
    auto = with_white_balance(raw, "auto")
    assert auto.metadata["wb_source"].startswith("auto (") and not np.allclose(auto.wb, raw.wb, rtol=1e-6)
    unknown = with_white_balance(replace(raw, metadata={}), "auto")    # no known D65 white: grey pixels
    assert unknown.metadata["wb_source"] == "auto (grey pixels)" and "no daylight" in unknown.metadata["wb_explain"]
    camera_like = replace(raw, metadata={"daylight_multipliers": [2.2, 1.0, 1.4]})
    assert np.allclose(with_white_balance(camera_like, "daylight").wb, [2.2, 1.0, 1.4])
    with pytest.raises(ClispError, match="has no daylight white balance"):
        with_white_balance(replace(raw, metadata={}), "daylight")
    for bad in ("2,1", "a,b,c", "2,0,1", "1e9,1,1", "nan,1,1", "autp"):
        with pytest.raises(ClispError, match="--wb"):
            with_white_balance(raw, bad)


def test_wb_reaches_the_pipeline_and_the_output(tmp_path) -> None:
    """--wb changes pass 1's gains (the output's colour) and the output's description says so."""
    from clisp.app.cli import main
    from clisp.io.imageio import read_image
    from clisp.io.rawfile import write_raw
    import OpenImageIO as oiio
    raw = simulate(_wood_and_steel(64, 96), "bayer", gain=4, optics="none").raw
    write_raw(tmp_path / "r.dng", raw)
    outputs = {}
    for wb in ("camera", "2,1,1"):
        out = tmp_path / f"{wb}.tif"
        assert main(["process", str(tmp_path / "r.dng"), "-o", str(out), "--wb", wb, "--preset", "fast"]) == 0
        outputs[wb] = read_image(out)[0].reshape(-1, 3).mean(axis=0)
        note = oiio.ImageInput.open(str(out)).spec().getattribute("ImageDescription") or ""
        assert ("white balance multipliers (--wb)" in note) == (wb != "camera")
    assert outputs["2,1,1"][0] > outputs["camera"][0] * 1.02        # R multiplier 2 against the camera's


def test_explain_says_what_auto_found(tmp_path, capsys) -> None:
    """``--explain`` prints auto's light, its confidence and what decided it."""
    from clisp.app.cli import main
    from clisp.io.rawfile import write_raw
    write_raw(tmp_path / "r.dng", simulate(_wood_and_steel(64, 96), "bayer", gain=4, optics="none").raw)
    assert main(["process", str(tmp_path / "r.dng"), "-o", str(tmp_path / "a.tif"), "--wb", "auto", "--explain",
                 "--preset", "fast"]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("explain: white balance auto: "))
    assert " K, Duv " in line and "confidence" in line and "decided by" in line


def test_a_raw_without_camera_white_balance_gets_its_grey_pixels_in_the_run() -> None:
    """Reading decides nothing (clisp.io.camera leaves NO_CAMERA_WB and a placeholder); the run's
    ``--wb camera`` measures the scene once and takes its grey pixels, from the statistics' thumbnail."""
    raw = simulate(_wood_and_steel(), "bayer", gain=4, optics="none", seed=3).raw
    unknown = replace(raw, wb=np.ones(3), metadata={**raw.metadata, "wb_source": NO_CAMERA_WB})
    scene = measure_scene(unknown)
    assert scene.raw.metadata["wb_source"] == "auto (grey pixels), file has no camera WB"
    assert scene.statistics is not None and _angle(scene.raw.wb, raw.wb) < 2.0
    assert with_white_balance(raw, "camera") is raw and measure_scene(raw).statistics is None


def test_a_run_that_reads_the_thumbnail_alone_reads_nothing_more() -> None:
    """Without a noise estimate to make (the fast preset), a raw without camera white balance has its
    cell thumbnail read alone, the cells the whole pass reads, so the same gains; a noise estimate
    (a raw without a sensor model) reads the whole pass, and an estimate asking for the table after
    a thumbnail-only read gets the whole pass then."""
    raw = simulate(_wood_and_steel(), "bayer", gain=4, optics="none", seed=3).raw
    camera = {k: v for k, v in raw.metadata.items() if k not in ("noise", "gain")}   # a camera raw: no model
    unknown = replace(raw, wb=np.ones(3), metadata={**camera, "wb_source": NO_CAMERA_WB})
    assert not has_noise_model(unknown)
    alone, whole = measure_scene(unknown), measure_scene(unknown, noise=True)
    assert not alone.statistics.complete and alone.statistics.table is None and not alone.statistics.strips
    assert whole.statistics.complete and whole.statistics.table is not None and whole.noise is not None
    assert np.array_equal(alone.raw.wb, whole.raw.wb)
    assert np.array_equal(alone.statistics.cells, whole.statistics.cells)
    assert alone.measured().complete and alone.measured().table is not None


@pytest.mark.parametrize("shape", [(37, 53), (4, 5), (1, 9)])
def test_grey_pixel_filters_equal_scipy(shape) -> None:
    """The grey-pixel search's NumPy filters against scipy.ndimage, which they stand in for (its
    import cost 0.4 s of every run of a raw without camera white balance)."""
    from scipy import ndimage
    from clisp.scene.white_balance import box_mean, eroded, gradient_magnitude
    rng = np.random.default_rng(sum(shape))
    a = rng.random(shape)
    mask = rng.random(shape) > 0.15
    np.testing.assert_allclose(gradient_magnitude(a, 0.5), ndimage.gaussian_gradient_magnitude(a, 0.5, mode="nearest"),
                               rtol=0, atol=1e-12)
    np.testing.assert_allclose(box_mean(a, 7), ndimage.uniform_filter(a, 7, mode="nearest"), rtol=0, atol=1e-12)
    assert np.array_equal(eroded(mask, 2), ndimage.binary_erosion(mask, iterations=2, border_value=1))


def test_the_grey_pixel_estimate_imports_no_scipy() -> None:
    """A raw without camera white balance gets its grey pixels without importing scipy.ndimage."""
    import subprocess
    import sys
    code = ("import sys, numpy as np; from clisp.sim.simulate import simulate; "
            "from clisp.scene.white_balance import grey_pixel_gains; "
            "r = simulate(np.random.default_rng(0).random((64, 96, 3)), cfa='bayer', gain=4, seed=1, optics='none').raw; "
            "grey_pixel_gains(r.data, r.cfa, r.black_level, r.white_level); "
            "print('scipy.ndimage' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False", out.stdout + out.stderr


def test_percentile_and_channel_mean_are_numpys_bit_for_bit():
    """The grey-pixel search's percentile and channel mean, written to skip NumPy's costs, give
    NumPy's own values exactly (random sizes, scales and percentiles)."""
    from clisp.scene.white_balance import channel_mean, every_channel_above, percentile_linear, row_sum
    rng = np.random.default_rng(42)
    for _ in range(400):
        values = rng.random(int(rng.integers(1, 3000))) * rng.choice([1e-3, 1.0, 1e3])
        q = float(rng.choice([0.0, 1.0, 50.0, 99.0, 100.0, rng.random() * 100]))
        assert percentile_linear(values, q) == np.percentile(values, q)
    planes = rng.random((64, 96, 3))
    assert np.array_equal(channel_mean(planes), planes.mean(axis=-1))
    assert np.array_equal(every_channel_above(planes, 0.3), np.all(planes > 0.3, axis=-1))
    pairs = rng.random((500, 2)) - 0.5
    assert np.array_equal(row_sum(pairs), pairs.sum(axis=1)) and np.array_equal(row_sum(planes), planes.sum(axis=-1))
