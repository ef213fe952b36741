"""The ARI demosaic on the device (clisp.modules.demosaic_ari.stage, clisp/modules/demosaic_ari/demosaic_ari.cl) against its float64 NumPy
reference clisp.modules.demosaic_ari.reference.demosaic_ari (clip=None), and the tiling contract.

The device stage is valid-only: an H x W window gives its (H - 2 halo)^2 interior, and the halo is the
formal support of the chain, so the reference run on the same window (mirrored borders) and cropped by
the halo is compared on every output pixel (a halo too small would show as differences at the border
of the output; the enqueue also checks that its chain ends exactly at the declared halo).

Tolerance (float32 device, float64 reference on the float32 input; output in the mosaic's units, ~[0, 1]):
    max |opencl - reference| <= TOL_MAX, mean <= TOL_MEAN, PSNR(opencl vs reference) >= PSNR_FLOOR dB.
MEASURED (PoCL CPU, the 16 scene x phase cases of test_matches_reference, OUT = 24): smooth ramps and
white noise 5e-7..4e-6 max (float32 rounding); sharp colour edges and random discs up to 2.1e-4 max
(0.05 8-bit levels; 99.9th percentile <= 6.4e-5, mean <= 1.9e-6, PSNR >= 104 dB): ARI's weights
1 / max(RMSE, 1e-3) of nearly exact fits (flat patches beside an edge) and its per-pixel argmin of the
criterion amplify float32 rounding where two iterations' criteria nearly tie. The bounds leave ~5x
room over the worst case; a broken kernel fails them by orders of magnitude (tried: ari_green_residual's
residual weight 0.5 -> 0.49 gives PSNR 47-74 dB, one MLRI Laplacian tap 2 -> 2.01 gives 54-61 dB).
"""
from __future__ import annotations

import re

import numpy as np
import pytest

from clisp.cfa import BAYER_PHASES, bayer_cfa
from clisp.errors import ClispError
from clisp.engine.runtime import kernel_path
from clisp.pipeline import DEMOSAICS, PRESETS
from clisp.modules.demosaic_ari.stage import MODES, DemosaicARI, ari_halo, program_defines
from bayer_scenes import assert_memory_within_declared, assert_tiled_equals_whole, mosaic, scene

TOL_MAX = 1e-3
TOL_MEAN = 1e-5
PSNR_FLOOR = 95.0
MEASURED = {"ramps": (4.3e-6, 9.0e-8, 135.6), "edges": (2.1e-4, 1.9e-6, 104.0), "discs": (7.3e-5, 7.2e-7, 110.0),
            "noise": (4.7e-6, 8.4e-8, 132.9)}
"""Worst max |error|, mean |error| and lowest PSNR (dB, peak 1) per scene over the four phases."""
OUT = 24
"""Output side of the comparisons (the window is OUT + 2 halo)."""


def run_device(rt, stage: DemosaicARI, mos: np.ndarray, origin=(0, 0)) -> np.ndarray:
    out = stage.enqueue(rt, rt.upload(np.ascontiguousarray(mos, dtype=np.float32)), origin)
    result = np.moveaxis(rt.download(out), 0, -1)
    rt.release(out)
    return result


def compare(rt, stage, mos, origin=(0, 0)) -> tuple[float, float]:
    """(max, mean) |device - reference|; asserts shapes, finiteness and the PSNR floor."""
    ref = stage.reference(mos.astype(np.float64), origin)
    out = run_device(rt, stage, mos, origin)
    assert out.shape == ref.shape
    assert np.all(np.isfinite(out))
    err = np.abs(out.astype(np.float64) - ref)
    psnr = 10 * np.log10(1.0 / max(np.mean(err ** 2), 1e-30))
    assert psnr >= PSNR_FLOOR, f"PSNR vs reference {psnr:.1f} dB"
    return float(err.max()), float(err.mean())


# ------------------------------------------------------------------------------------ halo

def test_halo_formula():
    """The halo is the chain's formal support; closed forms of the module doc."""
    for n in (1, 2, 5, 11):
        for m in (1, 2, 3):
            assert ari_halo(n, m) == (3 + n * (n + 10)) + (2 * m * m + 7 * m + 2) + (m * m + 6 * m + 3)
    assert DemosaicARI(bayer_cfa("RGGB")).halo == 121
    assert DemosaicARI(bayer_cfa("RGGB")).output_shape(300, 301) == (58, 59)


def test_options_and_registration():
    assert DEMOSAICS["ari"] is DemosaicARI
    assert [name for name, p in PRESETS.items() if "ari" in p["demosaic"].values()] == ["best"]  # best's alone
    with pytest.raises(ClispError):
        DemosaicARI(bayer_cfa("RGGB"), green_iterations=0)


def test_defines_come_from_the_host(rt):
    """demosaic_ari.cl holds no fallback of a host define: a program built without them fails, and the
    host refuses a kernel's modes given incompletely or with others; its table covers every kernel."""
    with pytest.raises(ClispError, match="build"):
        rt.kernel("demosaic_ari", "ari_scale", {})
    with pytest.raises(ClispError, match="ari_box_apply"):
        program_defines("ari_box_apply", {"ARI_DIR": 0, "ARI_R": 2})
    with pytest.raises(ClispError, match="ari_scale"):
        program_defines("ari_scale", {"ARI_R": 2})
    kernels = re.findall(r"__kernel void (\w+)", kernel_path("demosaic_ari.cl").read_text())
    assert sorted(MODES) == sorted(kernels)                  # the host's table names every kernel once


# ------------------------------------------------------------------------------------ vs reference

@pytest.mark.parametrize("kind, phase", list(zip(["ramps", "edges", "discs", "noise"], BAYER_PHASES)))
def test_matches_reference(rt, phase, kind):
    """Every scene kind and every CFA phase once (each pair costs a NumPy ARI reference of ~5 s; all
    16 pairs took CI a minute more and found nothing the diagonal does not)."""
    stage = DemosaicARI(bayer_cfa(phase))
    size = OUT + 2 * stage.halo
    seed = BAYER_PHASES.index(phase)
    emax, emean = compare(rt, stage, mosaic(scene(kind, size, seed), phase))
    assert emax <= TOL_MAX and emean <= TOL_MEAN, f"{kind} {phase}: max {emax:.3g}, mean {emean:.3g}"


@pytest.mark.parametrize("iterations", [(1, 1), (3, 2)])
def test_other_iteration_counts(rt, iterations):
    """Other (green, chroma) iteration counts, with a window origin off the CFA period (the stage
    reads the phase from the origin)."""
    stage = DemosaicARI(bayer_cfa("GRBG"), *iterations)
    size = OUT + 2 * stage.halo
    origin = (-3, 5)
    emax, emean = compare(rt, stage, mosaic(scene("discs", size, 7), "GRBG", origin), origin)
    assert emax <= TOL_MAX and emean <= TOL_MEAN, f"{iterations}: max {emax:.3g}, mean {emean:.3g}"


@pytest.mark.parametrize("iterations, phase", [((1, 1), "RGGB"), ((2, 1), "GBRG")])
def test_clipped_lights_match_reference(rt, iterations, phase):
    """Lights clipped flat at each channel's white (a white-balanced raw): the fits of a flat guide
    are well-conditioned (ARI_EPS), fits better than a level weigh alike (ARI_RMSE_FLOOR) and criteria
    of rounding size tie (CRIT_FLOOR), so the device follows the reference beside the clipped patches
    too. With the published constants it differed by 0.02-0.04 there (max; mean 1-2e-4); now 1-2e-5."""
    stage = DemosaicARI(bayer_cfa(phase), *iterations)
    size = 32 + 2 * stage.halo
    emax, emean = compare(rt, stage, mosaic(scene("clipped", size, 1), phase))
    assert emax <= TOL_MAX and emean <= TOL_MEAN, f"{iterations} {phase}: max {emax:.3g}, mean {emean:.3g}"


def test_keeps_samples_and_flat(rt):
    """Measured samples pass through (scaled by 255 and back: float32 rounding), a flat mosaic stays flat."""
    stage = DemosaicARI(bayer_cfa("BGGR"), 1, 1)
    size = 8 + 2 * stage.halo
    flat = np.full((size, size), 0.37, dtype=np.float32)
    assert np.allclose(run_device(rt, stage, flat), 0.37, atol=1e-6)
    mos = mosaic(scene("discs", size, 3), "BGGR")
    out = run_device(rt, stage, mos)
    h = stage.halo
    ch = bayer_cfa("BGGR").channel_map(size, size)[h:-h, h:-h]
    inner = mos[h:-h, h:-h]
    for c in range(3):
        np.testing.assert_allclose(out[..., c][ch == c], inner[ch == c], atol=1e-6)


def test_device_memory_within_declared(rt):
    """bytes_per_pixel covers what one enqueue creates from an empty pool."""
    assert_memory_within_declared(rt, DemosaicARI(bayer_cfa("RGGB")), ((300, 300), (442, 1800), (1000, 1000)))


# ------------------------------------------------------------------------------------ tiling

def test_tiled_equals_whole():
    assert_tiled_equals_whole(lambda cfa: DemosaicARI(cfa, 2, 1), (150, 170))
