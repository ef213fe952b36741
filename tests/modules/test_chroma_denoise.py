"""Chroma denoise (clisp/modules/chroma_denoise): kernels against references, tiling, behaviour on flat fields;
noise from the raw (model and estimate); white balance pass 2 estimation.

Tolerance for every OpenCL-vs-reference and tiled-vs-whole comparison (float32 kernels against
float64 references, signal values ~0..1.2):

    |opencl - reference| <= TOL * max(1, |reference|)
"""
from __future__ import annotations


import numpy as np
import pytest

from clisp.cfa import cfa_from_name
from clisp.sim.charts import colorchecker
from clisp.sim.colorimetry import B_BAYER, P_LMS
from clisp.errors import ClispError
from clisp.sim.noise import NoiseModel
from clisp.sim.noise import ChannelNoise
from clisp.scene.noise import estimate_raw_noise, raw_noise
from clisp.engine.runtime import get_runtime
from clisp.pipeline import Pipeline, chroma_denoise_for
from clisp.sim.simulate import simulate
from clisp.modules.chroma_denoise import stage as cd
from clisp.modules.chroma_denoise.stage import (ChromaDenoise, ChromaDenoiseParams, NoiseTable, calibrate_noise,
                                                haar_analyze, haar_synthesize, lms_space, luma_weights, make_plan,
                                                space_for_cfa, yuv_space)
from clisp.modules.colour.stage import ColourMatrix
from clisp.modules.demosaic_bilinear.stage import DemosaicBilinear
from clisp.modules.demosaic_lms_guided.stage import DemosaicLMSGuided
from clisp.modules.raw_scale.stage import normalize, white_balance1
from clisp.scene.white_balance_pass2 import estimate_wb2, gray_pixel_gains, illuminant_gains
from tolerance import TOL, assert_close

"""|opencl - reference| <= TOL * max(1, |reference|), everywhere in this file."""

SPACES = {"lms": lms_space(P_LMS), "yuv": yuv_space(B_BAYER),
          "rgb-cfa": space_for_cfa(cfa_from_name("bayer"), B_BAYER, "cfa")}
HALO = ChromaDenoise(SPACES["lms"]).halo            # 52 at the defaults (J = 3, r = 3)
# (window shape, window origin): odd sizes; origins at 0, negative, aligned to 2^J = 8 or not.
WINDOWS = [((2 * HALO + 37, 2 * HALO + 53), (0, 0)),                # window aligned
           ((2 * HALO + 37, 2 * HALO + 53), (-HALO, -HALO)),        # tile at (0, 0): window unaligned
           ((2 * HALO + 41, 2 * HALO + 19), (-48, -16)),            # negative, window aligned
           ((2 * HALO + 30, 2 * HALO + 67), (-61, 13)),             # negative, unaligned
           ((2 * HALO + 9, 2 * HALO + 11), (3, -5))]                # small output (9 x 11 < VEC rows)






def run_stage(rt, stage, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
    src = rt.upload(np.ascontiguousarray(np.moveaxis(x, -1, 0)).astype(np.float32))
    dst = stage.enqueue(rt, src, origin)
    out = np.moveaxis(rt.download(dst), 0, -1)
    rt.release(src)
    rt.release(dst)
    assert out.shape[:2] == stage.output_shape(x.shape[0], x.shape[1])
    return out


def random_table(space, seed: int, levels: int = 3, correlated: bool = False) -> NoiseTable:
    """Noise levels of a mid-gain capture: std ~0.005..0.05 at s = 0.3, random per subband;
    ``correlated``: chroma noise from n - 1 random sources (a rank-deficient correlation, as LMS's
    three planes from two)."""
    rng = np.random.default_rng(seed)
    n = space.n_chroma
    scale = np.array([2e-3, 2e-4])
    corr = None
    if correlated:
        mix = rng.standard_normal((levels + 1, n, max(n - 1, 1)))
        cov = mix @ np.swapaxes(mix, 1, 2)
        sd = np.sqrt(np.einsum("jkk->jk", cov))
        corr = cov / (sd[:, :, None] * sd[:, None, :])
    return NoiseTable(rng.uniform(0.1, 1.0, (levels + 1, 1 + n, 2)) * scale,
                      rng.uniform(0.1, 1.0, (levels + 1, 1 + n, 3, 2)) * scale, corr)


def noisy_camera(shape, seed: int) -> np.ndarray:
    """Smooth colour ramps and a luminance edge plus noise: H x W x 3 white-balanced camera values."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:shape[0], 0:shape[1]] / max(shape)
    base = np.stack([0.3 + 0.3 * x, 0.35 + 0.2 * y, 0.25 + 0.3 * x * y], axis=-1)
    base *= np.where(x > 0.5, 1.6, 1.0)[..., None]
    return base + 0.03 * rng.standard_normal(base.shape)


# ------------------------------------------------------------------------------------------
# colour spaces
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["lms", "yuv", "rgb-cfa"])
def test_space_round_trip_is_the_colour_matrix(name):
    """from_luma Y + from_chroma c == to_rgb cam: with c^ = c the stage is the colour matrix."""
    sp = SPACES[name]
    np.testing.assert_allclose(sp.merge_matrix @ sp.split_matrix, sp.to_rgb, rtol=0, atol=1e-12)


def test_spaces_are_the_papers():
    lms = SPACES["lms"]
    np.testing.assert_allclose(lms.luma, [0.5, 0.5, 0.0])
    np.testing.assert_allclose(lms.chroma, P_LMS - np.outer(np.ones(3), lms.luma))
    assert lms.strengths == (1.0, 1.0, 1.5)
    yuv = SPACES["yuv"]
    rgb = B_BAYER @ np.array([0.2, 0.5, 0.7])
    y = 0.299 * rgb[0] + 0.587 * rgb[1] + 0.114 * rgb[2]
    np.testing.assert_allclose(yuv.split_matrix @ [0.2, 0.5, 0.7], [y, 0.492 * (rgb[2] - y), 0.877 * (rgb[0] - y)])


def test_lumas_of_the_layouts():
    """Issue 45's luminances: the CFA's baseband (its channels' shares of the pixels) and the
    least-noise weighting (shares over the pass-1 gains), in the LMS construction (c_k = RGB_k - Y)."""
    cases = {"bayer": [0.25, 0.5, 0.25], "lms-bayer": [0.25, 0.5, 0.25], "ML/LS": [0.5, 0.25, 0.25],
             "lms": [0.5, 0.375, 0.125]}
    for name, shares in cases.items():
        cfa = cfa_from_name(name)
        np.testing.assert_allclose(luma_weights(cfa, "cfa"), shares)
        gains = np.array([1.0, 1.2191, 3.1397])
        snr = luma_weights(cfa, "snr", gains)
        np.testing.assert_allclose(snr, np.array(shares) / gains / np.sum(np.array(shares) / gains))
        matrix = P_LMS if cfa.spectral == "lms" else B_BAYER
        space = space_for_cfa(cfa, matrix, "cfa")
        assert space.name == f"{cfa.spectral}-cfa" and space.n_chroma == 3
        np.testing.assert_allclose(space.merge_matrix @ space.split_matrix, matrix, atol=1e-12)
    assert space_for_cfa(cfa_from_name("bayer"), B_BAYER).name == "yuv"          # 'paper' is the paper's
    assert space_for_cfa(cfa_from_name("ML/LS"), P_LMS).name == "lms"
    with pytest.raises(ClispError, match="luma"):
        ChromaDenoiseParams(luma="bt709")


def test_haar_is_inverted_exactly():
    a = np.random.default_rng(0).standard_normal((2, 16, 24))
    approx, detail = haar_analyze(a)
    np.testing.assert_allclose(haar_synthesize(approx, detail), a, rtol=0, atol=1e-12)
    np.testing.assert_allclose(approx, a.reshape(2, 8, 2, 12, 2).mean(axis=(2, 4)))


# ------------------------------------------------------------------------------------------
# kernels against the reference
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("vec", [1, 8])
@pytest.mark.parametrize("name", ["lms", "yuv", "rgb-cfa"])
def test_kernels_match_reference(rt, monkeypatch, name, vec):
    """Whole stage (chroma_split, haar_analyze, bayes_shrink, joint_bilateral, haar_synthesize,
    chroma_merge) on odd windows at negative, aligned and unaligned origins; both vector widths."""
    monkeypatch.setattr(cd, "vector_width", lambda rt: vec)
    stage = ChromaDenoise(SPACES[name], random_table(SPACES[name], seed=1))
    for i, (shape, origin) in enumerate(WINDOWS):
        x = noisy_camera(shape, seed=i)
        assert_close(run_stage(rt, stage, x, origin), stage.reference(x, origin), f"{name} {shape} {origin}")


@pytest.mark.parametrize("vec", [1, 8])
@pytest.mark.parametrize("interleaved", [False, True])
@pytest.mark.parametrize("output", ["srgb", "srgb16", "srgb8"])
def test_tone_curve_folded_into_the_merge(rt, monkeypatch, output, interleaved, vec):
    """The pipeline's tone curve folded into chroma_merge's store (ChromaDenoise.fuse(ToneCurve)):
    the stage then outputs what the tone curve would, from the merge's own float32 values: encoded
    floats within the tolerance rule, codes within one code of the reference (where the curve's
    error meets a half code), for both vector widths and both layouts; a white balance pass 2
    before it still folds into the merge, nothing after it."""
    from clisp.modules.colour.stage import WhiteBalance2, tone_curve_for
    monkeypatch.setattr(cd, "vector_width", lambda rt: vec)
    plain = ChromaDenoise(SPACES["lms"], random_table(SPACES["lms"], seed=2))
    tone = tone_curve_for(output)
    stage = plain.fuse(WhiteBalance2(np.array([1.2, 1.0, 0.8]))).fuse(tone)
    assert stage.tone == tone and stage.fuse(tone) is None and stage.out_dtype == tone.out_dtype
    if interleaved:
        stage = stage.with_interleaved_output()
    for i, (shape, origin) in enumerate(WINDOWS[:3]):
        x = noisy_camera(shape, seed=10 + i) * 1.3          # past white: the curve clips
        ref = stage.reference(x, origin)
        src = rt.upload(np.ascontiguousarray(np.moveaxis(x, -1, 0)).astype(np.float32))
        dst = stage.enqueue(rt, src, origin)
        assert dst.dtype == tone.out_dtype and dst.interleaved == interleaved
        got = rt.download(dst)
        got = got if interleaved else np.moveaxis(got, 0, -1)
        rt.release(src)
        rt.release(dst)
        if output == "srgb":
            assert_close(got, ref, f"{output} {shape} {origin}")
        else:
            diff = np.abs(got.astype(np.int32) - ref)
            assert diff.max() <= 1 and np.mean(diff > 0) < 0.05, f"{output} {shape} {origin}"


@pytest.mark.parametrize("params", [
    ChromaDenoiseParams(shrink="wiener"), ChromaDenoiseParams(shrink="none"),
    ChromaDenoiseParams(shrink_guide=False, k_luma=0.0), ChromaDenoiseParams(levels=2, radius=2, shrink_radius=1),
    ChromaDenoiseParams(strengths=(2.0, 0.5, 1.0), noise_scale=1.5),
    ChromaDenoiseParams(range_joint=3.0, range_joint_sigma=(0.0, 0.0), strengths=(1.0, 2.0, 1.5)),
], ids=["wiener", "no-shrink", "unguided", "J2r2", "strengths", "joint"])
def test_kernel_options_match_reference(rt, params):
    space = SPACES["lms"]
    table = random_table(space, seed=2, levels=params.levels, correlated=params.range_joint != "space")
    stage = ChromaDenoise(space, table, params)
    shape, origin = (2 * stage.halo + 29, 2 * stage.halo + 35), (-7, 6)
    x = noisy_camera(shape, seed=5)
    assert_close(run_stage(rt, stage, x, origin), stage.reference(x, origin), str(params))


@pytest.mark.parametrize("vec", [1, 8])
def test_fused_white_balance_and_interleaved_output(rt, monkeypatch, vec):
    """A following WB pass 2 folds into the merge; the interleaved last-stage output is the same
    image (chroma_merge's interleaved stores at both vector widths)."""
    monkeypatch.setattr(cd, "vector_width", lambda rt: vec)
    from clisp.modules.colour.stage import WhiteBalance2
    space = SPACES["yuv"]
    stage = ChromaDenoise(space, random_table(space, seed=7))
    wb2 = WhiteBalance2(np.array([1.1, 1.0, 0.9]))
    fused = stage.fuse(wb2)
    assert isinstance(fused, ChromaDenoise)
    shape, origin = (2 * HALO + 13, 2 * HALO + 17), (4, -9)
    x = noisy_camera(shape, seed=8)
    expected = wb2.reference(stage.reference(x, origin), origin)
    np.testing.assert_allclose(fused.reference(x, origin), expected, rtol=0, atol=1e-12)
    src = rt.upload(np.ascontiguousarray(np.moveaxis(x, -1, 0)).astype(np.float32))
    dst = fused.with_interleaved_output().enqueue(rt, src, origin)
    assert dst.interleaved
    assert_close(rt.download(dst), expected, "fused, interleaved")
    rt.release(src)
    rt.release(dst)


def test_plan_is_anchored_to_image_coordinates():
    """The aligned start is the first multiple of 2^J in image coordinates, whatever the window."""
    for origin in [(0, 0), (-52, -52), (3, -5), (-61, 17)]:
        plan = make_plan(3, 3, 200, 220, origin)
        assert all((o + s) % 8 == 0 for o, s in zip(origin, plan.skip))
        assert all(0 <= c for c in plan.crop)


# ------------------------------------------------------------------------------------------
# behaviour
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["lms", "yuv"])
def test_zero_noise_is_the_colour_matrix(name):
    """No noise: every sigma floors at 1e-6, so the denoiser returns the colour matrix."""
    sp = SPACES[name]
    stage = ChromaDenoise(sp)
    shape, origin = (2 * HALO + 21, 2 * HALO + 26), (-3, 9)
    x = noisy_camera(shape, seed=3)
    h = stage.halo
    expected = ColourMatrix(sp.to_rgb).reference(x, origin)[h:-h, h:-h]
    np.testing.assert_allclose(stage.reference(x, origin), expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", ["lms", "yuv"])
def test_flat_field_unchanged(rt, name):
    """A noiseless flat field stays exactly flat and equal to the colour matrix, noise table or not."""
    sp = SPACES[name]
    stage = ChromaDenoise(sp, random_table(sp, seed=4))
    cam = np.array([0.31, 0.27, 0.12])
    x = np.broadcast_to(cam, (2 * HALO + 16, 2 * HALO + 24, 3)).copy()
    expected = np.broadcast_to(sp.to_rgb @ cam, (16, 24, 3))
    np.testing.assert_allclose(stage.reference(x, (5, -2)), expected, rtol=0, atol=1e-12)
    assert_close(run_stage(rt, stage, x, (5, -2)), expected, name)


def flat_capture(kind: str, gain: float, level: float = 0.18, shape=(192, 256)):
    """Simulated raw of a flat neutral at linear ``level``, no optics."""
    return simulate(np.full(shape + (3,), level), kind, gain=gain, optics="none", seed=11).raw


@pytest.mark.parametrize("kind", ["lms", "bayer"])
def test_reduces_chroma_noise_and_keeps_luminance(kind):
    """On a noisy flat field the chroma std drops >= 5x; the output noise is then close to the
    luminance noise (Y untouched), for every output channel."""
    raw = flat_capture(kind, gain=16)
    cfa = raw.cfa
    demosaic = DemosaicBilinear(cfa)
    head = [normalize(cfa, raw.black_level, raw.white_level), white_balance1(cfa, raw.pass1_gains()), demosaic]
    stage = chroma_denoise_for(raw, demosaic)
    assert isinstance(stage, ChromaDenoise)
    sp = stage.space
    cam = Pipeline(cfa, head).run(raw.data, tile=0)[8:-8, 8:-8].astype(np.float64)
    out = Pipeline(cfa, head + [stage]).run(raw.data, tile=0)[8:-8, 8:-8].astype(np.float64)
    plain = cam @ sp.to_rgb.T
    luma = cam @ sp.luma
    pinv = np.linalg.pinv(sp.from_chroma)
    chroma_in = (plain - luma[..., None] * sp.from_luma) @ pinv.T
    chroma_out = (out - luma[..., None] * sp.from_luma) @ pinv.T
    assert np.all(chroma_out.std(axis=(0, 1)) * 5 <= chroma_in.std(axis=(0, 1)))
    # output noise ~ luminance noise: within 15 % per channel (luminance std from the input)
    assert np.all(np.abs(out.std(axis=(0, 1)) / luma.std() - 1.0) < 0.15)
    if kind == "bayer":      # BT.601 Y of the output is exactly the input's Y (U, V only changed)
        np.testing.assert_allclose(out @ [0.299, 0.587, 0.114], luma, rtol=0, atol=2e-6)


def test_noiseless_raw_keeps_the_colour_matrix():
    raw = flat_capture("lms", gain=None)
    assert raw_noise(raw).is_zero
    assert isinstance(chroma_denoise_for(raw, DemosaicBilinear(raw.cfa)), ColourMatrix)


@pytest.mark.parametrize("kind, tile", [("lms", 64), ("lms", 256), ("bayer", 64), ("bayer", 256), ("lms", 60)])
def test_tiled_equals_untiled(kind, tile):
    """Full pipeline on a 301 x 517 noisy capture; tiles 64 and 256 (origins aligned to 2^J = 8)
    and 60 (unaligned origins: the decimation grid is anchored to image coordinates anyway)."""
    rng = np.random.default_rng(6)
    scene = np.clip(0.2 + 0.15 * rng.standard_normal((301, 517, 3)).cumsum(axis=1) / 20, 0, 1)
    raw = simulate(scene, kind, gain=8, optics="none", seed=2).raw
    cfa = raw.cfa
    demosaic = DemosaicBilinear(cfa)
    stages = [normalize(cfa, raw.black_level, raw.white_level), white_balance1(cfa, raw.pass1_gains()),
              demosaic, chroma_denoise_for(raw, demosaic)]
    pipe = Pipeline(cfa, stages)
    assert pipe.align == 8
    whole = pipe.run(raw.data, tile=0)
    assert_close(pipe.run(raw.data, tile=tile), whole, f"{kind} tile {tile}")


def test_calibration_follows_the_noise():
    """Zero noise -> zero table; the measured level-0 luminance variance of a bilinear LMS demosaic
    scales with the raw variance (4x the noise variance -> ~4x the table)."""
    cfa = cfa_from_name("lms")
    sp, dem = SPACES["lms"], DemosaicBilinear(cfa)
    assert calibrate_noise(dem, cfa, sp, ChannelNoise.zero()).is_zero
    noise = ChannelNoise.from_model(NoiseModel(), 16.0, np.array([1.0, 1.2191, 3.1397]) / 0.98951)
    t1 = calibrate_noise(dem, cfa, sp, noise, size=192)
    t4 = calibrate_noise(dem, cfa, sp, noise.scaled(2.0), size=192)
    v1 = t1.approx[0, 0, 0] * 0.2 + t1.approx[0, 0, 1]
    v4 = t4.approx[0, 0, 0] * 0.2 + t4.approx[0, 0, 1]
    assert 3.6 < v4 / v1 < 4.4


def test_calibration_on_opencl_equals_reference():
    """The calibration's flat fields through the demosaic's kernels give the reference's table
    within float32 rounding (variances: relative 1e-4)."""
    cfa = cfa_from_name("lms")
    sp = SPACES["lms"]
    noise = ChannelNoise.from_model(NoiseModel(), 8.0, np.array([1.0, 1.2191, 3.1397]) / 0.98951)
    for dem in (DemosaicBilinear(cfa), DemosaicLMSGuided(cfa, noise=noise)):
        ref = calibrate_noise(dem, cfa, sp, noise, size=128)
        cl = calibrate_noise(dem, cfa, sp, noise, size=128, rt=get_runtime())
        np.testing.assert_allclose(cl.approx, ref.approx, rtol=1e-4, atol=1e-12)
        np.testing.assert_allclose(cl.detail, ref.detail, rtol=1e-4, atol=1e-12)


# ------------------------------------------------------------------------------------------
# noise from the raw
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("kind", ["lms", "bayer"])
def test_noise_estimate_matches_the_model(kind):
    """On a smooth simulated capture the blind estimate is within 15 % of the model's std."""
    y, x = np.mgrid[0:384, 0:512] / 512.0
    scene = np.stack([0.05 + 0.6 * x, 0.05 + 0.5 * x, 0.05 + 0.4 * x + 0.1 * y], axis=-1)
    raw = simulate(scene, kind, gain=16, optics="none", seed=3).raw
    model = raw_noise(raw)
    assert model.source == "model"
    est = estimate_raw_noise(raw.data, raw.cfa, raw.black_level, raw.white_level, raw.pass1_gains())
    for c in range(raw.cfa.n_channels):
        for s in (0.1, 0.4):
            ratio = np.sqrt(est.variance(c, s) / model.variance(c, s))
            assert abs(ratio - 1) < 0.15, (c, s, ratio)


def test_raw_noise_without_metadata_is_estimated():
    raw = flat_capture("bayer", gain=8)
    raw.metadata = {}
    assert raw_noise(raw).source == "estimate"


# ------------------------------------------------------------------------------------------
# white balance pass 2
# ------------------------------------------------------------------------------------------

def test_illuminant_gains_of_the_spec():
    np.testing.assert_allclose(illuminant_gains(P_LMS), [1.0, 1.0101, 1.0753], atol=1e-4)
    np.testing.assert_allclose(illuminant_gains(B_BAYER), [1.0, 1.0, 1.0], atol=1e-12)


def test_metadata_pass2_is_identity_for_rgb_sourced_simulations():
    raw = flat_capture("lms", gain=4)
    np.testing.assert_array_equal(estimate_wb2(raw, "metadata"), np.ones(3))
    raw.metadata["illuminant_white"] = [1.0, 1.0, 1.0]
    np.testing.assert_allclose(estimate_wb2(raw, "metadata"), illuminant_gains(P_LMS))


@pytest.mark.parametrize("kind", ["lms", "bayer"])
def test_gray_pixels_recover_a_colour_cast(kind):
    """ColorChecker under a warm cast: the gray-pixel estimate is within 1 degree of the cast's
    inverse; gray world is less accurate on this chart."""
    chart, _ = colorchecker(patch=32, gap=8)
    cast = np.array([1.25, 1.0, 0.7])
    raw = simulate(chart * cast * 0.8, kind, gain=8, seed=1).raw
    truth = (1.0 / cast) / (1.0 / cast[1])

    def angle(g):
        return np.degrees(np.arccos(g @ truth / np.linalg.norm(g) / np.linalg.norm(truth)))
    assert angle(estimate_wb2(raw, "gray_pixels")) < 1.0
    assert angle(estimate_wb2(raw, "gray_world")) < 5.0


def test_gray_pixels_ignore_saturated_colours():
    """Neutrals under a cast plus saturated reds: gray pixels give exactly the inverse cast."""
    cast = np.array([1.3, 1.0, 0.8])
    neutral = np.linspace(0.1, 0.9, 50)[:, None] * cast
    red = np.tile([0.9, 0.1, 0.05], (15, 1))
    gains = gray_pixel_gains(np.vstack([neutral, red]))
    np.testing.assert_allclose(gains, 1.0 / cast, rtol=1e-9)


def test_large_raws_are_sampled(monkeypatch):
    """Big (memory-mapped) raws: the WB thumbnail takes every k-th CFA tile, the noise estimate a
    grid of crops; both give the same answers as the full read on a uniform capture."""
    import clisp.scene.noise as ne
    from clisp.scene.statistics import thumbnail
    y, x = np.mgrid[0:512, 0:768] / 768.0
    scene = np.stack([0.1 + 0.5 * x, 0.1 + 0.4 * x, 0.1 + 0.3 * x + 0.1 * y], axis=-1)
    raw = simulate(scene, "lms", gain=16, optics="none", seed=4).raw
    full, ok = thumbnail(raw.data, raw.cfa, raw.black_level, raw.white_level)
    part, ok2 = thumbnail(raw.data, raw.cfa, raw.black_level, raw.white_level,
                          max_cells=full.shape[0] * full.shape[1] // 8)   # k = ceil(sqrt(8)) = 3
    np.testing.assert_array_equal(part, full[::3, ::3])
    np.testing.assert_array_equal(ok2, ok[::3, ::3])
    whole = estimate_raw_noise(raw.data, raw.cfa, raw.black_level, raw.white_level, raw.pass1_gains())
    monkeypatch.setattr(ne, "SAMPLE_PIXELS", 200_000)
    monkeypatch.setattr(ne, "SAMPLE_CROP", 128)
    assert len(ne.sample_crops(512, 768, ne.SAMPLE_PIXELS, ne.SAMPLE_CROP)) > 1
    sampled = ne.estimate_raw_noise(raw.data, raw.cfa, raw.black_level, raw.white_level, raw.pass1_gains())
    for c in range(3):
        assert abs(np.sqrt(sampled.variance(c, 0.3) / whole.variance(c, 0.3)) - 1) < 0.1


def test_chroma_range_cap_keeps_colour_edges_at_high_noise() -> None:
    """Bayer (YUV): the cap leaves k_chroma at gain 16 and lowers it at gain 64, where the ring
    just outside a green patch on grey (an edge the luminance hardly marks) keeps its colour better
    (issue 17; tools/bench_bleeding.py measures the whole chart). On DLMMSE, the Bayer demosaic the
    cap was designed and measured on: behind RI (the quality default since issue 27) the noise
    reaching the denoiser is higher and the cap already acts at gain 16 (factor 0.57)."""
    from clisp.sim.charts import colorchecker_linear
    from clisp.metrics import linear_srgb_to_lab
    from clisp.pipeline import build_pipeline
    from clisp.sim.simulate import simulate
    scene = np.full((160, 160, 3), 0.18)
    scene[56:104, 56:104] = colorchecker_linear()[13]                 # green
    yy, xx = np.mgrid[0:160, 0:160]
    d = np.maximum(np.maximum(56 - yy, yy - 103), np.maximum(56 - xx, xx - 103))
    ring = (d >= 3) & (d <= 10)
    factors, shifts = {}, {}
    for gain in (16, 64):
        sim = simulate(scene, cfa="bayer", gain=gain, seed=4)
        for cap in ("space", None):
            pipe = build_pipeline(sim.raw, demosaic="dlmmse",
                                  denoise=ChromaDenoiseParams(chroma_range_cap=cap, range_joint=0.0))
            stage = next(s for s in pipe.stages if isinstance(s, ChromaDenoise))
            factors[gain, cap] = stage.range_cap_factor()
            if gain == 64:
                out = pipe.run(sim.raw.data)
                a = linear_srgb_to_lab(out[ring].mean(axis=0)[None, None])[0, 0]
                b = linear_srgb_to_lab(sim.truth[ring].mean(axis=0)[None, None])[0, 0]
                shifts[cap] = float(np.hypot(*(a - b)[1:]))
    assert factors[16, "space"] == 1.0 and factors[64, None] == 1.0
    assert 0.3 < factors[64, "space"] < 0.6
    assert shifts["space"] < 0.7 * shifts[None], shifts


def test_joint_range_keeps_colour_edges_at_high_noise() -> None:
    """Bayer (YUV, range_joint 'space' = 1): at the coarse levels U and V share one range weight,
    so the blue sky's edge, plain in U, also stops V from being averaged across it: the ring just
    outside the patch keeps its colour better at gain 64 than with a weight per plane (issue 17). On
    DLMMSE, the demosaic it was measured on (behind RI the gain is smaller: 1.34 against 1.68)."""
    from clisp.sim.charts import colorchecker_linear
    from clisp.metrics import linear_srgb_to_lab
    from clisp.pipeline import build_pipeline
    from clisp.sim.simulate import simulate
    scene = np.full((160, 160, 3), 0.18)
    scene[56:104, 56:104] = colorchecker_linear()[2]                  # blue sky
    yy, xx = np.mgrid[0:160, 0:160]
    d = np.maximum(np.maximum(56 - yy, yy - 103), np.maximum(56 - xx, xx - 103))
    ring = (d >= 3) & (d <= 10)
    shifts = {"space": 0.0, 0.0: 0.0}
    for seed in (4, 5):
        sim = simulate(scene, cfa="bayer", gain=64, seed=seed)
        for joint in shifts:
            pipe = build_pipeline(sim.raw, demosaic="dlmmse", denoise=ChromaDenoiseParams(range_joint=joint))
            stage = next(s for s in pipe.stages if isinstance(s, ChromaDenoise))
            assert stage.range_joint(0) == 0.0 and stage.range_joint(1) == (1.0 if joint == "space" else 0.0)
            out = pipe.run(sim.raw.data)
            a = linear_srgb_to_lab(out[ring].mean(axis=0)[None, None])[0, 0]
            b = linear_srgb_to_lab(sim.truth[ring].mean(axis=0)[None, None])[0, 0]
            shifts[joint] += float(np.hypot(*(a - b)[1:]))
    assert shifts["space"] < 0.75 * shifts[0.0], shifts


def test_range_joint_is_checked() -> None:
    with pytest.raises(ClispError):
        ChromaDenoiseParams(range_joint=-1.0)


def test_range_metric_is_the_mahalanobis_distance() -> None:
    """Uncorrelated planes: range_joint times the mean of the planes' own terms; correlated planes
    from fewer sources: the pseudo-inverse over the sources' rank, so a difference along the noise
    gets the same penalty however many planes carry it; level 0 and low noise have no joint term."""
    space = SPACES["lms"]
    plain = ChromaDenoise(space, random_table(space, seed=3), ChromaDenoiseParams(
        range_joint=2.0, range_joint_sigma=(0.0, 0.0), strengths=(1.0, 1.0, 1.0)))
    np.testing.assert_allclose(plain.range_metric(1), 2.0 * np.eye(3) / 3)
    assert plain.range_metric(0) is None
    table = random_table(space, seed=4, correlated=True)
    stage = ChromaDenoise(space, table, ChromaDenoiseParams(range_joint=2.0, range_joint_sigma=(0.0, 0.0),
                                                            strengths=(1.0, 1.0, 1.0)))
    r = table.correlation(2, 3)
    m = stage.range_metric(2)
    # for noise z ~ N(0, R): E[z^T M z] = tr(M R) = range_joint tr(R^+ R) / rank = range_joint
    assert np.trace(m @ r) == pytest.approx(2.0, rel=1e-6)
    faded = ChromaDenoise(space, random_table(space, seed=3), ChromaDenoiseParams(
        range_joint=2.0, range_joint_sigma=(1.0, 2.0)))
    assert faded.range_joint(1) == 0.0 and faded.range_metric(1) is None


def test_calibration_is_remembered_for_the_same_inputs_only():
    """A second pipeline for a raw of the same camera and gain reuses the noise table (the same
    object, read-only); another gain or demosaic calibrates anew."""
    from clisp.pipeline import build_pipeline
    from clisp.sim.simulate import simulate
    from clisp.modules.chroma_denoise.stage import ChromaDenoise

    def table(gain, demosaic=None):
        raw = simulate(np.full((64, 64, 3), 0.3), "lms", gain=gain, seed=1).raw
        stage = next(s for s in build_pipeline(raw, demosaic=demosaic).stages if isinstance(s, ChromaDenoise))
        return stage.noise

    first = table(4.0)
    assert table(4.0) is first
    assert not first.approx.flags.writeable
    other = table(16.0)
    assert other is not first and not np.allclose(other.approx, first.approx)
    assert table(4.0, "hybrid") is not first


def test_calibration_is_kept_on_disk_per_code_and_device(tmp_path, monkeypatch):
    """A calibration measured once is read back by a later process (the in-process memory emptied)
    from the cache folder, equal to the last bit; damaged, it is measured again; a change of the
    clisp code (its fingerprint) or of the device (reference against OpenCL) never reads it."""
    from clisp.engine import disk_cache
    chroma_stage = cd
    monkeypatch.setenv("CLISP_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(chroma_stage, "_CALIBRATIONS", {})
    cfa, sp = cfa_from_name("lms"), SPACES["lms"]
    noise = ChannelNoise.from_model(NoiseModel(), 8.0, np.array([1.0, 1.2191, 3.1397]) / 0.98951)
    dem = DemosaicBilinear(cfa)
    rt = get_runtime()
    measured = calibrate_noise(dem, cfa, sp, noise, size=64, rt=rt)
    (kept,) = (tmp_path / "calibration").iterdir()
    monkeypatch.setattr(chroma_stage, "_CALIBRATIONS", {})
    calls = []
    real = chroma_stage.measure_calibration
    monkeypatch.setattr(chroma_stage, "measure_calibration", lambda *a, **k: calls.append(1) or real(*a, **k))
    again = calibrate_noise(dem, cfa, sp, noise, size=64, rt=rt)
    assert not calls and again is not measured
    for a, b in ((again.approx, measured.approx), (again.detail, measured.detail), (again.corr, measured.corr)):
        assert (a is None and b is None) or np.array_equal(a, b)
    kept.write_bytes(b"not a table")
    monkeypatch.setattr(chroma_stage, "_CALIBRATIONS", {})
    calibrate_noise(dem, cfa, sp, noise, size=64, rt=rt)
    assert len(calls) == 1
    monkeypatch.setattr(chroma_stage, "_CALIBRATIONS", {})
    monkeypatch.setattr(disk_cache, "_FINGERPRINT", "edited code")
    calibrate_noise(dem, cfa, sp, noise, size=64, rt=rt)
    assert len(calls) == 2 and len(list((tmp_path / "calibration").iterdir())) == 2
    calibrate_noise(dem, cfa, sp, noise, size=64)                 # the NumPy reference: its own entry
    assert len(calls) == 3 and len(list((tmp_path / "calibration").iterdir())) == 3
