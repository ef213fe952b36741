"""Tests of the raw simulator: optics kernel, noise model, mosaic layout (docs/model.md sections 1-3)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from clisp.cfa import cfa_from_name
from clisp.sim.colorimetry import camera_constants
from clisp.errors import ClispError
from clisp.sim.noise import NoiseModel
from clisp.sim.optics import airy_kernel, apply_optics
from clisp.sim.simulate import inverse_isp_matrix, simulate

BL, WL = 64.0, 1023.0
RANGE = WL - BL
SPEC_CENTRE = np.array([[.01096, .05252, .01096],
                        [.05252, .68125, .05252],
                        [.01096, .05252, .01096]])
BAYER_NAMES = ("bayer-rggb", "bayer-grbg", "bayer-gbrg", "bayer-bggr")
N_SIGMA = 5.0


# ----------------------------------------------------------------------------- helpers

def expected_raw(colour: np.ndarray, kind: str) -> np.ndarray:
    """Exposed raw channel values of a linear sRGB colour, computed straight from docs/model.md section 2."""
    matrix, wb = camera_constants(kind)
    inv = np.linalg.inv(matrix)
    k_exp = 1.0 / np.max(inv @ np.ones(3) / wb)
    return k_exp * (inv @ np.asarray(colour, dtype=np.float64)) / wb


def spec_channel(name: str, y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Channel index at (y, x) from the rules of docs/model.md section 1, independent of clisp.cfa's tables."""
    if name.startswith("lms"):
        dy, dx = (0, 0) if name == "lms" else (int(v) for v in name[4:].split(","))
        yy, xx = y + dy, x + dx
        s_site = (yy % 2 == 0) & ((xx - yy) % 4 == 3)
        return np.where((xx + yy) % 2 == 0, 0, np.where(s_site, 2, 1))
    letters = name.split("-")[1].upper()
    lookup = np.array(["RGB".index(ch) for ch in letters]).reshape(2, 2)
    return lookup[y % 2, x % 2]


def assert_moments(samples: np.ndarray, mean: float, var: float, label: str) -> None:
    """Sample mean and variance agree with the model within N_SIGMA standard errors."""
    x = samples.astype(np.float64).ravel()
    n = x.size
    m = x.mean()
    v = x.var(ddof=1)
    m4 = np.mean((x - m) ** 4)
    se_mean = np.sqrt(var / n)
    se_var = np.sqrt(max(m4 - v * v, 2 * v * v) / n)
    assert abs(m - mean) < N_SIGMA * se_mean, f"{label}: mean {m:.4f} vs model {mean:.4f} (se {se_mean:.4f})"
    assert abs(v - var) < N_SIGMA * se_var, f"{label}: var {v:.4f} vs model {var:.4f} (se {se_var:.4f})"


# ----------------------------------------------------------------------------- optics

def test_airy_kernel_matches_spec():
    k = airy_kernel()
    assert k.shape == (9, 9) and k.dtype == np.float64
    assert abs(k.sum() - 1.0) < 1e-12
    np.testing.assert_allclose(k[3:6, 3:6], SPEC_CENTRE, atol=1e-4)
    np.testing.assert_allclose(k, k.T, atol=1e-15)
    np.testing.assert_allclose(k, k[::-1, ::-1], atol=1e-15)
    assert abs(k[3:6, 3:6].sum() - 0.935) < 1e-3
    assert abs(k[2:7, 2:7].sum() - 0.974) < 1e-3


def test_airy_kernel_r0_widens_psf():
    assert airy_kernel(r0=2.0)[4, 4] < airy_kernel(r0=1.0)[4, 4]
    assert abs(airy_kernel(r0=2.0).sum() - 1.0) < 1e-12


def test_apply_optics_impulse_and_flat():
    k = airy_kernel()
    img = np.zeros((15, 17, 3))
    img[7, 8, :] = 1.0
    out = apply_optics(img, k)
    assert out.dtype == np.float64 and out.shape == img.shape
    for c in range(3):
        np.testing.assert_allclose(out[3:12, 4:13, c], k, atol=1e-15)
    flat = np.full((10, 12, 3), 0.37)
    np.testing.assert_allclose(apply_optics(flat, k), flat, atol=1e-14)


# ----------------------------------------------------------------------------- constants

def test_exposure_constants():
    a_lms, k_lms = inverse_isp_matrix("lms")
    a_bay, k_bay = inverse_isp_matrix("bayer")
    assert abs(k_lms - 0.98951) < 1e-5
    assert abs(k_bay - 1.0) < 1e-12
    np.testing.assert_allclose(a_lms @ np.ones(3), np.array([1.0106, 0.8329, 0.3393]) * k_lms, atol=1e-4)
    assert abs(np.max(a_lms @ np.ones(3)) - 1.0) < 1e-12


@pytest.mark.parametrize("gain, n_fs", [(1, 6850), (4, 1712), (8, 856), (16, 428), (32, 214), (64, 107)])
def test_full_scale_electrons(gain, n_fs):
    assert abs(NoiseModel().full_scale_electrons(gain) - n_fs) < 1.0


# ----------------------------------------------------------------------------- noise model

@pytest.mark.parametrize("gain", [1, 8, 64])
@pytest.mark.parametrize("level", [0.02, 0.2, 0.6])
def test_noise_model_flat_field_moments(gain, level):
    model = NoiseModel()
    dn = model.sample(np.full((256, 256), level), gain, np.random.default_rng([gain, int(level * 100)]))
    assert dn.dtype == np.uint16
    c = 0.14 * gain
    n_e = level * model.full_scale_electrons(gain)
    mean, var = c * n_e + BL, c * c * (n_e + 1.5 ** 2) + 1.0 / 12.0
    m_model, v_model = model.expected_dn_mean_var(level, gain)
    assert abs(m_model - mean) < 1e-9 and abs(v_model - var) < 1e-9
    assert_moments(dn, mean, var, f"gain {gain} level {level}")


@pytest.mark.parametrize("cfa", ["lms", "bayer"])
@pytest.mark.parametrize("gain", [1, 8, 64])
@pytest.mark.parametrize("grey", [0.05, 0.5])
def test_simulated_flat_grey_moments(cfa, gain, grey):
    sim = simulate(np.full((256, 256, 3), grey), cfa=cfa, gain=gain, optics="none", seed=7)
    raw = sim.raw
    model = NoiseModel()
    levels = expected_raw(np.full(3, grey), raw.cfa.kind)
    channel_of = raw.cfa.channel_map(*raw.shape)
    for ch in range(3):
        sites = raw.data[channel_of == ch]
        mean, var = model.expected_dn_mean_var(levels[ch], gain)
        assert_moments(sites, float(mean), float(var), f"{cfa} ch {ch} gain {gain} grey {grey}")
        # The same data in normalised white-balanced units against NoiseModel.variance.
        w = raw.pass1_gains()[ch]
        s = (sites.astype(np.float64) - BL) / RANGE * w
        assert_moments(s, levels[ch] * w, float(model.variance(levels[ch] * w, gain, w)),
                       f"{cfa} ch {ch} gain {gain} normalised")


def test_variance_matches_dn_model():
    model = NoiseModel()
    for gain in (1, 4, 64):
        for level in (0.0, 0.1, 0.9):
            _, var_dn = model.expected_dn_mean_var(level, gain)
            assert abs(model.variance(level, gain) - var_dn / RANGE ** 2) < 1e-15
            w = 3.1397
            assert abs(model.variance(level * w, gain, w) - w * w * var_dn / RANGE ** 2) < 1e-15


def test_noise_model_dict_round_trip():
    model = NoiseModel(read_noise_e=2.0, black_level=32)
    d = model.to_dict()
    assert json.loads(json.dumps(d)) == d
    assert NoiseModel.from_dict(d) == model
    assert NoiseModel.from_dict({}) == NoiseModel()
    with pytest.raises(ClispError):
        NoiseModel(black_level=2000)


# ----------------------------------------------------------------------------- clipping, quantisation

@pytest.mark.parametrize("cfa", ["lms", "bayer"])
@pytest.mark.parametrize("gain", [1, 64])
def test_overexposed_scene_saturates_at_white_level(cfa, gain):
    sim = simulate(np.full((64, 64, 3), 10.0), cfa=cfa, gain=gain, seed=3)
    assert sim.raw.data.dtype == np.uint16
    assert np.all(sim.raw.data == 1023)


def test_dark_values_clip_at_zero_without_wraparound():
    model = NoiseModel(black_level=0)
    dn = model.sample(np.full((128, 128), -0.5), 64, np.random.default_rng(5))
    assert dn.dtype == np.uint16 and dn.min() == 0 and dn.max() < 200
    assert 0.4 < np.mean(dn == 0) < 0.6
    dark = simulate(np.zeros((128, 128, 3)), gain=64, seed=5).raw.data
    assert dark.min() >= 0 and abs(dark.mean() - BL) < 1.0


def test_noisy_data_are_quantised_in_range():
    rng = np.random.default_rng(9)
    scene = rng.uniform(0.0, 1.2, size=(96, 96, 3))
    data = simulate(scene, cfa="lms", gain=4, seed=2).raw.data
    assert data.dtype == np.uint16
    assert data.min() >= 0 and data.max() <= 1023
    assert len(np.unique(data)) > 100


# ----------------------------------------------------------------------------- noiseless path

@pytest.mark.parametrize("cfa", ["lms", "bayer-grbg"])
def test_noiseless_equals_closed_form(cfa):
    rng = np.random.default_rng(11)
    scene = rng.uniform(0.0, 1.5, size=(32, 48, 3))
    sim = simulate(scene, cfa=cfa, gain=None, optics="none")
    data = sim.raw.data
    assert data.dtype == np.float32
    assert data.max() > 1023          # not clipped
    kind = sim.raw.cfa.kind
    channel_of = sim.raw.cfa.channel_map(32, 48)
    raw_all = np.stack([expected_raw(px, kind) for px in scene.reshape(-1, 3)]).reshape(32, 48, 3)
    want = np.take_along_axis(raw_all, channel_of[..., None].astype(np.intp), axis=2)[..., 0] * RANGE + BL
    np.testing.assert_allclose(data, want, rtol=1e-6, atol=1e-4)
    np.testing.assert_allclose(sim.truth, scene, rtol=1e-6, atol=1e-7)
    assert sim.truth.dtype == np.float32


def test_noiseless_above_white_exceeds_white_level():
    sim = simulate(np.full((16, 16, 3), 1.5), cfa="lms", gain=None)
    channel_of = sim.raw.cfa.channel_map(16, 16)
    l_sites = sim.raw.data[channel_of == 0]
    np.testing.assert_allclose(l_sites, 1.5 * RANGE + BL, rtol=1e-6)
    assert l_sites.min() > 1023


def test_noiseless_with_airy_optics():
    rng = np.random.default_rng(12)
    scene = rng.uniform(0.0, 1.0, size=(24, 28, 3)).astype(np.float32)
    sim = simulate(scene, cfa="bayer", gain=None, optics="airy", r0=1.0)
    blurred = apply_optics(scene.astype(np.float64), airy_kernel(1.0))
    np.testing.assert_allclose(sim.truth, blurred, rtol=1e-6, atol=1e-7)
    a, _ = inverse_isp_matrix("bayer")
    channel_of = sim.raw.cfa.channel_map(24, 28)
    want = np.einsum("yxj,yxj->yx", a[channel_of], blurred) * RANGE + BL
    np.testing.assert_allclose(sim.raw.data, want, rtol=1e-6)


# ----------------------------------------------------------------------------- reproducibility

def test_seeded_reproducibility():
    scene = np.full((64, 64, 3), 0.3)
    a = simulate(scene, gain=8, seed=1).raw.data
    b = simulate(scene, gain=8, seed=1).raw.data
    c = simulate(scene, gain=8, seed=2).raw.data
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    assert np.array_equal(simulate(scene, seed=1).raw.data, simulate(scene, seed=2).raw.data)


# ----------------------------------------------------------------------------- layout

@pytest.mark.parametrize("name", ("lms", "lms@1,2") + BAYER_NAMES)
def test_channel_layout_of_flat_colour(name):
    colour = np.array([0.3, 0.5, 0.7])
    h, w = 12, 16
    sim = simulate(np.broadcast_to(colour, (h, w, 3)).copy(), cfa=name, gain=None)
    kind = "lms" if name.startswith("lms") else "bayer"
    levels = expected_raw(colour, kind)
    assert len(np.unique(np.round(levels, 6))) == 3
    y, x = np.mgrid[0:h, 0:w]
    want = levels[spec_channel(name, y, x)] * RANGE + BL
    np.testing.assert_allclose(sim.raw.data, want, rtol=1e-6)


def test_lms_densities_and_s_sites():
    ch = spec_channel("lms", *np.mgrid[0:4, 0:4])
    np.testing.assert_array_equal(ch, cfa_from_name("lms").pattern)
    assert [int(np.sum(ch == c)) for c in range(3)] == [8, 6, 2]


# ----------------------------------------------------------------------------- RawImage contents

@pytest.mark.parametrize("cfa", ["lms", "bayer"])
def test_raw_image_fields_and_round_trip(cfa):
    colour = np.array([0.2, 0.6, 0.4])
    sim = simulate(np.broadcast_to(colour, (8, 8, 3)).copy(), cfa=cfa, gain=None, seed=4)
    raw = sim.raw
    matrix, wb = camera_constants(raw.cfa.kind)
    np.testing.assert_array_equal(raw.black_level, np.full(3, BL))
    assert raw.white_level == WL and raw.source == "simulated"
    np.testing.assert_array_equal(raw.wb, wb)
    np.testing.assert_array_equal(raw.colour_matrix, matrix)
    np.testing.assert_array_equal(raw.wb2, np.ones(3))
    meta = raw.metadata
    assert json.loads(json.dumps(meta)) == meta
    assert meta["cfa"] == raw.cfa.name and meta["gain"] is None and meta["full_scale_electrons"] is None
    assert meta["optics"] == {"kind": "airy", "r0": 1.0} and meta["seed"] == 4
    assert abs(raw.exposure * meta["k_exp"] - 1.0) < 1e-12
    assert meta["simulator"].startswith("clisp ")
    assert NoiseModel.from_dict(meta["noise"]) == NoiseModel()
    # Pass 1 (black subtract, normalise, WB x exposure) then the colour matrix recovers the scene.
    channel_of = raw.cfa.channel_map(8, 8)
    balanced = (raw.data - BL) / RANGE * raw.pass1_gains()[channel_of]
    for ch in range(3):
        want = (np.linalg.inv(matrix) @ colour)[ch]
        np.testing.assert_allclose(balanced[channel_of == ch], want, rtol=1e-6)
    noisy = simulate(np.full((8, 8, 3), 0.5), cfa=cfa, gain=16, optics="none").raw.metadata
    assert noisy["gain"] == 16.0 and abs(noisy["full_scale_electrons"] - 959 / (0.14 * 16)) < 1e-9
    assert noisy["optics"] == {"kind": "none", "r0": None}
    assert json.loads(json.dumps(noisy)) == noisy


# ----------------------------------------------------------------------------- validation

@pytest.mark.parametrize("kwargs", [
    {"gain": 0.5}, {"gain": 65}, {"gain": float("nan")}, {"gain": "8"}, {"gain": True},
    {"optics": "gauss"}, {"r0": -1.0}, {"cfa": "xyz"}, {"cfa": 3}, {"seed": -1}, {"noise": "default"},
])
def test_bad_arguments_raise(kwargs):
    with pytest.raises(ClispError):
        simulate(np.full((8, 8, 3), 0.5), **kwargs)


@pytest.mark.parametrize("scene", [
    np.zeros((8, 8)), np.zeros((8, 8, 4)), np.zeros((0, 8, 3)),
    np.full((8, 8, 3), np.nan), np.full((8, 8, 3), np.inf), np.full((8, 8, 3), "a"),
])
def test_bad_scene_raises(scene):
    with pytest.raises(ClispError):
        simulate(scene)
