"""The RI demosaic (clisp.modules.demosaic_ri): its float64 reference against the residual-interpolation
study code it condenses (clisp.modules.demosaic_ari.reference), the device kernels against the reference,
the tiling contract and the presets.

Tolerance (float32 device, float64 reference on the float32 input; output in the mosaic's units):
    max |opencl - reference| <= TOL_MAX, mean <= TOL_MEAN.
MEASURED (PoCL CPU, test_matches_reference): 2e-6..1.6e-5 max; the worst on sharp edges beside flat
patches, where the 1 / max(RMSE, 1e-3) weights of nearly exact fits amplify float32 rounding. The
bounds leave ~10x room; a broken kernel fails them by orders of magnitude (tried: the residual's 0.5
-> 0.49 in ri_green_residual gives 3e-3, one Laplacian tap 4 -> 4.01 in ri_chroma_laplacians 2e-3).
"""
from __future__ import annotations

import re

import numpy as np
import pytest
from scipy import ndimage

from clisp.cfa import BAYER_PHASES, bayer_cfa
from clisp.engine.runtime import kernel_path
from clisp.errors import ClispError
from clisp.modules.colour.stage import ColourMatrix
from clisp.modules.demosaic_ari import reference as ari
from clisp.modules.demosaic_ri.reference import HALO, STEP_RADII, demosaic
from clisp.modules.demosaic_ri.stage import DemosaicRI, chroma_fit_defines, program_defines
from clisp.pipeline import DEMOSAICS, PRESETS, resolve_options
from clisp.sim.colorimetry import B_BAYER
from clisp.sim.noise import ChannelNoise
from bayer_scenes import assert_memory_within_declared, assert_tiled_equals_whole, mosaic, scene

TOL_MAX = 2e-4
TOL_MEAN = 2e-6
OUT = 40
"""Output side of the device comparisons (the window is OUT + 2 HALO)."""


def run_device(rt, stage: DemosaicRI, mos: np.ndarray, origin=(0, 0)) -> np.ndarray:
    src = rt.upload(np.ascontiguousarray(mos))
    out = stage.enqueue(rt, src, origin)
    result = rt.download(out)
    rt.release(out)
    rt.release(src)
    return result if out.interleaved else np.moveaxis(result, 0, -1)


# ------------------------------------------------------------------------------------ the reference

def study_version(m: np.ndarray, phase: str, monkeypatch) -> np.ndarray:
    """The same algorithm through the study's mirrored-border functions: ARI's step 1 with the RI
    kind only, one iteration, window 7 x 1 along the line; the GBTF merge; weighted MLRI chroma on
    5 x 5 windows (docs/RESULTS.md, issue 27's study), with the published constants (RI keeps EPS and
    RMSE_FLOOR; ARI's own ARI_EPS, ARI_RMSE_FLOOR and CRIT_FLOOR came later, for clipped lights)."""
    monkeypatch.setitem(ari.KINDS, "ri", (3, 0))
    monkeypatch.setattr(ari, "ARI_EPS", ari.EPS)
    monkeypatch.setattr(ari, "CRIT_FLOOR", 0.0)
    monkeypatch.setattr(ari, "ARI_RMSE_FLOOR", ari.RMSE_FLOOR)

    def core(raw, sites, lo, hi):
        lines = ari._ari_green(raw, sites, 1, ("ri",))
        green = np.where(sites.g, raw, ari._merge_green(raw, sites, lines, "gbtf"))

        def gf(guide, target, mask):
            return ari.guided_filter(guide, target, mask, ("box", 2, 2), eps=0.0, laplacian=ari.LAPLACIAN_2D,
                                     lap_mask=mask, weighted=True, lap_floor=ari.MLRI_FLOOR)
        red, blue = ari._rb_by_ri(raw, sites, green, lo, hi, gf)
        return red, green, blue
    return ari._run(m, phase, None, core)


@pytest.mark.parametrize("phase", BAYER_PHASES)
def test_reference_is_the_study_algorithm(phase, monkeypatch):
    """The valid-only reference equals the study's construction (mirrored borders) on the interior."""
    m = mosaic(scene("discs", 90, 1), phase).astype(np.float64)
    ours = demosaic(m, phase)
    theirs = study_version(m, phase, monkeypatch)[HALO:-HALO, HALO:-HALO]
    np.testing.assert_allclose(ours, theirs, atol=1e-9)


def test_reference_window_origin():
    """A window cut at an odd origin reproduces the whole image's result there (the CFA from the origin)."""
    m = mosaic(scene("edges", 80, 2), "GRBG").astype(np.float64)
    whole = demosaic(m, "GRBG")
    part = demosaic(m[3:, 5:], "GRBG", (3, 5))
    np.testing.assert_allclose(part, whole[3:, 5:], atol=1e-12)


def test_reference_flat_and_samples():
    flat = demosaic(np.full((50, 51), 0.3), "BGGR")
    assert np.allclose(flat, 0.3)
    m = mosaic(scene("discs", 70, 3), "RGGB").astype(np.float64)
    out = demosaic(m, "RGGB")
    ch = bayer_cfa("RGGB").channel_map(70, 70)[HALO:-HALO, HALO:-HALO]
    inner = m[HALO:-HALO, HALO:-HALO]
    for c in range(3):
        np.testing.assert_allclose(out[..., c][ch == c], inner[ch == c], atol=1e-12)


def test_halo_is_the_sum_of_the_steps():
    assert HALO == sum(STEP_RADII.values()) == 19
    assert DemosaicRI(bayer_cfa("RGGB")).output_shape(100, 101) == (62, 63)


# ------------------------------------------------------------------------------------ the device

@pytest.mark.parametrize("kind", ["ramps", "edges", "discs", "noise"])
@pytest.mark.parametrize("phase, origin", [("RGGB", (0, 0)), ("GRBG", (1, 3)), ("GBRG", (-2, -5)), ("BGGR", (5, 2))])
def test_matches_reference(rt, kind, phase, origin):
    stage = DemosaicRI(bayer_cfa(phase))
    size = OUT + 2 * HALO
    mos = mosaic(scene(kind, size, BAYER_PHASES.index(phase)), phase, origin)
    ref = stage.reference(mos.astype(np.float64), origin)
    out = run_device(rt, stage, mos, origin)
    assert out.shape == ref.shape
    err = np.abs(out - ref)
    assert err.max() <= TOL_MAX and err.mean() <= TOL_MEAN, f"max {err.max():.3g}, mean {err.mean():.3g}"


def test_noise_regularisation(rt):
    """With the raw's noise the chroma slope is regularised (reference.CHROMA_NOISE_K): the kernel
    follows the reference, and the result differs from the noiseless stage's (the term is used)."""
    noise = ChannelNoise(shot=(2e-3, 1e-3, 3e-3), floor=(1e-5, 2e-5, 1e-5))
    stage = DemosaicRI(bayer_cfa("GRBG"), noise)
    mos = mosaic(scene("discs", OUT + 2 * HALO, 6), "GRBG", (1, 1))
    ref = stage.reference(mos.astype(np.float64), (1, 1))
    out = run_device(rt, stage, mos, (1, 1))
    err = np.abs(out - ref)
    assert err.max() <= TOL_MAX and err.mean() <= TOL_MEAN, f"max {err.max():.3g}, mean {err.mean():.3g}"
    plain = DemosaicRI(bayer_cfa("GRBG")).reference(mos.astype(np.float64), (1, 1))
    assert np.abs(plain - ref).max() > 1e-3
    np.testing.assert_array_equal(plain[..., 1], ref[..., 1])        # G does not use it


@pytest.mark.parametrize("out_h, out_w", [(17, 22), (1, 1), (2, 5), (66, 3)])
def test_odd_shapes_and_uint16_input(rt, out_h, out_w):
    """Odd and tiny window sides (ri_chroma_fit's four pixel classes, R's and B's of one offset in
    one launch with work-groups that fit the smaller, cover every pixel) and a uint16 mosaic as the
    first stage (RAW_T ushort)."""
    stage = DemosaicRI(bayer_cfa("GBRG"))
    rng = np.random.default_rng(4)
    mos16 = (ndimage.gaussian_filter(rng.random((2 * HALO + out_h, 2 * HALO + out_w)), 1.5) * 60000).astype(np.uint16)
    ref = stage.reference(mos16.astype(np.float64), (1, 0))
    src = rt.upload(mos16)
    out = stage.enqueue(rt, src, (1, 0))
    got = np.moveaxis(rt.download(out), 0, -1)
    rt.release(out)
    rt.release(src)
    assert got.shape == ref.shape == (out_h, out_w, 3)
    assert np.abs(got - ref).max() <= TOL_MAX * 60000


def test_colour_matrix_fusion_and_interleaved(rt):
    cfa = bayer_cfa("RGGB")
    stage = DemosaicRI(cfa)
    fused = stage.fuse(ColourMatrix(B_BAYER))
    assert isinstance(fused, DemosaicRI) and stage.matrix is None
    mos = mosaic(scene("ramps", OUT + 2 * HALO, 2), "RGGB")
    expected = np.einsum("ij,hwj->hwi", B_BAYER, stage.reference(mos.astype(np.float64), (0, 0)))
    for candidate in (fused, fused.with_interleaved_output()):
        out = run_device(rt, candidate, mos)
        assert np.abs(out - expected).max() <= TOL_MAX * 4


def test_defines_come_from_the_host(rt):
    """The two kernel files hold no fallback of a host define: a program built without them fails;
    the host gives each exactly the ones its file checks."""
    for program, kernel, defines in (("demosaic_ri", "ri_green_fit", program_defines(np.dtype(np.float32), False)),
                                     ("demosaic_ri_chroma_fit", "ri_chroma_fit",
                                      chroma_fit_defines(np.dtype(np.float32), 1, 0))):
        with pytest.raises(ClispError, match="build"):
            rt.kernel(program, kernel, {})
        checked = set(re.findall(r"!defined\((\w+)\)", kernel_path(f"{program}.cl").read_text()))
        assert checked == set(defines), program


def test_device_memory_within_declared(rt):
    """bytes_per_pixel covers what one enqueue creates from an empty pool."""
    assert_memory_within_declared(rt, DemosaicRI(bayer_cfa("RGGB")), ((120, 120), (300, 1500)))


def test_tiled_equals_whole():
    assert_tiled_equals_whole(DemosaicRI, (150, 171))


# ------------------------------------------------------------------------------------ presets

def test_presets():
    assert DEMOSAICS["ri"] is DemosaicRI
    assert resolve_options("quality", None, "bayer")["demosaic"] == "ri"
    assert resolve_options(None, None, "bayer")["demosaic"] == "ri"          # quality is the default
    assert resolve_options("best", None, "bayer")["demosaic"] == "ari"
    assert resolve_options("best", None, "lms")["demosaic"] == PRESETS["quality"]["demosaic"]["lms"]
    with pytest.raises(ClispError, match="works on bayer"):
        resolve_options(None, "ri", "lms")
    with pytest.raises(ClispError, match="Bayer CFA"):
        from clisp.cfa import lms_cfa
        DemosaicRI(lms_cfa())
