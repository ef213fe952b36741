"""Every OpenCL kernel against its NumPy reference (on PoCL), plus properties of the references.

Tolerance, used by every OpenCL-vs-reference comparison in this file (float32 kernels against
float64 references; raw inputs in DN scale):

    |opencl - reference| <= TOL * max(1, |reference|)
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy import ndimage

from clisp.cfa import CFA, cfa_from_name
from clisp.sim.colorimetry import B_BAYER, P_LMS, WB_BAYER, WB_LMS
from clisp.pipeline import build_pipeline
from clisp.io.rawimage import RawImage
from clisp.engine.runtime import DeviceImage
from clisp.engine.stage import fuse_stages
from clisp.modules.colour.stage import ColourMatrix, ToneCurve, WhiteBalance2
from clisp.modules.demosaic_bilinear.stage import DemosaicBilinear
from clisp.modules.linear_filter import stage as linear_filter
from clisp.modules.linear_filter.stage import LinearPhaseFilter
from clisp.modules.raw_scale.stage import CfaAffine, normalize, white_balance1
from tolerance import TOL, assert_close

"""|opencl - reference| <= TOL * max(1, |reference|), everywhere in this file."""

ORIGINS = [(0, 0), (1, 3), (-2, -5), (5, 2)]
CFA_NAMES = ["lms", "lms@1,2", "bayer-rggb", "bayer-grbg", "bayer-gbrg", "bayer-bggr"]
SHAPE = (37, 53)                      # odd on purpose: not a multiple of any CFA period
BLACK = np.array([64.0, 65.0, 66.0])
WHITE = 1023.0
K_EXP = 0.98951






def to_device(rt, x: np.ndarray) -> DeviceImage:
    """H x W raw, or H x W x C image (uploaded planar)."""
    if x.ndim == 2:
        return rt.upload(x)
    return rt.upload(np.ascontiguousarray(np.moveaxis(x, -1, 0)))


def from_device(rt, image: DeviceImage) -> np.ndarray:
    """H x W for one plane, else H x W x C whatever the device layout."""
    host = rt.download(image)
    if image.channels > 1 and not image.interleaved:
        host = np.moveaxis(host, 0, -1)
    return host


def run_stage(rt, stage, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
    src = to_device(rt, x)
    dst = stage.enqueue(rt, src, origin)
    out = from_device(rt, dst)
    rt.release(src)
    rt.release(dst)
    h, w = stage.output_shape(x.shape[0], x.shape[1])
    assert out.shape[:2] == (h, w)
    return out


def random_raw(dtype, seed: int, shape=SHAPE) -> np.ndarray:
    """Raw mosaic in DN: uint16 0..4095 (some above white) or float32 -30..1100 (negatives kept)."""
    rng = np.random.default_rng(seed)
    if dtype == np.uint16:
        return rng.integers(0, 4096, size=shape, dtype=np.uint16)
    return (rng.random(shape) * 1130.0 - 30.0).astype(np.float32)


def random_mosaic(seed: int, shape=SHAPE) -> np.ndarray:
    """Normalised, white-balanced mosaic (what the demosaic sees), float32."""
    return np.random.default_rng(seed).uniform(-0.05, 1.3, size=shape).astype(np.float32)


def random_rgb(seed: int, shape=SHAPE) -> np.ndarray:
    """H x W x 3 float32 values spanning -0.1 .. 1.2."""
    return np.random.default_rng(seed).uniform(-0.1, 1.2, size=shape + (3,)).astype(np.float32)


# ------------------------------------------------------------------------------------------
# raw scaling: normalise and WB pass 1 (kernel raw.cl: cfa_affine)
# ------------------------------------------------------------------------------------------

def raw_stages(cfa: CFA):
    return [normalize(cfa, BLACK, WHITE), white_balance1(cfa, WB_LMS / K_EXP)]


@pytest.mark.parametrize("dtype", [np.uint16, np.float32])
@pytest.mark.parametrize("name", CFA_NAMES)
def test_raw_scale_kernels(rt, name, dtype):
    cfa = cfa_from_name(name)
    x = random_raw(dtype, seed=CFA_NAMES.index(name))
    for stage in raw_stages(cfa):
        for origin in ORIGINS:
            ref = stage.reference(x, origin)
            # the reference itself: channel of pixel (y, x) is pattern[(y + oy) % p, (x + ox) % p]
            p = cfa.period
            ys = (np.arange(x.shape[0]) + origin[0]) % p
            xs = (np.arange(x.shape[1]) + origin[1]) % p
            ch = cfa.pattern[ys[:, None], xs[None, :]]
            np.testing.assert_allclose(ref, (x.astype(np.float64) - stage.offset[ch]) * stage.scale[ch],
                                       rtol=1e-15, atol=0)
            assert_close(run_stage(rt, stage, x, origin), ref, f"{stage.name} {name} {origin}")


def test_normalize_maps_black_and_white(rt):
    """Black level -> 0 and white level -> 1 in every channel."""
    cfa = cfa_from_name("lms")
    stage = normalize(cfa, BLACK, WHITE)
    ch = cfa.channel_map(*SHAPE)
    x = BLACK[ch].astype(np.float32)
    assert_close(run_stage(rt, stage, x, (0, 0)), np.zeros(SHAPE), "black")
    assert_close(run_stage(rt, stage, np.full(SHAPE, WHITE, np.float32), (0, 0)), np.ones(SHAPE), "white")


def test_affine_fusion(rt):
    """Two CFA affines fuse into one equal to applying them in turn (non-zero offsets on both)."""
    rng = np.random.default_rng(7)
    cfa = cfa_from_name("lms@1,2")
    a = CfaAffine(cfa, rng.uniform(50, 70, 3), rng.uniform(0.5, 2.0, 3) / WHITE)
    b = CfaAffine(cfa, rng.uniform(-0.1, 0.1, 3), rng.uniform(0.5, 3.0, 3))
    fused = a.fuse(b)
    assert fused is not None
    x = random_raw(np.float32, seed=8)
    for origin in ORIGINS:
        ref = b.reference(a.reference(x, origin), origin)
        np.testing.assert_allclose(fused.reference(x, origin), ref, rtol=1e-12, atol=1e-12)
        assert_close(run_stage(rt, fused, x, origin), ref, f"fused affine {origin}")


# ------------------------------------------------------------------------------------------
# bilinear demosaic (kernel demosaic_linear.cl: phase_filter with derived weights)
# ------------------------------------------------------------------------------------------

# OpenCL origins per CFA: every origin for lms, two (rotating) for the others, so that each
# origin is run on LMS and on Bayer without compiling a program per (CFA, origin) pair.
DEMOSAIC_KERNEL_ORIGINS = {
    "lms": ORIGINS,
    "lms@1,2": [(-2, -5), (5, 2)],
    "bayer-rggb": [(0, 0), (1, 3)],
    "bayer-grbg": [(-2, -5), (5, 2)],
    "bayer-gbrg": [(1, 3), (-2, -5)],
    "bayer-bggr": [(5, 2), (0, 0)],
}


@pytest.mark.parametrize("name", CFA_NAMES)
def test_demosaic_bilinear_kernel(rt, name):
    cfa = cfa_from_name(name)
    stage = DemosaicBilinear(cfa)
    assert stage.halo == (2 if cfa.kind == "lms" else 1)
    phase_filter = stage.as_phase_filter()
    assert phase_filter.halo == stage.halo
    x = random_mosaic(seed=20 + CFA_NAMES.index(name))
    for origin in ORIGINS:
        ref = stage.reference(x, origin)
        assert ref.shape == (SHAPE[0] - 2 * stage.halo, SHAPE[1] - 2 * stage.halo, 3)
        np.testing.assert_allclose(phase_filter.reference(x, origin), ref, rtol=0, atol=1e-12,
                                   err_msg=f"as_phase_filter reference {name} {origin}")
        if origin in DEMOSAIC_KERNEL_ORIGINS[name]:
            assert_close(run_stage(rt, stage, x, origin), ref, f"demosaic {name} {origin}")


def test_demosaic_bilinear_kernel_uint16(rt):
    """The demosaic kernel also reads raw DN directly (RAW_T ushort)."""
    stage = DemosaicBilinear(cfa_from_name("lms"))
    x = random_raw(np.uint16, seed=30)
    ref = stage.reference(x, (0, 0))
    assert_close(run_stage(rt, stage, x, (0, 0)), ref, "demosaic uint16")


@pytest.mark.parametrize("name", CFA_NAMES)
def test_demosaic_bilinear_keeps_samples(name):
    cfa = cfa_from_name(name)
    stage = DemosaicBilinear(cfa)
    r = stage.halo
    x = random_mosaic(seed=40)
    for origin in ORIGINS:
        out = stage.reference(x, origin)
        inner = x[r:-r, r:-r].astype(np.float64)
        ch = cfa.channel_map(inner.shape[0], inner.shape[1], (origin[0] + r, origin[1] + r))
        for c in range(3):
            assert np.array_equal(out[..., c][ch == c], inner[ch == c]), (name, origin, c)
        # and a channel at another channel's site is an interpolation, not the sample itself
        assert not np.array_equal(out[..., 0][ch != 0], inner[ch != 0])


@pytest.mark.parametrize("name", CFA_NAMES)
def test_demosaic_bilinear_flat_field(rt, name):
    cfa = cfa_from_name(name)
    stage = DemosaicBilinear(cfa)
    x = np.full(SHAPE, 0.4375, dtype=np.float32)
    for origin in ORIGINS:
        out = stage.reference(x, origin)
        np.testing.assert_allclose(out, 0.4375, rtol=0, atol=1e-12)
    origin = DEMOSAIC_KERNEL_ORIGINS[name][0]
    assert_close(run_stage(rt, stage, x, origin), np.full(out.shape, 0.4375), f"flat {name}")


@pytest.mark.parametrize("name", ["bayer-rggb", "bayer-grbg", "bayer-gbrg", "bayer-bggr"])
def test_demosaic_bilinear_is_classic_bayer_bilinear(name):
    """Bayer: G = [[0,1,0],[1,4,1],[0,1,0]]/4 on the G samples, R and B = [[1,2,1],[2,4,2],[1,2,1]]/4
    on theirs (the textbook bilinear demosaic), in the interior."""
    cfa = cfa_from_name(name)
    stage = DemosaicBilinear(cfa)
    k_g = np.array([[0, 1, 0], [1, 4, 1], [0, 1, 0]]) / 4.0
    k_rb = np.array([[1, 2, 1], [2, 4, 2], [1, 2, 1]]) / 4.0
    x = random_mosaic(seed=50).astype(np.float64)
    for origin in ORIGINS:
        ch = cfa.channel_map(x.shape[0], x.shape[1], origin)
        classic = np.stack([ndimage.convolve(x * (ch == c), k_g if c == 1 else k_rb, mode="constant")
                            for c in range(3)], axis=-1)[1:-1, 1:-1]
        np.testing.assert_allclose(stage.reference(x, origin), classic, rtol=0, atol=1e-12)


# ------------------------------------------------------------------------------------------
# generic per-phase linear filter (random dense weights)
# ------------------------------------------------------------------------------------------

# (radius, cfa, encode, interleaved, origin, input dtype): every combination of radius, encode and
# interleave once; origins rotate so each radius sees all four, LMS and Bayer both appear for each
# radius, and float32 input (in -0.05..1.3) alternates with uint16 DN input (0..1023, weights
# scaled by 1/1023). One program per case keeps compile time down.
LPF_CASES = [
    (1, "lms", False, False, (0, 0), np.float32),
    (1, "lms", False, True, (1, 3), np.uint16),
    (1, "bayer-gbrg", True, False, (-2, -5), np.float32),
    (1, "lms", True, True, (5, 2), np.uint16),
    (2, "bayer-grbg", False, False, (-2, -5), np.uint16),
    (2, "bayer-grbg", False, True, (5, 2), np.float32),
    (2, "lms@1,2", True, False, (1, 3), np.uint16),
    (2, "bayer-grbg", True, True, (0, 0), np.float32),
]


@pytest.mark.parametrize("radius, name, encode, interleaved, origin, dtype", LPF_CASES,
                         ids=[f"r{r}-{n}-enc{int(e)}-il{int(i)}-{d.__name__}" for r, n, e, i, o, d in LPF_CASES])
def test_linear_phase_filter(rt, radius, name, encode, interleaved, origin, dtype):
    cfa = cfa_from_name(name)
    k, taps = cfa.period ** 2, (2 * radius + 1) ** 2
    rng = np.random.default_rng(100 + radius * 10 + 2 * encode + interleaved)
    weights = rng.normal(size=(k, 3, taps)) * 2.0 / taps + 1.0 / taps     # dense: no zero tap
    assert np.all(weights != 0)
    bias = rng.uniform(-0.1, 0.1, size=(k, 3))
    if dtype == np.uint16:
        x = rng.integers(0, 1024, size=SHAPE, dtype=np.uint16)
        weights = weights / 1023.0
    else:
        x = rng.uniform(-0.05, 1.3, size=SHAPE).astype(np.float32)
    f = LinearPhaseFilter(cfa, radius, weights, bias, encode=encode, interleaved=interleaved)
    ref = f.reference(x, origin)
    assert ref.shape == (SHAPE[0] - 2 * radius, SHAPE[1] - 2 * radius, 3)
    if encode:
        assert ref.min() >= 0 and ref.max() <= 1
        assert np.mean(ref == 0) < 0.5 and np.mean(ref == 1) < 0.5      # mostly inside the curve
    src = to_device(rt, x)
    dst = f.enqueue(rt, src, origin)
    assert dst.interleaved == interleaved and dst.channels == 3
    assert_close(from_device(rt, dst), ref, f"phase_filter r={radius} {name} {origin} {dtype.__name__}")
    rt.release(src)
    rt.release(dst)


@pytest.mark.parametrize("name, radius, shape", [("bayer-grbg", 1, (38, 70)), ("lms", 2, (40, 76))])
@pytest.mark.parametrize("encode, quantize", [(False, False), (True, False), (True, True)])
def test_linear_phase_filter_whole_blocks(rt, name, radius, shape, encode, quantize):
    """Outputs of whole CFA blocks take the launch without bounds checks (EXACT): same result."""
    cfa = cfa_from_name(name)
    k, taps = cfa.period ** 2, (2 * radius + 1) ** 2
    rng = np.random.default_rng(7)
    weights = rng.normal(size=(k, 3, taps)) * 2.0 / taps + 1.0 / taps
    x = rng.uniform(-0.05, 1.3, size=shape).astype(np.float32)
    f = LinearPhaseFilter(cfa, radius, weights, rng.uniform(-0.1, 0.1, size=(k, 3)), encode=encode,
                          quantize=quantize, interleaved=True)
    out_h, out_w = f.output_shape(*shape)
    assert out_h % cfa.period == 0 and out_w % cfa.period == 0
    ref = f.reference(x, (2, -3))
    got = run_stage(rt, f, x, (2, -3))
    if quantize:
        assert got.dtype == np.uint16 and np.abs(got.astype(np.int32) - ref).max() <= 1
    else:
        assert_close(got, ref, f"phase_filter exact {name}")


BAYER_NAMES = ["bayer-rggb", "bayer-grbg", "bayer-gbrg", "bayer-bggr"]


@pytest.mark.parametrize("name", BAYER_NAMES)
@pytest.mark.parametrize("dtype", [np.uint16, np.float32])
def test_linear_phase_filter_factored(rt, name, dtype):
    """Normalise + WB + bilinear + matrix fuse into a filter that keeps its factors
    (weights == mix @ basis); the per-column kernel computing the factored form equals the chain
    of references, for every column and row phase (two origins, even output height)."""
    cfa = cfa_from_name(name)
    matrix = np.array([[1.7, -0.5, -0.2], [-0.3, 1.6, -0.3], [0.05, -0.6, 1.55]])
    chain = [normalize(cfa, BLACK, WHITE), white_balance1(cfa, np.array([2.0, 1.0, 1.6])),
             DemosaicBilinear(cfa), ColourMatrix(matrix)]
    fused = fuse_stages(chain)
    assert len(fused) == 1
    f = fused[0].with_interleaved_output()
    assert isinstance(f, LinearPhaseFilter) and f.factored
    np.testing.assert_allclose(np.einsum("cd,kdt->kct", f.mix, f.basis), f.weights, rtol=1e-12, atol=1e-15)
    rng = np.random.default_rng(41 + BAYER_NAMES.index(name))
    shape = (38, 70)
    x = (rng.integers(0, 1024, size=shape) if dtype == np.uint16 else rng.uniform(-30, 1100, size=shape))
    x = x.astype(dtype)
    for origin in [(0, 0), (1, 3)]:
        ref, o = x, origin
        for stage in chain:
            ref = stage.reference(ref, o)
            o = (o[0] + stage.halo, o[1] + stage.halo)
        assert f.output_shape(*shape)[0] % cfa.period == 0            # the per-column kernel runs
        assert_close(run_stage(rt, f, x, origin), ref, f"factored phase_filter {name} {origin}")


def _eight_per_item_equals(rt, monkeypatch, f: LinearPhaseFilter, x: np.ndarray, origin: tuple[int, int],
                           what: str) -> None:
    """``f`` run with the CPU devices' eight-per-item kernel equals its kernel elsewhere bit for bit
    and the reference under the rule (codes: one off where the curve's error meets a half code)."""
    monkeypatch.setattr(linear_filter, "eight_per_item", lambda rt: True)
    eight = run_stage(rt, f, x, origin)
    monkeypatch.setattr(linear_filter, "eight_per_item", lambda rt: False)
    other = run_stage(rt, f, x, origin)
    assert eight.dtype == f.out_dtype and np.array_equal(eight, other), what
    ref = f.reference(x, origin)
    if f.quantize:
        assert np.abs(eight.astype(np.int32) - ref).max() <= 1
    else:
        assert_close(eight, ref, what)


PX8_CASES = [(False, False, 16), (True, False, 16), (True, True, 16), (True, True, 8)]


@pytest.mark.parametrize("dense", [False, True], ids=["factored", "dense"])
@pytest.mark.parametrize("encode, quantize, bits", PX8_CASES, ids=["linear", "srgb", "srgb16", "srgb8"])
def test_phase_filter_px8_equals_per_column(rt, monkeypatch, dense, encode, quantize, bits):
    """On a CPU device an interleaved period-2 filter runs phase_filter_px8 (eight columns per
    work-item, the tone curve in its store): it equals the per-column kernel phase_filter_px bit for
    bit (each lane the same sums in the same order) and the reference under the rule (codes: one
    off where the curve's error meets a half code), for both column parities of the last
    work-item (output widths 68 and 69) and two origins."""
    cfa = cfa_from_name("bayer-grbg")
    chain = [normalize(cfa, BLACK, WHITE), white_balance1(cfa, np.array([2.0, 1.0, 1.6])), DemosaicBilinear(cfa),
             ColourMatrix(np.array([[1.7, -0.5, -0.2], [-0.3, 1.6, -0.3], [0.05, -0.6, 1.55]]))]
    f = fuse_stages(chain)[0]
    if dense:
        f = replace(f, basis=None, mix=None)
    f = replace(f, encode=encode, quantize=quantize, bits=bits, interleaved=True)
    assert f.factored != dense
    rng = np.random.default_rng(8)
    for shape in ((38, 70), (38, 71)):
        x = rng.integers(0, 1024, size=shape).astype(np.uint16)
        for origin in ((0, 0), (1, 3)):
            _eight_per_item_equals(rt, monkeypatch, f, x, origin, f"phase_filter_px8 {shape} {origin}")


P4X8_CASES = [(False, 16), (True, 16), (True, 8)]


@pytest.mark.parametrize("quantize, bits", P4X8_CASES, ids=["srgb", "srgb16", "srgb8"])
def test_phase_filter_p4x8_equals_the_block_kernel(rt, monkeypatch, quantize, bits):
    """On a CPU device an LMS (period 4) filter ending in the tone curve runs phase_filter_p4x8 (eight
    columns per work-item, each phase once for two pixels, the curve in its store): it equals the
    block kernel with the curve inside bit for bit and the reference under the rule (codes: one off
    where the curve's error meets a half code), for every row and column phase (four origins) and a
    last work-item that overlaps its neighbour (output width 68: 8 x 8 + 4)."""
    cfa = cfa_from_name("lms")
    chain = [normalize(cfa, BLACK, WHITE), white_balance1(cfa, np.array([1.0, 1.2, 3.1])), DemosaicBilinear(cfa),
             ColourMatrix(np.array([[1.7, -0.5, -0.2], [-0.3, 1.6, -0.3], [0.05, -0.6, 1.55]]))]
    f = replace(fuse_stages(chain)[0], encode=True, quantize=quantize, bits=bits, interleaved=True)
    rng = np.random.default_rng(9)
    halo = 2 * f.radius
    for shape in ((16 + halo, 64 + halo), (16 + halo, 68 + halo)):
        x = rng.integers(0, 1024, size=shape).astype(np.uint16)
        for origin in ((0, 0), (1, 3), (2, 1), (3, 2)):
            _eight_per_item_equals(rt, monkeypatch, f, x, origin, f"phase_filter_p4x8 {shape} {origin}")


def test_linear_phase_filter_drops_factors_when_not_channel_pure():
    """A basis that mixes CFA channels cannot take per-channel scales into ``mix``: after an
    affine the filter is dense again (and still equals its definition)."""
    cfa = cfa_from_name("bayer-rggb")
    basis = DemosaicBilinear(cfa).as_phase_filter().weights.copy()
    basis[:, 0, 4] += 0.1                                   # channel 0 reads every centre sample
    f = LinearPhaseFilter(cfa, 1, basis, np.zeros((4, 3)), basis=basis, mix=np.eye(3))
    g = f.after_affine(np.array([1.0, 2.0, 3.0]), np.array([0.5, 1.0, 2.0]))
    assert not g.factored
    kept = DemosaicBilinear(cfa).as_phase_filter().after_affine(np.ones(3), np.array([0.5, 1.0, 2.0]))
    assert kept.factored


def test_linear_phase_filter_reference_definition():
    """reference(): out_c = bias[k, c] + sum_t w[k, c, t] * raw(tap t), k the CFA phase of the
    output pixel, checked pixel by pixel on a small window."""
    cfa = cfa_from_name("lms")
    rng = np.random.default_rng(5)
    weights = rng.normal(size=(16, 3, 25))
    bias = rng.normal(size=(16, 3))
    f = LinearPhaseFilter(cfa, 2, weights, bias)
    x = rng.normal(size=(9, 11))
    origin = (-3, 2)
    out = f.reference(x, origin)
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            y, xx = i + 2, j + 2                           # input coordinates of the output pixel
            k = ((y + origin[0]) % 4) * 4 + (xx + origin[1]) % 4
            window = x[y - 2:y + 3, xx - 2:xx + 3].ravel()
            np.testing.assert_allclose(out[i, j], bias[k] + weights[k] @ window, rtol=1e-12, atol=1e-12)


# ------------------------------------------------------------------------------------------
# colour steps (kernels colour.cl)
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("stage", [ColourMatrix(P_LMS), ColourMatrix(B_BAYER),
                                   ColourMatrix(np.random.default_rng(9).normal(size=(3, 3))),
                                   WhiteBalance2(np.array([1.0, 1.0101, 1.0753])), ToneCurve()],
                         ids=["P", "B", "random", "wb2", "tone"])
def test_colour_kernels(rt, stage):
    x = random_rgb(seed=60)
    for origin in ORIGINS:
        ref = stage.reference(x, origin)
        assert_close(run_stage(rt, stage, x, origin), ref, f"{stage.name} {origin}")


def test_srgb_polynomial_within_three_hundredths_of_a_code(rt):
    """clisp/modules/colour/srgb.h's polynomial sRGB curve against the exact transfer function, on every 7th
    float in [2^-9, 1] (4.5 M values: every exponent, many mantissas) and on the linear segment
    below: within 0.03 of a 16-bit code (measured worst 0.019 over every float)."""
    bits = np.arange(np.float32(2.0 ** -9).view(np.uint32), np.float32(1.0).view(np.uint32) + 1, 7,
                     dtype=np.uint32)
    x = np.concatenate([bits.view(np.float32), np.linspace(-0.5, 0.0031308, 1001, dtype=np.float32),
                        np.array([1.0, 1.5, 7.0], dtype=np.float32)])
    x = np.resize(x, (3, 1000, -(-x.size // 3000))).astype(np.float32)       # 3 planes
    exact = ToneCurve().reference(np.moveaxis(x, 0, -1), (0, 0))
    got = run_stage(rt, ToneCurve(), np.moveaxis(x, 0, -1), (0, 0))
    assert np.abs(got - exact).max() * 65535 <= 0.03


@pytest.mark.parametrize("bits, dtype, seed", [(16, np.uint16, 62), (8, np.uint8, 63)])
def test_tone_curve_to_codes(rt, bits, dtype, seed):
    """ToneCurve(quantize=True): the nearest 16-bit code (TIFF, PNG) or 8-bit code (JPEG) of the
    encoded value, interleaved or not; the OpenCL codes equal the reference's except where the
    encoded value lies within the curve's error (0.02 of a 16-bit code) of a half code: there they
    are one code off."""
    x = random_rgb(seed=seed)
    stage = ToneCurve(quantize=True, bits=bits)
    ref = stage.reference(x, (0, 0))
    assert ref.dtype == dtype and ref.max() == np.iinfo(dtype).max and ref.min() == 0
    for interleaved in (False, True):
        s = stage.with_interleaved_output() if interleaved else stage
        src = to_device(rt, x)
        dst = s.enqueue(rt, src, (0, 0))
        assert dst.dtype == dtype and dst.interleaved == interleaved
        got = from_device(rt, dst)
        rt.release(src)
        rt.release(dst)
        diff = np.abs(got.astype(np.int32) - ref)
        assert diff.max() <= 1 and np.mean(diff > 0) < (0.05 if bits == 16 else 0.001)


@pytest.mark.parametrize("quantize, bits", [(False, 16), (True, 16), (True, 8)])
def test_tone_curve_eight_per_item_equals_the_scalar_kernel(rt, quantize, bits):
    """srgb_encode8 (eight pixels per work-item, the interleaved output on CPU devices) gives
    exactly srgb_encode's values: every exponent of [2^-9, 1], the linear segment, values past 1
    and below 0, on rows whose width is not a multiple of 8 (the last work-item overlaps)."""
    from clisp.modules.colour import stage as colour_stage
    if not colour_stage.eight_per_item(rt):
        pytest.skip("srgb_encode8 runs on CPU devices only")
    patterns = np.arange(np.float32(2.0 ** -9).view(np.uint32), np.float32(1.0).view(np.uint32) + 1, 97,
                     dtype=np.uint32)
    x = np.concatenate([patterns.view(np.float32), np.linspace(-0.5, 0.0031308, 1001, dtype=np.float32),
                        np.array([0.0, 1.0, 1.5, 7.0, -0.0, 2.0 ** -9], dtype=np.float32)])
    x = np.resize(x, (3, 301, 203)).astype(np.float32)
    src = rt.upload(x)
    planar = ToneCurve(quantize=quantize, bits=bits).enqueue(rt, src, (0, 0))
    eight = ToneCurve(quantize=quantize, interleaved=True, bits=bits).enqueue(rt, src, (0, 0))
    a, b = rt.download(planar), rt.download(eight)
    for image in (src, planar, eight):
        rt.release(image)
    np.testing.assert_array_equal(b, np.moveaxis(a, 0, -1))


def test_colour_references():
    x = random_rgb(seed=61).astype(np.float64)
    np.testing.assert_allclose(ColourMatrix(P_LMS).reference(x, (0, 0)), x @ P_LMS.T, rtol=1e-13)
    np.testing.assert_allclose(WhiteBalance2(np.array([1.0, 2.0, 0.5])).reference(x, (0, 0)),
                               x * [1.0, 2.0, 0.5], rtol=1e-13)
    tone = ToneCurve().reference(x, (0, 0))
    assert tone.min() >= 0.0 and tone.max() <= 1.0
    np.testing.assert_allclose(tone[x <= 0], 0.0)
    np.testing.assert_allclose(tone[x >= 1], 1.0)
    mid = (x > 0.0031308) & (x < 1)
    np.testing.assert_allclose(tone[mid], 1.055 * x[mid] ** (1 / 2.4) - 0.055, rtol=1e-12)


# ------------------------------------------------------------------------------------------
# full pipelines: fused schedule == unfused == stage-by-stage reference
# ------------------------------------------------------------------------------------------

def make_raw(kind: str, dtype, wb2: bool, seed: int = 70) -> RawImage:
    cfa = cfa_from_name(kind)
    matrix, wb = (P_LMS, WB_LMS) if cfa.kind == "lms" else (B_BAYER, WB_BAYER)
    rng = np.random.default_rng(seed)
    if dtype == np.uint16:
        data = rng.integers(0, 1024, size=SHAPE, dtype=np.uint16)
    else:
        data = (rng.random(SHAPE) * 1100.0 - 30.0).astype(np.float32)
    return RawImage(data=data, cfa=cfa, black_level=BLACK, white_level=WHITE, wb=wb,
                    colour_matrix=matrix, exposure=1.0 / K_EXP,
                    wb2=np.array([1.0, 1.0101, 1.0753]) if wb2 else np.ones(3))


PIPELINE_CASES = [(kind, output, wb2, dtype)
                  for kind in ("lms", "bayer")
                  for output in ("linear", "srgb", "srgb16")
                  for wb2, dtype in ((False, np.uint16), (True, np.float32))]


@pytest.mark.parametrize("kind, output, wb2, dtype", PIPELINE_CASES,
                         ids=[f"{k}-{o}-{'wb2' if w else 'nowb2'}-{d.__name__}" for k, o, w, d in PIPELINE_CASES])
def test_pipeline_fused_equals_unfused_reference(kind, output, wb2, dtype):
    raw = make_raw(kind, dtype, wb2)
    pipeline = build_pipeline(raw, demosaic="bilinear", output=output, denoise=False, bad_pixels="off",
                              highlights="off")   # random raws reach past white: the fused linear chain alone
    names = [s.name for s in pipeline.stages]
    expected = ["normalize", "white_balance1", "demosaic_bilinear", "colour_matrix"]
    expected += ["white_balance2"] if wb2 else []
    expected += ["tone_curve"] if output != "linear" else []
    assert names == expected

    fused = pipeline.schedule(fuse=True)
    assert isinstance(fused[0], LinearPhaseFilter)
    if output == "linear" or linear_filter.tone_in_store(raw.cfa.period):  # everything in one kernel
        assert len(fused) == 1 and fused[0].interleaved
        assert fused[0].encode == (output != "linear") and fused[0].quantize == (output == "srgb16")
    else:                                                        # the tone curve as its own kernel
        assert len(fused) == 2 and not fused[0].encode and isinstance(fused[1], ToneCurve)
        assert fused[1].interleaved and fused[1].quantize == (output == "srgb16")
    assert [s.name for s in pipeline.schedule(fuse=False)] == names

    # fusion algebra in float64: the fused stages' references == the stages one after another
    x = raw.data
    for origin in ORIGINS:
        results = []
        for stages in (pipeline.stages, fuse_stages(pipeline.stages)):
            chained, o = x, origin
            for stage in stages:
                chained = stage.reference(chained, o)
                o = (o[0] + stage.halo, o[1] + stage.halo)
            results.append(chained)
        np.testing.assert_allclose(results[1], results[0], rtol=1e-9, atol=1e-9)

    ref = pipeline.run(raw.data, backend="reference")
    assert ref.shape == SHAPE + (3,) and ref.dtype == (np.uint16 if output == "srgb16" else np.float32)
    for fuse in (True, False):
        got = pipeline.run(raw.data, backend="opencl", fuse=fuse)
        if output == "srgb16":      # 16-bit codes: one code off where the curve's error meets a half code
            diff = np.abs(got.astype(np.int32) - ref)
            assert diff.max() <= 1 and np.mean(diff > 0) < 0.05, f"fuse={fuse}"
        else:
            assert_close(got, ref, f"fuse={fuse}")
