"""The hybrid LMS demosaic (clisp.modules.demosaic_lms.stage): every kernel against its NumPy reference,
flat fields, filter properties, and tiled against untiled through a full pipeline.

Tolerance, used by every OpenCL-vs-reference comparison in this file (float32 kernels against float64
references, inputs white-balanced values around 0..1):

    |opencl - reference| <= TOL * max(1, |reference|),  TOL = 1e-5

Two tests choose their data instead of relaxing it, with the reason at the test (the guided filter on
a smooth guide, the joint bilateral kernel with a wider range sigma); one relaxes: S of the
joint-bilateral option on a natural scene (TOL_BILATERAL).
"""
from __future__ import annotations

import numpy as np
import pytest

from clisp import simulate
from clisp.sim import charts
from clisp.cfa import bayer_cfa, lms_cfa
from clisp.sim.colorimetry import P_LMS, WB_LMS
from clisp.errors import ClispError
from clisp.sim.noise import ChannelNoise, NoiseModel
from clisp.pipeline import Pipeline
from clisp.engine.runtime import DeviceImage
from clisp.modules.colour.stage import ColourMatrix
from clisp.modules.demosaic_lms.stage import (A_RADIUS, CHROMA_RADIUS, LUM_RADIUS, DemosaicLMSHybrid,
                                       LMSHybridParams, chroma_demodulate_rows, diamond_halfband,
                                       frequency_response, lm_combine, luma_filter, luma_lowpass, m_at_s,
                                       s_joint_bilateral)
from clisp.modules.common.box import enqueue_box
from clisp.modules.common.guided_filter import (box_rows, gf_apply, gf_coefficients, gf_row_moments,
                                        guided_filter_spec)
from clisp.modules.raw_scale.stage import normalize, white_balance1
from tolerance import TOL, assert_close

"""|opencl - reference| <= TOL * max(1, |reference|) unless a test states otherwise."""
TOL_BILATERAL = 5e-5
"""S of the joint-bilateral option on a natural scene: at sharp edges its weights are exp(e) with
e = -(dI)^2 / (2 sigma_r^2) down to about -600 (sigma_r = 0.02 when noiseless), and float32 rounding
of e alone changes exp(e) by |e| * 6e-8 relative; measured 6e-6 on dead leaves, 1.1e-5 on McMaster 1."""

PHASES = [(0, 0), (1, 2)]
ORIGINS = [(0, 0), (1, 3), (-2, -5), (-7, 6)]
SHAPE = (45, 97)                        # odd sizes; every intermediate >= 64 wide (one work-group shape)
NOISE = ChannelNoise.from_model(NoiseModel(), 8.0, WB_LMS / 0.98951)






def random_window(seed: int, shape=SHAPE, lo: float = 0.02, hi: float = 1.2) -> np.ndarray:
    """float32 values (exactly representable, so both paths see the same input)."""
    return np.random.default_rng(seed).uniform(lo, hi, shape).astype(np.float32)


def smooth_pair(seed: int, shape=SHAPE) -> tuple[np.ndarray, np.ndarray]:
    """(guide, samples) float32: a smooth random field in 0.1..0.9 and 1.05 * field - 0.02 + noise."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:shape[0], 0:shape[1]]
    field = 0.5 + 0.25 * np.sin(0.21 * x + 0.13 * y) * np.cos(0.17 * y - 0.05 * x) + 0.1 * np.sin(0.9 * x)
    field += 0.02 * rng.standard_normal(shape)
    samples = 1.05 * field - 0.02 + 0.01 * rng.standard_normal(shape)
    return field.astype(np.float32), samples.astype(np.float32)


def upload(rt, x: np.ndarray) -> DeviceImage:
    """H x W, or H x W x C uploaded as C planes."""
    if x.ndim == 2:
        return rt.upload(np.ascontiguousarray(x, dtype=np.float32))
    planar = np.ascontiguousarray(np.moveaxis(x, -1, 0), dtype=np.float32)
    return rt.upload(planar)


def download(rt, image: DeviceImage) -> np.ndarray:
    """H x W for one plane, else H x W x C."""
    host = rt.download(image)
    return host if image.channels == 1 else np.moveaxis(host, 0, -1)


def f64(x: np.ndarray) -> np.ndarray:
    return np.asarray(x, dtype=np.float64)


# ------------------------------------------------------------------------------------ filters

def test_luma_filter_properties() -> None:
    """h_lum: 9 x 9, 8-fold symmetric, DC 1, exactly 0 at the (pi, pi) carrier, 53 non-zero taps."""
    h = luma_filter(0.75)
    assert h.shape == (9, 9) and np.count_nonzero(h) == 53
    np.testing.assert_allclose(h, h.T, atol=1e-15)
    np.testing.assert_allclose(h, h[::-1], atol=1e-15)
    assert abs(frequency_response(h, 0, 0) - 1) < 1e-12
    assert abs(frequency_response(h, np.pi, np.pi)) < 1e-12
    assert abs(frequency_response(h, 0, np.pi) - 0.625) < 1e-12
    assert abs(np.sum(h ** 2) - 0.46296) < 1e-5                   # noise gain -3.34 dB
    literal = luma_filter(0.75, exact_halfband=False)              # every tap of D scaled to sum 1
    assert abs(frequency_response(literal, np.pi, np.pi) - 0.003817) < 1e-6


def test_diamond_is_halfband() -> None:
    d = diamond_halfband(4)
    assert d[4, 4] == 0.5 and abs(d.sum() - 1) < 1e-15
    n = np.arange(-4, 5)
    even = (n[:, None] + n[None, :]) % 2 == 0
    even[4, 4] = False
    assert np.all(d[even] == 0)


# ------------------------------------------------------------------------------------ kernels

@pytest.mark.parametrize("phase", PHASES)
@pytest.mark.parametrize("origin", ORIGINS)
def test_m_at_s_kernel(rt, phase, origin) -> None:
    cfa = lms_cfa(phase)
    x = random_window(1)
    for params, noise in [(LMSHybridParams(), None), (LMSHybridParams(), NOISE),
                          (LMSHybridParams(select="hard"), None), (LMSHybridParams(select="iso"), None)]:
        stage = DemosaicLMSHybrid(cfa, params, noise)
        channel = cfa.channel_map(*x.shape, origin)
        ref = m_at_s(f64(x), channel, stage.ch_s, params, stage.pixel_noise, stage.ch_m)
        src = upload(rt, x)
        out = stage.enqueue_m_at_s(rt, src, origin)
        assert_close(download(rt, out), ref, f"m_at_s {params.select} noise={noise is not None}")
        rt.release(src)
        rt.release(out)


def test_m_at_s_keeps_samples_and_uses_the_s_detail() -> None:
    """Non-S samples pass through; at an S site on a flat M field the estimate is M + k (S - mean S)."""
    cfa = lms_cfa()
    x = random_window(2)
    channel = cfa.channel_map(*x.shape)
    m = m_at_s(f64(x), channel, 2, LMSHybridParams(), ChannelNoise((0, 0, 0), (0, 0, 0)), 1)
    inner = channel[A_RADIUS:-A_RADIUS, A_RADIUS:-A_RADIUS]
    np.testing.assert_array_equal(m[inner != 2], f64(x)[A_RADIUS:-A_RADIUS, A_RADIUS:-A_RADIUS][inner != 2])
    flat = np.where(channel == 2, 0.0, 0.4)
    flat[6, 5] = 0.9                                                  # (6, 5) is an S site at phase (0, 0)
    m = m_at_s(flat, channel, 2, LMSHybridParams(s_detail=0.25), ChannelNoise((0, 0, 0), (0, 0, 0)), 1)
    assert channel[6, 5] == 2 and abs(m[4, 3] - (0.4 + 0.25 * 0.9)) < 1e-12


@pytest.mark.parametrize("phase", PHASES)
@pytest.mark.parametrize("origin", ORIGINS[1:3])
def test_luma_and_chroma_kernels(rt, phase, origin) -> None:
    stage = DemosaicLMSHybrid(lms_cfa(phase))
    m = random_window(3)
    src = upload(rt, m)
    lum = stage.enqueue_luma_lowpass(rt, src)
    lum_host = download(rt, lum)
    assert_close(lum_host, luma_lowpass(f64(m), stage.h_lum), "luma_lowpass")
    # chroma rows over all lum rows, centred on lum columns 4 .. W-5 (the reference's layout)
    mod = np.where(stage.cfa.channel_map(*m.shape, origin) == stage.ch_l, 1.0, -1.0)
    lum_origin = (origin[0] + LUM_RADIUS, origin[1] + LUM_RADIUS)
    rows = stage.enqueue_chroma_demodulate_rows(rt, src, lum, lum_origin, lum.height,
                                                lum.width - 2 * CHROMA_RADIUS, (0, CHROMA_RADIUS))
    rows_host = download(rt, rows)
    assert_close(rows_host, chroma_demodulate_rows(f64(m), f64(lum_host), mod, stage.g_c), "chroma rows")
    # combine: output (y, x) at lum (y + 4, x + 4), rows (y + 4, x)
    dst = rt.acquire(3, lum.height - 2 * CHROMA_RADIUS, lum.width - 2 * CHROMA_RADIUS)
    stage.enqueue_lm_combine(rt, lum, rows, dst, (CHROMA_RADIUS, CHROMA_RADIUS))
    lm = download(rt, dst)[..., :2]
    assert_close(lm, lm_combine(f64(lum_host), f64(rows_host), stage.g_c), "lm_combine")
    for image in (src, lum, rows, dst):
        rt.release(image)


def test_box_rows_kernel(rt) -> None:
    """The shared box filter along x (the guided demosaic's box sums) against its NumPy twin, two
    planes. The guided filter itself runs as fused strip kernels, tested in test_lms_guided.py."""
    lum, p = smooth_pair(4)
    r = DemosaicLMSHybrid(lms_cfa(PHASES[0])).params.gf_radius
    src = rt.upload(np.stack([lum, p]).astype(np.float32))                      # two planes
    rows = enqueue_box(rt, src, 0, r)
    assert_close(download(rt, rows), box_rows(f64(np.stack([lum, p], axis=-1)), r), "box_rows")
    for image in (src, rows):
        rt.release(image)


def test_guided_steps_equal_the_spec_formula() -> None:
    """Row moments (centred per row), re-centred column sums and the box of a, b reproduce the
    masked guided filter written with window means (guided_filter_spec)."""
    stage = DemosaicLMSHybrid(lms_cfa((1, 2)), noise=NOISE)
    r = stage.params.gf_radius
    lum, p = f64(random_window(12, lo=0.1, hi=0.9)), f64(random_window(13))
    is_s = stage.cfa.channel_map(*p.shape, (3, -1)) == stage.ch_s
    noise_s = (NOISE.shot[stage.ch_s], NOISE.floor[stage.ch_s])
    a, b = gf_coefficients(gf_row_moments(lum, p, is_s, r), lum[:, r:-r], r, stage.params.gf_eps, *noise_s,
                           False)
    steps = gf_apply(lum[2 * r:-2 * r, 2 * r:-2 * r], box_rows(a, r), box_rows(b, r), r)
    spec = guided_filter_spec(lum, p, is_s, r, stage.params.gf_eps, *noise_s, False)
    np.testing.assert_allclose(steps, spec, rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("phase", PHASES)
@pytest.mark.parametrize("domain", ["ratio", "difference"])
def test_joint_bilateral_kernel(rt, phase, domain) -> None:
    """Range sigma 0.25 here: on uniform random data the default floor 0.02 gives exponents up to
    ~600, where float32 rounding of the exponent alone changes weights by ~4e-5 relative (a property
    of the data, not of the kernel); the whole stage at the default is checked on a natural scene."""
    params = LMSHybridParams(s_method="bilateral", bl_domain=domain, bl_sigma_r_min=0.25)
    stage = DemosaicLMSHybrid(lms_cfa(phase), params, NOISE)
    origin = (-3, 2)
    lum, p = random_window(6, lo=0.1, hi=0.9), random_window(7)
    is_s = stage.cfa.channel_map(*p.shape, origin) == stage.ch_s
    r = params.bl_radius
    lum_d, p_d = upload(rt, lum), upload(rt, p)
    dst = rt.acquire(3, lum.shape[0] - 2 * r, lum.shape[1] - 2 * r)
    stage.enqueue_s_joint_bilateral(rt, lum_d, p_d, dst, origin, (r, r), (r, r))
    ref = s_joint_bilateral(f64(lum), f64(p), is_s, params, float(np.sum(stage.h_lum ** 2)), NOISE,
                            stage.ch_l, stage.ch_m)
    assert_close(download(rt, dst)[..., 2], ref, f"s_joint_bilateral {domain}")
    for image in (lum_d, p_d, dst):
        rt.release(image)


# ------------------------------------------------------------------------------------ whole stage

@pytest.mark.parametrize("phase", PHASES)
@pytest.mark.parametrize("origin", ORIGINS)
def test_stage_matches_reference(rt, phase, origin) -> None:
    stage = DemosaicLMSHybrid(lms_cfa(phase))
    x = random_window(8)
    src = upload(rt, x)
    out = stage.enqueue(rt, src, origin)
    ref = stage.reference(f64(x), origin)
    assert ref.shape == (SHAPE[0] - 28, SHAPE[1] - 28, 3) and stage.halo == 14
    assert_close(download(rt, out), ref, f"stage {phase} {origin}")
    rt.release(src)
    rt.release(out)


def test_stage_bilateral_and_noise_options(rt) -> None:
    for params, noise in [(LMSHybridParams(s_method="bilateral", bl_sigma_r_min=0.25), NOISE),
                          (LMSHybridParams(select="hard"), NOISE)]:
        stage = DemosaicLMSHybrid(lms_cfa((1, 2)), params, noise)
        assert stage.halo == (10 if params.s_method == "bilateral" else 14)
        x = random_window(9)
        src = upload(rt, x)
        out = stage.enqueue(rt, src, (-1, -6))
        assert_close(download(rt, out), stage.reference(f64(x), (-1, -6)), f"stage {params}")
        rt.release(src)
        rt.release(out)


@pytest.mark.parametrize("s_method", ["guided", "bilateral"])
def test_stage_on_a_natural_scene(rt, s_method) -> None:
    """Simulated dead leaves (optics on, noiseless): L, M, S within TOL (S: TOL_BILATERAL for that option)."""
    sim = simulate(charts.dead_leaves(96, seed=3), "lms", gain=None)
    raw = sim.raw
    p = (raw.data.astype(np.float64) - raw.black_level[0]) / (raw.white_level - raw.black_level[0])
    p = (p * raw.pass1_gains()[raw.cfa.channel_map(*p.shape)]).astype(np.float32)
    stage = DemosaicLMSHybrid(raw.cfa, LMSHybridParams(s_method=s_method))
    src = upload(rt, p)
    out = download(rt, stage.enqueue(rt, src, (0, 0)))
    ref = stage.reference(f64(p), (0, 0))
    assert_close(out[..., :2], ref[..., :2], "natural L, M")
    assert_close(out[..., 2], ref[..., 2], "natural S", tol=TOL if s_method == "guided" else TOL_BILATERAL)
    rt.release(src)


@pytest.mark.parametrize("phase", PHASES)
@pytest.mark.parametrize("origin", [(0, 0), (-5, 3)])
def test_flat_mosaic_is_reproduced(rt, phase, origin) -> None:
    """A flat scene (per-channel flat values, L != M != S) comes back exactly, on both paths."""
    cfa = lms_cfa(phase)
    values = np.array([0.61, 0.47, 0.33], dtype=np.float32).astype(np.float64)
    x = values[cfa.channel_map(*SHAPE, origin)].astype(np.float32)
    for params in (LMSHybridParams(), LMSHybridParams(s_method="bilateral"), LMSHybridParams(select="hard")):
        stage = DemosaicLMSHybrid(cfa, params)
        expected = np.broadcast_to(values, stage.reference(f64(x), origin).shape)
        np.testing.assert_allclose(stage.reference(f64(x), origin), expected, rtol=0, atol=1e-12)
        src = upload(rt, x)
        out = stage.enqueue(rt, src, origin)
        assert_close(download(rt, out), expected, f"flat {params.s_method} {params.select}")
        rt.release(src)
        rt.release(out)


def test_tiled_equals_untiled_through_a_pipeline() -> None:
    """normalise -> WB 1 -> hybrid demosaic -> colour matrix on a 301 x 517 raw, tiles 64 and 256."""
    leaves = np.tile(charts.dead_leaves(160, seed=5), (2, 4, 1))
    scene = np.concatenate([leaves[:301, :261], charts.zone_plate(320)[:301, :256]], axis=1)
    raw = simulate(scene, "lms", gain=None).raw
    cfa = raw.cfa
    pipeline = Pipeline(cfa, [normalize(cfa, raw.black_level, raw.white_level),
                              white_balance1(cfa, raw.pass1_gains()), DemosaicLMSHybrid(cfa),
                              ColourMatrix(P_LMS)])
    whole = pipeline.run(raw.data)
    assert whole.shape == (301, 517, 3) and np.all(np.isfinite(whole))
    for tile in (64, 256):
        assert_close(pipeline.run(raw.data, tile=tile), whole, f"tile {tile}")


# ------------------------------------------------------------------------------------ parameters

def test_parameters_and_cfa_are_checked() -> None:
    with pytest.raises(ClispError):
        DemosaicLMSHybrid(bayer_cfa("RGGB"))
    for bad in ({"select": "median"}, {"s_method": "nn"}, {"gf_radius": 1}, {"gf_eps": 0.0}):
        with pytest.raises(ClispError):
            LMSHybridParams(**bad)


def test_pixel_noise_matches_the_noise_model() -> None:
    model, gain, w = NoiseModel(), 16.0, WB_LMS / 0.98951
    noise = ChannelNoise.from_model(model, gain, w)
    for c in range(3):
        for level in (0.0, 0.2, 0.9):
            assert abs(noise.variance(c, level) - model.variance(level, gain, w[c])) < 1e-15
