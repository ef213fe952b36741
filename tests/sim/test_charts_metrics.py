"""Tests of the built-in charts (clisp.sim.charts) and the quality metrics (clisp.metrics)."""
from __future__ import annotations

import numpy as np
import pytest

from clisp import metrics
from clisp.sim import charts
from clisp.sim.colorimetry import srgb_decode

REC709_Y = np.array([0.2126, 0.7152, 0.0722])


@pytest.fixture(scope="module")
def demo() -> charts.Chart:
    return charts.demo_chart(seed=0)


# ---------------------------------------------------------------- charts

@pytest.mark.parametrize("make", [charts.zone_plate, charts.siemens_star, charts.dead_leaves])
def test_targets_shape_and_range(make) -> None:
    img = make(256)
    assert img.shape == (256, 256, 3) and img.dtype == np.float64
    assert img.min() >= 0.0 and img.max() <= 1.0


def test_colorchecker_layout() -> None:
    img, rois = charts.colorchecker()
    assert img.shape == (336, 496, 3)
    assert len(rois) == 24
    assert all((y1 - y0, x1 - x0) == (64, 64) for y0, y1, x0, x1 in rois)
    assert rois[0] == (16, 80, 16, 80) and rois[5] == (16, 80, 416, 480) and rois[6][0] == 96
    colours = charts.colorchecker_linear()
    for (y0, y1, x0, x1), c in zip(rois, colours):
        np.testing.assert_array_equal(img[y0:y1, x0:x1], np.broadcast_to(c, (64, 64, 3)))
    assert 0.0 <= img.min() and img.max() <= 1.0


def test_demo_chart_layout(demo: charts.Chart) -> None:
    h, w, c = demo.image.shape
    assert (h, w, c) == (608, 832, 3) and h % 4 == 0 and w % 4 == 0
    assert 0.3e6 <= h * w <= 0.52e6
    assert 0.0 <= demo.image.min() and demo.image.max() <= 1.0
    assert set(demo.regions) == {"colorchecker", "zone_plate", "siemens_star", "dead_leaves"}
    for y0, y1, x0, x1 in demo.regions.values():
        assert 0 <= y0 < y1 <= h and 0 <= x0 < x1 <= w
        assert all(v % 4 == 0 for v in (y0, y1, x0, x1))
    np.testing.assert_array_equal(demo.image[slice(*demo.regions["zone_plate"][:2]),
                                             slice(*demo.regions["zone_plate"][2:])],
                                  charts.zone_plate(256))
    assert len(demo.gray_rois) == 6
    assert all((y1 - y0, x1 - x0) == (32, 32) for y0, y1, x0, x1 in demo.gray_rois)
    assert len(demo.patch_rois) == 24
    for (gy0, gy1, gx0, gx1), k in zip(demo.gray_rois, charts.NEUTRAL_INDICES):
        py0, py1, px0, px1 = demo.patch_rois[k]
        assert (gy0 - py0, py1 - gy1, gx0 - px0, px1 - gx1) == (16, 16, 16, 16)


def test_gray_panels_match_spec(demo: charts.Chart) -> None:
    """Panels 1..6 (black -> white) are flat; their luminance Y matches charts.SPEC_NEUTRAL_LUMINANCE to 0.002.

    Per channel the colour-science data give (R, G, B) = (0.0314, 0.0315, 0.0323) ...
    (0.8792, 0.8848, 0.8350): within 0.01 of those except the white patch's blue (0.835 vs 0.8807).
    """
    means = np.array([demo.image[y0:y1, x0:x1].mean(axis=(0, 1)) for y0, y1, x0, x1 in demo.gray_rois])
    stds = np.array([demo.image[y0:y1, x0:x1].std(axis=(0, 1)) for y0, y1, x0, x1 in demo.gray_rois])
    assert np.all(stds < 1e-12)
    np.testing.assert_allclose(means @ REC709_Y, charts.SPEC_NEUTRAL_LUMINANCE, atol=0.002)
    np.testing.assert_allclose(means[:5], np.repeat(np.array(charts.SPEC_NEUTRAL_LUMINANCE[:5])[:, None], 3, 1),
                               atol=0.01)
    np.testing.assert_allclose(means[5], charts.SPEC_NEUTRAL_LUMINANCE[5], atol=0.05)
    assert np.all(np.diff(means @ REC709_Y) > 0)


def test_dead_leaves_deterministic() -> None:
    a, b, c = charts.dead_leaves(128, seed=3), charts.dead_leaves(128, seed=3), charts.dead_leaves(128, seed=4)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)
    assert a.std(axis=(0, 1)).min() > 0.05  # textured and coloured
    assert np.abs(a[..., 0] - a[..., 1]).mean() > 0.02


def test_zone_plate_neutral_and_reaches_nyquist() -> None:
    size = 256
    zp = charts.zone_plate(size)
    np.testing.assert_array_equal(zp[..., 0], zp[..., 1])
    np.testing.assert_array_equal(zp[..., 0], zp[..., 2])
    row = zp[size // 2, :, 0]

    def peak_frequency(segment: np.ndarray) -> float:
        spectrum = np.abs(np.fft.rfft((segment - segment.mean()) * np.hanning(segment.size)))
        return float(np.fft.rfftfreq(segment.size)[np.argmax(spectrum)])

    assert peak_frequency(row[-32:]) >= 0.43          # last 32 px: 0.4375 .. 0.5 cycles/px
    assert peak_frequency(row[size // 2 + 48:size // 2 + 80]) < 0.35
    # Encoded values span ~0.1..0.9 near the centre (low frequency, well sampled).
    centre = zp[size // 2 - 8:size // 2 + 8, size // 2 - 8:size // 2 + 8, 0]
    assert centre.max() == pytest.approx(float(srgb_decode(np.array(0.9))), rel=0.01)


def test_siemens_star_neutral_two_levels() -> None:
    st = charts.siemens_star(256, spokes=36)
    np.testing.assert_array_equal(st[..., 0], st[..., 2])
    disc = st[64:192, 64:192, 0]
    assert disc.min() == pytest.approx(0.05) and disc.max() == pytest.approx(0.75)
    assert np.mean(np.isclose(disc, 0.05) | np.isclose(disc, 0.75)) > 0.5


def test_chart_generation_fast() -> None:
    import time
    charts.colorchecker_linear()  # colour-science import, cached
    t = time.perf_counter()
    charts.demo_chart(seed=1)
    assert time.perf_counter() - t < 1.0


# ---------------------------------------------------------------- metrics

def _rng_image(shape=(64, 48, 3), seed=0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(0.05, 0.95, size=shape)


def test_psnr_identical_is_inf() -> None:
    img = _rng_image()
    assert metrics.psnr(img, img.copy()) == float("inf")
    assert metrics.psnr(img, img.copy(), tone_mapped=False) == float("inf")


def test_psnr_known_mse_linear_and_tone_mapped() -> None:
    truth = np.full((40, 40, 3), 0.5)
    out = truth + 0.01                       # MSE = 1e-4 everywhere -> 40 dB linear
    assert metrics.psnr(out, truth, tone_mapped=False) == pytest.approx(40.0, abs=1e-9)
    # Tone-mapped: in the encoded domain both are constants, so the MSE is their squared difference.
    enc = metrics.tone_map(np.array([0.51, 0.5]))
    expected = 10 * np.log10(1.0 / (enc[0] - enc[1]) ** 2)
    assert metrics.psnr(out, truth) == pytest.approx(expected, abs=1e-9)


def test_psnr_clips_to_unit_range() -> None:
    truth = np.ones((30, 30, 3))
    assert metrics.psnr(truth * 1.5, truth, tone_mapped=False) == float("inf")
    assert metrics.psnr(truth * 1.5, truth) == float("inf")


def test_psnr_border_is_honoured() -> None:
    truth = _rng_image((64, 64, 3), seed=1)
    out = truth + 0.02 * np.random.default_rng(2).standard_normal(truth.shape)
    ref = metrics.psnr(out, truth)
    spoiled = out.copy()
    spoiled[:10] = 0.0
    spoiled[-10:] = 1.0
    spoiled[:, :10] = 1.0
    spoiled[:, -10:] = 0.0
    assert metrics.psnr(spoiled, truth) == ref
    assert metrics.psnr(spoiled, truth, border=9) < ref - 5


def test_psnr_region() -> None:
    truth = np.full((64, 64, 3), 0.5)
    out = truth.copy()
    out[20:30, 20:30] += 0.1
    assert metrics.psnr(out, truth, region=(0, 20, 0, 64), tone_mapped=False) == float("inf")
    # Region scores exactly its crop (no border inside it): MSE = 0.01 over 10x10 of a 20x20 crop.
    val = metrics.psnr(out, truth, region=(15, 35, 15, 35), tone_mapped=False)
    assert val == pytest.approx(10 * np.log10(1 / (0.01 * 100 / 400)), abs=1e-9)
    with pytest.raises(ValueError):
        metrics.psnr(out, truth[:, :32])


def test_panel_snr_known_mean_std() -> None:
    img = np.zeros((20, 20, 3))
    # Checkerboard +-d around m has population std exactly d.
    checker = np.where((np.indices((8, 8)).sum(axis=0) % 2) == 0, 1.0, -1.0)
    for c, (m, d) in enumerate([(0.5, 0.05), (0.2, 0.002), (0.8, 0.4)]):
        img[4:12, 6:14, c] = m + d * checker
    snr = metrics.panel_snr(img, [(4, 12, 6, 14)])
    assert snr.shape == (1, 3)
    np.testing.assert_allclose(snr[0], [20.0, 40.0, 20 * np.log10(2.0)], atol=1e-9)
    gray = metrics.gray_panel_snr(img, [(4, 12, 6, 14), (4, 12, 6, 14)])
    assert gray.shape == (2,)
    np.testing.assert_allclose(gray, np.mean([20.0, 40.0, 20 * np.log10(2.0)]), atol=1e-9)


def test_gray_panel_snr_on_noisy_chart(demo: charts.Chart) -> None:
    rng = np.random.default_rng(0)
    sigma = 0.01
    noisy = demo.image + sigma * rng.standard_normal(demo.image.shape)
    snr = metrics.gray_panel_snr(noisy, demo.gray_rois)
    expected = 20 * np.log10(np.array(charts.SPEC_NEUTRAL_LUMINANCE) / sigma)
    assert snr.shape == (6,) and np.all(np.diff(snr) > 0)
    np.testing.assert_allclose(snr, expected, atol=0.6)


def test_ciede2000() -> None:
    truth = _rng_image((16, 16, 3), seed=5)
    assert metrics.ciede2000(truth, truth.copy()) == pytest.approx(0.0, abs=1e-9)
    lab_white = metrics.linear_srgb_to_lab(np.ones(3))
    np.testing.assert_allclose(lab_white, [100.0, 0.0, 0.0], atol=1e-9)
    shifted = truth.copy()
    shifted[..., 0] *= 1.2
    de = metrics.ciede2000(shifted, truth)
    assert 0.5 < de < 20
    assert metrics.ciede2000(shifted, truth, region=(0, 8, 0, 16)) > 0


def test_zone_plate_linear_encoding() -> None:
    """encoding="linear": the same cosine in linear values (range lo..hi, mean (lo+hi)/2 off-disc);
    an unknown encoding is an error."""
    lin = charts.zone_plate(64, encoding="linear")
    assert lin.min() == pytest.approx(0.1, abs=0.01) and lin.max() == pytest.approx(0.9, abs=0.01)
    assert lin[0, 0, 0] == pytest.approx(0.5)
    np.testing.assert_allclose(srgb_decode(lin), charts.zone_plate(64), rtol=1e-12)
    with pytest.raises(ValueError):
        charts.zone_plate(64, encoding="gamma")
