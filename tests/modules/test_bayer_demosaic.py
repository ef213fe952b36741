"""The Bayer baseline demosaics: Malvar-He-Cutler 2004 and DLMMSE (Zhang & Wu 2005, as Getreuer documents it).

Tolerance, used by every OpenCL-vs-reference comparison in this file (float32 kernels against
float64 references, inputs in [0, 1]-ish):

    |opencl - reference| <= TOL * max(1, |reference|)

It is not relaxed for DLMMSE: its divisions (the LMMSE gain and the fusion weights) are well
conditioned because both variances carry EPSILON, and the kernel sums the signal variance about the
window mean, so float32 cancellation stays far below TOL (measured worst case 2e-6 on log-normal
"HDR" mosaics, 1.5e-7 on noise in [0, 1]).
"""
from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from clisp.cfa import BAYER_PHASES, bayer_cfa, lms_cfa
from clisp.sim.colorimetry import B_BAYER, WB_BAYER
from clisp.errors import ClispError
from clisp.pipeline import Pipeline
from clisp.engine.runtime import DeviceImage
from clisp.modules.colour.stage import ColourMatrix
from clisp.modules.demosaic_dlmmse.stage import EPSILON, DemosaicDLMMSE
from clisp.modules.demosaic_malvar.stage import DemosaicMalvar
from clisp.modules.raw_scale.stage import normalize, white_balance1
from tolerance import TOL, assert_close

"""|opencl - reference| <= TOL * max(1, |reference|), everywhere in this file."""

ORIGINS = [(0, 0), (1, 3), (-2, -5), (5, -2)]
SHAPE = (47, 61)                      # odd on purpose
R, G, B = 0, 1, 2

# DLMMSE's constants (Getreuer, IPOL 2011), written out here (not imported from the stage).
SPEC_INTERPOLATION = np.array([-0.25, 0.5, 0.5, 0.5, -0.25])
SPEC_SMOOTHING = np.array([4, 9, 15, 23, 26, 23, 15, 9, 4]) / 128.0
SPEC_M = 4
SPEC_EPSILON = 0.1 / 255 ** 2






def run_stage(rt, stage, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
    """stage.enqueue on the H x W mosaic ``x``; returns H' x W' x 3 whatever the device layout."""
    src = rt.upload(x)
    dst: DeviceImage = stage.enqueue(rt, src, origin)
    out = rt.download(dst)
    rt.release(src)
    rt.release(dst)
    if not dst.interleaved:
        out = np.moveaxis(out, 0, -1)
    assert out.shape == stage.output_shape(*x.shape) + (3,)
    return out


def sample_mosaic(seed: int, shape=SHAPE) -> np.ndarray:
    """A white-balanced mosaic in about [-0.05, 1.2] float32: smooth structure, edges and noise."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:shape[0], :shape[1]]
    smooth = ndimage.gaussian_filter(rng.random(shape), 2.0) * 2.0 - 0.3
    edges = 0.4 * (xx + 0.6 * yy > shape[1] / 2) + 0.2 * (np.sin(xx * 1.3) > 0)
    return (smooth + edges + 0.05 * rng.standard_normal(shape)).astype(np.float32)


def site_masks(cfa, shape, origin):
    channel = cfa.channel_map(shape[0], shape[1], origin)
    return [channel == c for c in range(3)]


# ------------------------------------------------------------------------------------------
# construction
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("stage_class", [DemosaicMalvar, DemosaicDLMMSE])
def test_non_bayer_cfa_rejected(stage_class):
    with pytest.raises(ClispError, match="Bayer"):
        stage_class(lms_cfa())


def test_dlmmse_options():
    cfa = bayer_cfa("RGGB")
    assert DemosaicDLMMSE(cfa).local_mean == "centre"           # mu = centre value by default
    assert DemosaicDLMMSE(cfa, local_mean="window").local_mean == "window"
    with pytest.raises(ClispError, match="local_mean"):
        DemosaicDLMMSE(cfa, local_mean="median")


def test_halos():
    cfa = bayer_cfa("GRBG")
    assert DemosaicMalvar(cfa).halo == 2                         # 5 x 5 kernels
    assert DemosaicDLMMSE(cfa).halo == 2 + 4 + 4 + 2             # HA, smoothing, LMMSE window, R/B fill
    assert DemosaicDLMMSE(cfa).output_shape(40, 51) == (16, 27)


# ------------------------------------------------------------------------------------------
# Malvar-He-Cutler
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("phase", BAYER_PHASES)
def test_malvar_reference_equals_phase_filter(phase):
    """Two derivations of one operator: published kernels on masks vs per-phase weights."""
    stage = DemosaicMalvar(bayer_cfa(phase))
    x = sample_mosaic(1).astype(np.float64)
    for origin in ORIGINS:
        np.testing.assert_allclose(stage.as_phase_filter().reference(x, origin), stage.reference(x, origin),
                                   rtol=0, atol=1e-12, err_msg=f"{phase} {origin}")


def test_malvar_published_example():
    """An exact case from the paper's kernels: a unit impulse at an R site (RGGB, (2, 2)) of a
    zero mosaic. G at that site is 4/8; R at the G site (2, 3) of its row is 4/8 (same-row kernel,
    tap (0, -1)); R at the B site (3, 3) is 2/8 (R-at-B kernel, diagonal tap); G at the G site
    (2, 3) is 0 (measured); G at the B site (3, 3), a diagonal neighbour, is 0."""
    x = np.zeros((9, 9))
    x[4, 4] = 1.0                                                # (2, 2) of the 5 x 5 output
    out = DemosaicMalvar(bayer_cfa("RGGB")).reference(x, (-2, -2))
    assert out[2, 2, G] == pytest.approx(4 / 8)
    assert out[2, 3, R] == pytest.approx(4 / 8)
    assert out[3, 3, R] == pytest.approx(2 / 8)
    assert out[2, 3, G] == 0.0 and out[3, 3, G] == 0.0
    assert out[2, 2, R] == 1.0                                   # measured sample kept


def test_malvar_matches_colour_demosaicing():
    """Independent implementation (tools-only dependency): colour-demosaicing's Malvar2004."""
    cd = pytest.importorskip("colour_demosaicing")
    x = sample_mosaic(2).astype(np.float64)
    for phase in BAYER_PHASES:
        theirs = cd.demosaicing_CFA_Bayer_Malvar2004(x, phase)[2:-2, 2:-2]
        np.testing.assert_allclose(DemosaicMalvar(bayer_cfa(phase)).reference(x, (0, 0)), theirs,
                                   rtol=0, atol=1e-12, err_msg=phase)


@pytest.mark.parametrize("phase", BAYER_PHASES)
def test_malvar_kernel(rt, phase):
    stage = DemosaicMalvar(bayer_cfa(phase))
    x = sample_mosaic(3)
    for origin in ORIGINS:
        assert_close(run_stage(rt, stage, x, origin), stage.reference(x, origin), f"malvar {phase} {origin}")


# ------------------------------------------------------------------------------------------
# DLMMSE
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("local_mean", ["centre", "window"])
@pytest.mark.parametrize("phase", BAYER_PHASES)
def test_dlmmse_kernel(rt, phase, local_mean):
    stage = DemosaicDLMMSE(bayer_cfa(phase), local_mean=local_mean)
    x = sample_mosaic(4 + BAYER_PHASES.index(phase))
    for origin in ORIGINS:
        assert_close(run_stage(rt, stage, x, origin), stage.reference(x, origin),
                     f"dlmmse {phase} {local_mean} {origin}")


def test_dlmmse_kernel_uint16_input(rt):
    """As the first stage the kernels read raw DN (ushort) directly."""
    stage = DemosaicDLMMSE(bayer_cfa("GBRG"))
    x = np.random.default_rng(9).integers(0, 1024, size=(41, 39), dtype=np.uint16)
    ref = stage.reference(x, (-3, 2))
    out = run_stage(rt, stage, x, (-3, 2))
    assert_close(out / 1023.0, ref / 1023.0, "uint16 input, compared in white-normalised units")


def spec_difference(line: np.ndarray, green: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """DLMMSE steps 1-3 (interpolation, differences, smoothing) along one full row or column: (d, s),
    valid 6 samples in from the ends."""
    f = np.convolve(line, SPEC_INTERPOLATION[::-1], mode="same")
    d = np.where(green, line - f, f - line)
    return d, np.convolve(d, SPEC_SMOOTHING[::-1], mode="same")


def spec_green_minus_x(x: np.ndarray, green: np.ndarray, y: int, c: int, window_mean: bool) -> float:
    """DLMMSE steps 1-5 at the R/B site (y, c), written from the published formulas with scalar sums."""
    estimates = []
    for line, g, i in ((x[y, :], green[y, :], c), (x[:, c], green[:, c], y)):
        d, s = spec_difference(line, g)
        m = SPEC_M
        win_s, win_d = s[i - m:i + m + 1], d[i - m:i + m + 1]
        mu = win_s.mean() if window_mean else s[i]
        sx2 = np.sum(win_s ** 2) / (2 * m) - np.sum(win_s) ** 2 / (2 * m * (2 * m + 1))
        sv2 = np.mean((win_s - win_d) ** 2) + SPEC_EPSILON
        u = mu + sx2 / (sx2 + sv2) * (d[i] - mu)
        e = sx2 - sx2 ** 2 / (sx2 + sv2) + SPEC_EPSILON
        estimates.append((u, e))
    (u_h, e_h), (u_v, e_v) = estimates
    return (e_v * u_h + e_h * u_v) / (e_h + e_v)


@pytest.mark.parametrize("window_mean", [False, True])
def test_dlmmse_reference_follows_spec(window_mean):
    """The vectorised reference against the formulas written out pixel by pixel: G at R/B sites
    (steps 1-5) and R/B at every kind of site (step 6: diagonal, then axial fill)."""
    cfa = bayer_cfa("GRBG")
    x = sample_mosaic(11, shape=(40, 44)).astype(np.float64)
    channel = cfa.channel_map(*x.shape)
    green = channel == G
    stage = DemosaicDLMMSE(cfa, local_mean="window" if window_mean else "centre")
    out = stage.reference(x, (0, 0))
    halo = stage.halo

    def diff(y: int, c: int, colour: int) -> float:
        """G - colour at an R/B site: measured there, else mean over the 4 diagonals (step 6)."""
        if channel[y, c] == colour:
            return spec_green_minus_x(x, green, y, c, window_mean)
        return np.mean([diff(y + dy, c + dx, colour) for dy in (-1, 1) for dx in (-1, 1)])

    checked = set()
    for y in range(halo, halo + 6):
        for c in range(halo, halo + 6):
            site = channel[y, c]
            g = x[y, c] if site == G else x[y, c] + spec_green_minus_x(x, green, y, c, window_mean)
            expected = [0.0, g, 0.0]
            for colour in (R, B):
                if site == colour:
                    expected[colour] = x[y, c]
                elif site == G:
                    neighbours = [(y - 1, c), (y + 1, c), (y, c - 1), (y, c + 1)]
                    expected[colour] = g - np.mean([diff(ny, nx, colour) for ny, nx in neighbours])
                else:
                    expected[colour] = g - diff(y, c, colour)
            np.testing.assert_allclose(out[y - halo, c - halo], expected, rtol=1e-10, atol=1e-12,
                                       err_msg=f"pixel {(y, c)}, site {'RGB'[site]}")
            checked.add(site)
    assert checked == {R, G, B}


@pytest.mark.parametrize("phase", BAYER_PHASES)
def test_dlmmse_keeps_measured_samples(rt, phase):
    """DLMMSE: G = X + Delta only at R/B sites, so G sites keep G; R = G - (G - R) is R at R sites
    and B likewise: every measured sample comes out as it went in (kernel: bit for bit)."""
    cfa = bayer_cfa(phase)
    stage = DemosaicDLMMSE(cfa)
    x = sample_mosaic(20)
    for origin in ORIGINS[:2]:
        inner = x[stage.halo:-stage.halo, stage.halo:-stage.halo]
        masks = site_masks(cfa, inner.shape, (origin[0] + stage.halo, origin[1] + stage.halo))
        ref, out = stage.reference(x, origin), run_stage(rt, stage, x, origin)
        for c in range(3):
            np.testing.assert_array_equal(ref[..., c][masks[c]], inner[masks[c]].astype(np.float64))
            np.testing.assert_array_equal(out[..., c][masks[c]], inner[masks[c]])


@pytest.mark.parametrize("stage_class", [DemosaicMalvar, DemosaicDLMMSE])
def test_flat_mosaic_stays_flat(rt, stage_class):
    for phase in BAYER_PHASES:
        stage = stage_class(bayer_cfa(phase))
        x = np.full((35, 41), 0.3125, dtype=np.float32)
        expected = np.full(stage.output_shape(*x.shape) + (3,), 0.3125)
        np.testing.assert_allclose(stage.reference(x, (1, 0)), expected, rtol=0, atol=1e-12)
        assert_close(run_stage(rt, stage, x, (1, 0)), expected, f"{stage.name} {phase}")


def test_dlmmse_epsilon_is_spec_value():
    assert EPSILON == pytest.approx(SPEC_EPSILON, rel=1e-15)


def test_dlmmse_colour_matrix_fusion(rt):
    """A following colour matrix runs inside the last kernel: same result as a separate pass."""
    cfa = bayer_cfa("BGGR")
    stage = DemosaicDLMMSE(cfa)
    fused = stage.fuse(ColourMatrix(B_BAYER))
    assert isinstance(fused, DemosaicDLMMSE) and stage.matrix is None
    x = sample_mosaic(30)
    separate = np.einsum("ij,hwj->hwi", B_BAYER, stage.reference(x, (0, 1)))
    np.testing.assert_allclose(fused.reference(x, (0, 1)), separate, rtol=0, atol=1e-12)
    assert_close(run_stage(rt, fused.with_interleaved_output(), x, (0, 1)), separate, "fused, interleaved")


# ------------------------------------------------------------------------------------------
# through the pipeline
# ------------------------------------------------------------------------------------------

def bayer_pipeline(cfa, stage) -> Pipeline:
    return Pipeline(cfa, [normalize(cfa, np.full(3, 64.0), 1023.0), white_balance1(cfa, WB_BAYER),
                          stage, ColourMatrix(B_BAYER)])


@pytest.mark.parametrize("stage_class", [DemosaicMalvar, DemosaicDLMMSE])
@pytest.mark.parametrize("phase", BAYER_PHASES)
def test_tiled_equals_untiled(phase, stage_class):
    cfa = bayer_cfa(phase)
    pipeline = bayer_pipeline(cfa, stage_class(cfa))
    rng = np.random.default_rng(BAYER_PHASES.index(phase))
    scene = ndimage.gaussian_filter(rng.random((301, 517)), 3.0) * 500 + 100
    raw = np.clip(scene + rng.normal(0, 8, scene.shape), 0, 1023).astype(np.uint16)
    whole = pipeline.run(raw)
    assert whole.shape == (301, 517, 3)
    for tile in (64, 256):
        assert_close(pipeline.run(raw, tile=tile), whole, f"{stage_class.__name__} {phase} tile {tile}")
    if phase == "RGGB":                     # and the OpenCL pipeline against the references
        assert_close(whole, pipeline.run(raw, tile=256, backend="reference"), "opencl vs reference")
