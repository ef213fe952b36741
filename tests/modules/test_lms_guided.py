"""The guided LMS demosaic (clisp.modules.demosaic_lms_guided.stage): every kernel against its NumPy reference,
the whole stage at several origins and both tested CFA phases, flat fields, the noise-driven blend,
and tiled against untiled through a full pipeline.

Tolerance, used by every OpenCL-vs-reference comparison in this file (float32 kernels against float64
references on the same float32 inputs, white-balanced values around 0..1):

    |opencl - reference| <= TOL * max(1, |reference|),  TOL = 1e-5

(measured worst case 2.5e-7 for the whole stage on a simulated natural scene, noiseless and at gain 8:
the guided filters centre their statistics, so no step loses float32 precision to cancellation).
Tiled against untiled: the same kernels on the same pixels, compared with TOL as well.
Windows are at least 2 halo + 64 px wide so that every kernel runs with one work-group shape: PoCL
compiles each kernel once per shape (about 1 s each on a cold kernel cache, ~25 s for this file's
first run; warm runs take ~8 s).
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
from clisp.modules.colour.stage import ColourMatrix
from clisp.modules.common.lms import valid
from clisp.modules.demosaic_lms_guided.stage import (COMBINE_RADIUS, D_RADIUS, D9, LUM_NOISE_GAIN, PRE_RADIUS,
                                                     RI_RADIUS, DemosaicLMSGuided, LMSGuidedParams, alias_gain,
                                                     chroma_input, l_guide, lm_output, lum_lowpass, m_at_s_combine,
                                                     neutral_of, s_alias, s_output, tonal_energy,
                                                     S_ALIAS_RADIUS, axial_tonal_energy)
from clisp.modules.common.guided_filter import (MASK_ALL, MASK_M, MASK_S, enqueue_guided_filter, enqueue_guided_pair,
                                                guided_filter)
from clisp.modules.raw_scale.stage import normalize, white_balance1
from tolerance import TOL, assert_close

"""|opencl - reference| <= TOL * max(1, |reference|) everywhere in this file."""

PHASES = [(0, 0), (1, 2)]
ORIGINS = [(0, 0), (1, 3), (-2, -5), (-7, 6)]
K_EXP = 0.98951
NOISE = ChannelNoise.from_model(NoiseModel(), 8.0, WB_LMS / K_EXP)
NEUTRAL = neutral_of(P_LMS)
"""White-balanced LMS of a neutral under the paper's P (what for_raw gives a simulated LMS raw)."""






def mosaic(cfa, gain=None, shape=(125, 181), offset=(40, 52), seed=0) -> np.ndarray:
    """A white-balanced float32 LMS mosaic window of a simulated dead-leaves capture (optics on):
    natural-image statistics with sharp colour edges; ``offset`` picks the window."""
    sim = simulate(charts.dead_leaves(256, seed=seed), cfa, gain=gain, seed=seed)
    raw = sim.raw
    ch = cfa.channel_map(*raw.data.shape)
    p = (raw.data.astype(np.float64) - raw.black_level[ch]) / (raw.white_level - raw.black_level[ch])
    p *= raw.pass1_gains()[ch]
    y0, x0 = offset
    return np.ascontiguousarray(p[y0:y0 + shape[0], x0:x0 + shape[1]], dtype=np.float32)


def download(rt, image) -> np.ndarray:
    """Planar device image as H x W (one plane) or H x W x C."""
    host = rt.download(image)
    return host if host.ndim == 2 else host.transpose(1, 2, 0)


# ---------------------------------------------------------------------------------- whole stage

@pytest.mark.parametrize("phase", PHASES)
@pytest.mark.parametrize("noisy", [False, True])
def test_stage_matches_reference(rt, phase, noisy):
    cfa = lms_cfa(phase)
    stage = DemosaicLMSGuided(cfa, noise=NOISE if noisy else None, neutral=NEUTRAL if noisy else (1.0, 1.0, 1.0))
    x = mosaic(cfa, 8.0 if noisy else None)
    src = rt.upload(x)
    for origin in ORIGINS:
        ref = stage.reference(x.astype(np.float64), origin)
        out = stage.enqueue(rt, src, origin)
        assert_close(download(rt, out), ref, f"stage phase {phase} origin {origin} noisy {noisy}")
        rt.release(out)
    rt.release(src)


@pytest.mark.parametrize("noisy", [False, True])
def test_colour_aware_chroma_guide_matches_reference(rt, noisy):
    """chroma_guide (issue 17): the chroma filter's guide ylp + lambda cin and its regulariser, kernel
    against reference; lambda 0 is the luminance-only filter."""
    cfa = lms_cfa()
    stage = DemosaicLMSGuided(cfa, LMSGuidedParams(chroma_guide=4.0), noise=NOISE if noisy else None,
                              neutral=NEUTRAL if noisy else (1.0, 1.0, 1.0))
    x = mosaic(cfa, 8.0 if noisy else None)
    src = rt.upload(x)
    ref = stage.reference(x.astype(np.float64), ORIGINS[1])
    out = stage.enqueue(rt, src, ORIGINS[1])
    assert_close(download(rt, out), ref, f"chroma guide noisy {noisy}")
    rt.release(out)
    rt.release(src)
    plain = DemosaicLMSGuided(cfa, noise=NOISE if noisy else None,
                              neutral=NEUTRAL if noisy else (1.0, 1.0, 1.0))
    assert not np.allclose(plain.reference(x.astype(np.float64), ORIGINS[1]), ref)


@pytest.mark.parametrize("noisy", [False, True])
def test_one_pass_matches_reference(rt, noisy):
    """passes=1 (the high-noise choice, clisp.pipeline.demosaic_choice): kernel against reference, a halo 16 px
    smaller, and an output that differs from the two-pass one (pass 2 is really left out)."""
    cfa = lms_cfa()
    noise, neutral = (NOISE, NEUTRAL) if noisy else (None, (1.0, 1.0, 1.0))
    stage = DemosaicLMSGuided(cfa, LMSGuidedParams(passes=1), noise=noise, neutral=neutral)
    two = DemosaicLMSGuided(cfa, noise=noise, neutral=neutral)
    assert stage.halo == two.halo - 16
    x = mosaic(cfa, 8.0 if noisy else None)
    src = rt.upload(x)
    for origin in ORIGINS[:2]:
        ref = stage.reference(x.astype(np.float64), origin)
        out = stage.enqueue(rt, src, origin)
        assert_close(download(rt, out), ref, f"one pass origin {origin} noisy {noisy}")
        rt.release(out)
        k = two.halo - stage.halo
        assert not np.allclose(ref[k:-k, k:-k], two.reference(x.astype(np.float64), origin), atol=1e-4)
    rt.release(src)
    with pytest.raises(ClispError, match="passes"):
        LMSGuidedParams(passes=3)


def test_chroma_guide_fades_with_the_noise():
    """lambda in full at low noise, 0 at high noise (its PSNR cost there), linear in between."""
    from clisp.sim.noise import ChannelNoise
    cfa = lms_cfa()
    params = LMSGuidedParams(chroma_guide=4.0)
    stage = DemosaicLMSGuided(cfa, params)
    lo, hi = params.chroma_guide_sigma
    assert stage.guide_lambda == 4.0 and DemosaicLMSGuided(cfa).guide_lambda == 0.0  # noiseless; default off
    for sigma, expected in ((0.5 * lo, 4.0), (0.5 * (lo + hi), 2.0), (2 * hi, 0.0)):
        noise = ChannelNoise((0.0, 0.0, 0.0), (sigma ** 2,) * 3)
        assert DemosaicLMSGuided(cfa, params, noise=noise).guide_lambda == pytest.approx(expected)


def test_halo_and_shapes():
    stage = DemosaicLMSGuided(lms_cfa())
    assert stage.halo == sum(stage.radii.values()) == 55
    assert stage.reference(np.full((128, 139), 0.3), (0, 0)).shape == (18, 29, 3)
    small = DemosaicLMSGuided(lms_cfa(), LMSGuidedParams(ms_radius1=2, chroma_radius=2, s_radius=2))
    assert small.halo == 55 - 2 - 4


@pytest.mark.parametrize("noisy", [False, True])
def test_flat_field_reproduced(rt, noisy):
    """A neutral flat field (L = M = S after white balance) comes back exactly flat, both paths."""
    stage = DemosaicLMSGuided(lms_cfa(), noise=NOISE if noisy else None)
    x = np.full((2 * stage.halo + 9, 2 * stage.halo + 71), 0.37, dtype=np.float32)
    ref = stage.reference(x.astype(np.float64), (-3, 2))
    np.testing.assert_allclose(ref, float(np.float32(0.37)), rtol=0, atol=1e-12)
    out = stage.enqueue(rt, rt.upload(x), (-3, 2))
    assert_close(download(rt, out), ref, "flat")


def test_coloured_flat_field_reproduced():
    """A flat field of any colour (L, M, S constant but different) is reproduced (reference)."""
    cfa = lms_cfa()
    stage = DemosaicLMSGuided(cfa)
    lms = np.array([0.6, 0.3, 0.1])
    shape = (2 * stage.halo + 5, 2 * stage.halo + 6)
    x = lms[cfa.channel_map(*shape, (1, 1))]
    np.testing.assert_allclose(stage.reference(x, (1, 1)), np.broadcast_to(lms, (5, 6, 3)), atol=1e-9)


def test_noise_blend_averages_flat_noise():
    """On a noisy flat patch the luminance falls back to the flat-field target ybl (w -> 0): the noise
    of Y = (L + M) / 2 is about sqrt(0.3125) = 0.56 of one sample's, where keeping samples gives 1.0."""
    cfa = lms_cfa()
    rng = np.random.default_rng(3)
    level = 0.2
    shape = (240, 240)
    ch = cfa.channel_map(*shape)
    sd = np.sqrt(NOISE.variance(0, level))
    x = level + rng.normal(0.0, 1.0, shape) * np.sqrt([NOISE.variance(c, level) for c in range(3)])[ch]
    noisy = DemosaicLMSGuided(cfa, noise=NOISE).reference(x, (0, 0))
    kept = DemosaicLMSGuided(cfa).reference(x, (0, 0))
    ratio = (0.5 * (noisy[..., 0] + noisy[..., 1])).std() / sd
    assert ratio < 0.6, ratio
    assert (0.5 * (kept[..., 0] + kept[..., 1])).std() / sd > 0.9
    assert abs(LUM_NOISE_GAIN - 0.405) < 1e-3


def test_lm_output_blend_ends():
    """lm_output's two ends: noiseless (and w = 1) keeps y = m - c mod exactly; on flat noise (w = 0)
    Y is the flat-field target ybl = m / 2 + (4 axial neighbours) / 8, which cancels the (pi, pi)
    chroma carrier (a pure +-c checkerboard in m gives ybl = its DC level)."""
    cfa = lms_cfa()
    stage = DemosaicLMSGuided(cfa, noise=NOISE)
    shape = (40, 44)
    mod = np.where(cfa.channel_map(*shape) == stage.ch_l, 1.0, -1.0)
    rng = np.random.default_rng(1)
    m = rng.uniform(0.1, 0.9, shape)
    c = 0.05 * rng.standard_normal(shape)
    lm = lm_output(m, c, lum_lowpass(np.pad(m, D_RADIUS, mode="reflect")), mod, None, stage.ch_l, stage.ch_m, 2.0)
    r = COMBINE_RADIUS
    np.testing.assert_allclose(0.5 * (lm[..., 0] + lm[..., 1]), valid(m - c * mod, r), rtol=0, atol=1e-15)
    np.testing.assert_allclose(lm[..., 0] - lm[..., 1], 2.0 * valid(c, r), atol=1e-15)
    # flat noise far below the blend threshold -> w = 0 -> Y = ybl; a carrier +-0.1 in m cancels in ybl
    flat = 0.3 + 0.1 * mod + 1e-9 * rng.standard_normal(shape)
    c0 = np.full(shape, 0.1)
    lm = lm_output(flat, c0, np.full(shape, 0.3), mod, NOISE, stage.ch_l, stage.ch_m, 2.0)
    ybl = 0.5 * valid(flat, r) + 0.125 * sum(valid(flat, r, dy, dx) for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1)))
    np.testing.assert_allclose(0.5 * (lm[..., 0] + lm[..., 1]), ybl, atol=1e-12)
    np.testing.assert_allclose(ybl, 0.3, atol=1e-8)


# ---------------------------------------------------------------------------------- kernels

@pytest.fixture(scope="module")
def window():
    cfa = lms_cfa((1, 2))
    return cfa, mosaic(cfa, None, shape=(90, 181))


@pytest.mark.parametrize("origin", [(0, 0), (-5, 3)])
def test_kernel_l_guide(rt, window, origin):
    cfa, x = window
    stage = DemosaicLMSGuided(cfa)
    ref = l_guide(x.astype(np.float64), cfa.channel_map(*x.shape, origin), stage.ch_l)
    assert_close(download(rt, stage.enqueue_l_guide(rt, rt.upload(x), origin)), ref, "l_guide")


@pytest.mark.parametrize("channel_name", ["M", "S", None])
def test_kernel_guided_filter(rt, window, channel_name):
    """The fused strip kernels (the NumPy steps gf_row_moments, gf_coefficients, box_rows, gf_apply)
    against guided_filter, masked and not, with a guide offset into a larger image and the noise term
    in eps."""
    cfa, x = window
    stage = DemosaicLMSGuided(cfa, noise=NOISE)
    origin, off, r = (-3, 2), 3, 3
    guide = x[off:-off, off:-off].astype(np.float64) ** 0.5          # a smooth, different guide
    channel = -1 if channel_name is None else cfa.channels.index(channel_name)
    ch = cfa.channel_map(*guide.shape, (origin[0] + off, origin[1] + off))
    shot, floor = (0.01, 1e-5) if channel < 0 else (NOISE.shot[channel], NOISE.floor[channel])
    mask = None if channel < 0 else ch == channel
    ref = guided_filter(guide, x[off:-off, off:-off].astype(np.float64), mask, r, 1e-4, shot, floor, channel < 0)
    mask_arg = {None: MASK_ALL, "M": MASK_M, "S": MASK_S}[channel_name]
    out = enqueue_guided_filter(rt, guide.shape, (origin[0] + off, origin[1] + off), stage.shift,
                                rt.upload(guide.astype(np.float32)), 0, rt.upload(x), off, r, mask_arg, 1e-4,
                                (shot, floor), channel < 0)
    assert_close(download(rt, out), ref, f"guided filter {channel_name}")


@pytest.mark.parametrize("r, rows", [(2, 90), (4, 90), (3, 19), (2, 13)])
def test_kernel_guided_filter_strips(rt, window, r, rows):
    """The fused strip kernels (gf_ab_strip, gf_apply_strip) at other radii and on windows whose
    outputs are shorter than a strip (strip heights fall back to powers of two; ragged last strips
    shift up), S sites and every pixel."""
    cfa, x = window
    x = x[:rows]
    stage = DemosaicLMSGuided(cfa, noise=NOISE)
    origin, off = (5, -2), 2
    guide = x[off:-off, off:-off].astype(np.float64) ** 0.5
    ch = cfa.channel_map(*guide.shape, (origin[0] + off, origin[1] + off))
    for name, mask, mask_arg in (("S", ch == stage.ch_s, MASK_S), ("all", None, MASK_ALL)):
        ref = guided_filter(guide, x[off:-off, off:-off].astype(np.float64), mask, r, 1e-4, 0.01, 1e-5, mask is None)
        out = enqueue_guided_filter(rt, guide.shape, (origin[0] + off, origin[1] + off), stage.shift,
                                    rt.upload(guide.astype(np.float32)), 0, rt.upload(x), off, r, mask_arg, 1e-4,
                                    (0.01, 1e-5), mask is None)
        assert_close(download(rt, out), ref, f"guided filter {name} r={r} rows={rows}")


@pytest.mark.parametrize("r", [2, 3])
def test_kernel_guided_pair(rt, window, r):
    """enqueue_guided_pair (the M and S fits in one pass, GF_MASK 3) against two guided_filter calls."""
    cfa, x = window
    stage = DemosaicLMSGuided(cfa, noise=NOISE)
    origin, off = (-1, 4), 3
    guide = x[off:-off, off:-off].astype(np.float64) ** 0.5
    ch = cfa.channel_map(*guide.shape, (origin[0] + off, origin[1] + off))
    noise = {c: (NOISE.shot[c], NOISE.floor[c]) for c in (stage.ch_m, stage.ch_s)}
    fits = enqueue_guided_pair(rt, guide.shape, (origin[0] + off, origin[1] + off), stage.shift,
                               rt.upload(guide.astype(np.float32)), 0, rt.upload(x), off, r, 1e-4,
                               noise[stage.ch_m], noise[stage.ch_s], False)
    for fit, c in zip(fits, (stage.ch_m, stage.ch_s)):
        ref = guided_filter(guide, x[off:-off, off:-off].astype(np.float64), ch == c, r, 1e-4, *noise[c], False)
        assert_close(download(rt, fit), ref, f"guided pair, channel {cfa.channels[c]}")


@pytest.mark.parametrize("noisy", [False, True])
@pytest.mark.parametrize("origin", [(0, 0), (3, -5)])
def test_kernel_s_output(rt, window, noisy, origin):
    """s_residual + s_output (enqueue_s_output) against s_output, L and M copied from lm."""
    cfa, x = window
    stage = DemosaicLMSGuided(cfa, noise=NOISE if noisy else None)
    o_g, lm_off = 5, 4
    p = x.astype(np.float64)
    g = p[o_g:-o_g, o_g:-o_g] * 0.95 + 0.02
    rng = np.random.default_rng(2)
    lm = rng.uniform(0.1, 0.9, (2, g.shape[0] - 2 * RI_RADIUS + 2 * lm_off, g.shape[1] - 2 * RI_RADIUS + 2 * lm_off))
    ch = cfa.channel_map(*p.shape, origin)
    ref = s_output(valid(p, o_g), valid(ch, o_g), g.astype(np.float32).astype(np.float64), stage.ch_s,
                   NOISE if noisy else None)
    lms = stage.enqueue_s_output(rt, rt.upload(x), origin, rt.upload(g.astype(np.float32)), o_g,
                                 rt.upload(lm.astype(np.float32)), lm_off)
    out = download(rt, lms)
    assert_close(out[..., 2], ref, f"s_output noisy={noisy}")
    assert_close(out[..., :2], lm.astype(np.float32).transpose(1, 2, 0)[lm_off:-lm_off, lm_off:-lm_off], "L, M")


@pytest.mark.parametrize("pass2", [False, True])
@pytest.mark.parametrize("noisy", [False, True])
def test_kernel_m_at_s(rt, window, pass2, noisy):
    """enqueue_m_at_s (two guided filters + m_at_s_combine) against its reference, pass 1 (guide only)
    and pass 2 (edge-directed estimate mixed in)."""
    cfa, x = window
    stage = DemosaicLMSGuided(cfa, noise=NOISE if noisy else None)
    origin, o_g, r = (2, -7), 6, 2
    p = x.astype(np.float64)
    guide = p[o_g:-o_g, o_g:-o_g] * 0.9 + 0.01
    rng = np.random.default_rng(1)
    c = 0.01 * rng.standard_normal(guide.shape)
    ylp = guide + 0.005 * rng.standard_normal(guide.shape)
    ch = cfa.channel_map(*p.shape, origin)
    directional = (valid(guide, 2 * r), valid(c, 2 * r), valid(ylp, 2 * r)) if pass2 else None
    ref = stage._m_at_s(valid(p, o_g), valid(ch, o_g), guide, r, directional)
    up = {k: rt.upload(v.astype(np.float32)) for k, v in (("g", guide), ("c", c), ("ylp", ylp))}
    out = stage.enqueue_m_at_s(rt, rt.upload(x), origin, up["g"], o_g, r,
                               (up["g"], up["c"], up["ylp"], o_g, o_g) if pass2 else None)
    # the reference ran on float64 copies of float32 inputs; guide etc. rounded the same way:
    ref32 = stage._m_at_s(valid(p, o_g), valid(ch, o_g), guide.astype(np.float32).astype(np.float64), r,
                          None if not pass2 else tuple(a.astype(np.float32).astype(np.float64) for a in directional))
    assert_close(download(rt, out), ref32, f"m_at_s pass2={pass2} noisy={noisy}")
    assert np.abs(ref32 - ref).max() < 1e-5


@pytest.mark.parametrize("origin", [(0, 0), (-6, 1)])
def test_kernel_chroma(rt, window, origin):
    """lum_lowpass + chroma_input + the chroma guided filter (enqueue_chroma) and keep_luminance."""
    cfa, x = window
    stage = DemosaicLMSGuided(cfa, noise=NOISE)
    m = x.astype(np.float64)
    ch = cfa.channel_map(*m.shape, origin)
    mod = np.where(ch == stage.ch_l, 1.0, -1.0)
    c_ref, ylp_ref = stage._chroma(m, mod, NOISE)
    c_dev, ylp_dev = stage.enqueue_chroma(rt, rt.upload(x), origin)
    assert_close(download(rt, ylp_dev), lum_lowpass(m), "lum_lowpass")
    assert_close(download(rt, c_dev), c_ref, "chroma")
    k = D_RADIUS + PRE_RADIUS + 2 * stage.params.chroma_radius
    assert_close(download(rt, ylp_dev)[k - D_RADIUS:-(k - D_RADIUS), k - D_RADIUS:-(k - D_RADIUS)], ylp_ref,
                 "ylp crop")
    y = stage.enqueue_keep_luminance(rt, rt.upload(x), c_dev, k, (origin[0] + k, origin[1] + k))
    assert_close(download(rt, y), valid(m, k) - download(rt, c_dev) * valid(mod, k), "keep_luminance")
    assert chroma_input(m, lum_lowpass(m), mod).shape == (m.shape[0] - 12, m.shape[1] - 12)


def test_reference_steps_compose():
    """The step functions used by the kernels tests agree with the stage's own composition (shapes)."""
    cfa = lms_cfa()
    stage = DemosaicLMSGuided(cfa, noise=NOISE)
    rng = np.random.default_rng(0)
    m = rng.uniform(0.1, 0.9, (40, 44))
    c = 0.01 * rng.standard_normal((40, 44))
    ylp = m + 0.01
    mod = np.where(cfa.channel_map(40, 44) == stage.ch_l, 1.0, -1.0)
    lm = lm_output(m, c, ylp, mod, NOISE, stage.ch_l, stage.ch_m, 2.0)
    assert lm.shape == (40 - 2 * COMBINE_RADIUS, 44 - 2 * COMBINE_RADIUS, 3)
    assert s_alias(np.dstack([m, m, ylp]), m, 1.05, 1.0, 1.0).shape == (32, 36, 3)
    g = rng.uniform(0.1, 0.9, (40, 44))
    s = s_output(m, cfa.channel_map(40, 44), g, stage.ch_s, NOISE)
    assert s.shape == (40 - 2 * RI_RADIUS, 44 - 2 * RI_RADIUS)
    assert m_at_s_combine(m, cfa.channel_map(40, 44), g, g, stage.ch_m, stage.ch_s, None, None, 0.1,
                          1e-7).shape == (36, 40)
    assert abs(D9.sum() - 1.0) < 1e-12


# ---------------------------------------------------------------------------------- pipeline

def _pipeline(raw, stage) -> Pipeline:
    cfa = raw.cfa
    return Pipeline(cfa, [normalize(cfa, raw.black_level, raw.white_level), white_balance1(cfa, raw.pass1_gains()),
                          stage, ColourMatrix(raw.colour_matrix)])


@pytest.mark.parametrize("gain", [None, 8.0])
def test_tiled_equals_untiled(gain):
    scene = charts.demo_chart().image[150:451, 100:617]                # 301 x 517
    sim = simulate(scene, "lms", gain=gain, seed=2)
    stage = DemosaicLMSGuided.for_raw(sim.raw)
    assert (stage.noise is None) == (gain is None)
    pipe = _pipeline(sim.raw, stage)
    whole = pipe.run(sim.raw.data, tile=0)
    assert whole.shape == (301, 517, 3) and np.all(np.isfinite(whole))
    for tile in (64, 256):
        assert_close(pipe.run(sim.raw.data, tile=tile), whole, f"tile {tile}")


def test_pipeline_reference_backend_matches_opencl():
    """The NumPy reference through the same pipeline (stage by stage) agrees with OpenCL."""
    sim = simulate(charts.dead_leaves(96, seed=1), "lms@1,2", gain=None)
    pipe = _pipeline(sim.raw, DemosaicLMSGuided.for_raw(sim.raw))
    assert_close(pipe.run(sim.raw.data, tile=0), pipe.run(sim.raw.data, tile=0, backend="reference"), "backends")


# ---------------------------------------------------------------------------------- parameters

def test_noise_from_metadata():
    sim = simulate(np.full((16, 16, 3), 0.5), "lms", gain=16.0)
    noise = ChannelNoise.from_metadata(sim.raw.metadata, sim.raw.pass1_gains())
    model = NoiseModel()
    for c in range(3):
        assert noise.variance(c, 0.3) == pytest.approx(float(model.variance(0.3, 16.0, sim.raw.pass1_gains()[c])))
    clean = simulate(np.full((16, 16, 3), 0.5), "lms", gain=None)
    assert ChannelNoise.from_metadata(clean.raw.metadata, clean.raw.pass1_gains()) is None
    assert DemosaicLMSGuided.for_raw(clean.raw).noise is None


def test_rejects_bad_cfa_and_params():
    with pytest.raises(ClispError):
        DemosaicLMSGuided(bayer_cfa("RGGB"))
    with pytest.raises(ClispError):
        LMSGuidedParams(s_radius=1)
    with pytest.raises(ClispError):
        LMSGuidedParams(chroma_eps=0.0)
    assert DemosaicLMSGuided.cfa_kinds == ("lms",)


def test_colour_of_demosaiced_neutral_is_neutral():
    """A neutral (sRGB-grey) flat scene simulated and demosaiced stays grey through eq. (1)."""
    sim = simulate(np.full((140, 150, 3), 0.3), "lms", gain=None)
    stage = DemosaicLMSGuided.for_raw(sim.raw)
    rgb = _pipeline(sim.raw, stage).run(sim.raw.data, tile=0, backend="reference")
    np.testing.assert_allclose(rgb, 0.3, atol=1e-5)
    assert P_LMS.shape == (3, 3)


# ---------------------------------------------------------------------------------- alias suppression

def test_alias_gain_and_neutral():
    """alias_gain is the LMMSE-style shrink max(E - A, 0) / E (1 where E == 0); neutral_of inverts the
    colour matrix (the paper's P is not white-preserving) and falls back to (1, 1, 1)."""
    np.testing.assert_allclose(alias_gain(np.array([0.0, 1.0, 4.0, 1.0]), np.array([1.0, 0.5, 1.0, 2.0])),
                               [1.0, 0.5, 0.75, 0.0])
    np.testing.assert_allclose(NEUTRAL, [1.0106, 1.0153, 1.0654], atol=1e-4)
    assert neutral_of(np.zeros((3, 3))) == (1.0, 1.0, 1.0)
    assert neutral_of(-np.eye(3)) == (1.0, 1.0, 1.0)
    sim = simulate(np.full((16, 16, 3), 0.5), "lms", gain=None)
    np.testing.assert_allclose(DemosaicLMSGuided.for_raw(sim.raw).neutral, NEUTRAL, rtol=1e-12)
    with pytest.raises(ClispError):
        DemosaicLMSGuided(lms_cfa(), neutral=(1.0, 0.0, 1.0))
    with pytest.raises(ClispError):
        LMSGuidedParams(alias_c=-0.1)


def test_s_alias_shrinks_toward_neutral():
    """s_alias: where the luminance detail energy E_sig dwarfs the S - M deviation, S becomes the neutral
    s_from_m M; with E_sig = 0 (or strength 0) S is kept; L and M are never touched."""
    rng = np.random.default_rng(4)
    lms = rng.uniform(0.2, 0.8, (20, 24, 3))
    centre = valid(lms, S_ALIAS_RADIUS)
    kept = s_alias(lms, np.zeros((20, 24)), 1.05, 1.0)
    np.testing.assert_allclose(kept, centre, rtol=1e-12)
    np.testing.assert_allclose(s_alias(lms, np.ones((20, 24)), 1.05, 0.0), centre, rtol=1e-12)
    gone = s_alias(lms, np.full((20, 24), 10.0), 1.05, 1.0)
    np.testing.assert_array_equal(gone[..., :2], centre[..., :2])
    np.testing.assert_allclose(gone[..., 2], 1.05 * centre[..., 1], rtol=1e-12)


def test_axial_tonal_energy_and_s_alias_tone_term():
    """axial_tonal_energy: vertical or horizontal stripes at Nyquist (an S-lattice carrier) give their
    full energy with tonality 1; noise and a diagonal (pi/2, pi/2) pattern much less; flat 0. With that
    term alone (E_sig = 0), S on Nyquist stripes becomes the neutral s_from_m M."""
    yy, xx = np.mgrid[0:30, 0:34].astype(np.float64)
    amp = 0.2
    for stripes in (np.cos(np.pi * xx), np.cos(np.pi * yy)):
        np.testing.assert_allclose(axial_tonal_energy(0.5 + amp * stripes), amp ** 2, rtol=0.05)
    assert axial_tonal_energy(0.5 + amp * np.random.default_rng(1).standard_normal((30, 34))).mean() < 0.1 * amp ** 2
    assert axial_tonal_energy(0.5 + amp * np.cos(np.pi / 2 * (xx + yy))).max() < 0.1 * amp ** 2
    assert axial_tonal_energy(np.full((20, 20), 0.3)).max() < 1e-30
    lum = 0.5 + amp * np.cos(np.pi * xx)
    lms = np.dstack([lum, lum, np.full_like(lum, 0.5)])                  # S flat where M has stripes
    out = s_alias(lms, np.zeros(lum.shape), 1.05, 1.0, alias_st=10.0)
    np.testing.assert_allclose(out[..., 2], 1.05 * valid(lum, S_ALIAS_RADIUS), rtol=1e-9)
    np.testing.assert_allclose(s_alias(lms, np.zeros(lum.shape), 1.05, 1.0)[..., 2], 0.5, rtol=1e-12)


def _zone_plate_psnr(params: LMSGuidedParams) -> float:
    from clisp.metrics import psnr
    sim = simulate(charts.zone_plate(256), "lms", gain=None)
    stage = DemosaicLMSGuided.for_raw(sim.raw, params)
    return psnr(_pipeline(sim.raw, stage).run(sim.raw.data, tile=0), sim.truth, border=10)


def test_alias_suppression_clears_zone_plate_false_colour():
    """The demo's neutral zone plate (an sRGB cosine up to Nyquist), noiseless, tone-mapped PSNR with a
    10 px border: at least 40 dB with the default alias suppression (issue 3's target); without it the
    false colour at the (pi, pi) carrier and the S-lattice carriers costs more than 10 dB."""
    with_alias = _zone_plate_psnr(LMSGuidedParams())
    without = _zone_plate_psnr(LMSGuidedParams(alias_c=0.0, alias_m=0.0, alias_s=0.0))
    assert with_alias >= 40.0 and with_alias > without + 10.0, (with_alias, without)


def test_tonal_energy_picks_periodic_half_nyquist_diagonals():
    """tonal_energy: a cosine at (pi/2, pi/2) (whose 2nd harmonic is the L-M carrier) gives its full band
    energy A^2 / 2 with tonality 1; white noise of the same power and a diagonal cosine at (pi/4, pi/4)
    give far less; a flat field gives 0."""
    yy, xx = np.mgrid[0:40, 0:40].astype(np.float64)
    amp = 0.2
    tone = tonal_energy(0.5 + amp * np.cos(np.pi / 2 * (xx + yy)))
    np.testing.assert_allclose(tone, amp ** 2 / 2, rtol=0.05)      # 5 x 5 window: +-1/25 of the (pi, pi) term
    noise = tonal_energy(0.5 + amp * np.random.default_rng(2).standard_normal((40, 40)))
    assert noise.mean() < 0.02 * amp ** 2 / 2
    slow = tonal_energy(0.5 + amp * np.cos(np.pi / 4 * (xx + yy)))
    assert slow.max() < 0.01 * amp ** 2 / 2
    assert tonal_energy(np.full((20, 20), 0.3)).max() < 1e-30
    assert tone.shape == (40 - 12, 40 - 12)
