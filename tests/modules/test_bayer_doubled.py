"""The Bayer demosaics on a Bayer layout whose doubled channel is not the second (issue 45): L doubled
on the Bayer layout (``ML/LS``, the paper's "double L" step applied there) and its phases, and an RGB
layout with R doubled.

A Bayer demosaic reads such a CFA by roles (clisp.cfa CFA.bayer_roles: the doubled channel as G, the
other two as R and B in channel order) and writes its output in the CFA's channel order. So the
operator on ``ML/LS`` must be exactly the operator on the RGGB Bayer CFA of its roles with the
outputs permuted: that is checked on the references (float64, equal to rounding), then each kernel
against its reference (the files' own tolerances: tests/modules/test_demosaic_ri.py and
test_demosaic_ari_cl.py for RI and ARI, tests/tolerance.py's rule for Malvar and DLMMSE), the
measured samples kept in their own channel's plane, and tiled output against whole.
"""
from __future__ import annotations

import numpy as np
import pytest

from clisp.cfa import bayer_cfa, cfa_from_name
from clisp.engine.runtime import DeviceImage
from clisp.modules.demosaic_ari.stage import DemosaicARI
from clisp.modules.demosaic_dlmmse.stage import DemosaicDLMMSE
from clisp.modules.demosaic_malvar.stage import DemosaicMalvar, channel_order
from clisp.modules.demosaic_ri.stage import DemosaicRI
from clisp.sim.colorimetry import P_LMS
from bayer_scenes import assert_tiled_equals_whole, mosaic, scene
from tolerance import assert_close

DOUBLED = ["ML/LS", "SL/LM", "LS/ML", "RG/BR"]
"""L doubled on the Bayer layout in three of its phases (ML/LS is the issue's), and RGB with R doubled."""
STAGES = {"malvar": DemosaicMalvar, "dlmmse": DemosaicDLMMSE, "ri": DemosaicRI,
          "ari": lambda cfa: DemosaicARI(cfa, 2, 1)}
"""The four Bayer demosaics (ARI with fewer iterations: its NumPy reference costs seconds)."""
OUT = 24
"""Output side of the comparisons (the window is OUT + 2 halo)."""


def role_bayer(cfa):
    """The RGGB-family Bayer CFA of ``cfa``'s roles (the same geometry, R, G, B where its roles are)."""
    return next(bayer_cfa(p) for p in ("RGGB", "GRBG", "GBRG", "BGGR")
                if np.array_equal(bayer_cfa(p).pattern, cfa.role_cfa().pattern))


def run_device(rt, stage, x: np.ndarray, origin) -> np.ndarray:
    src = rt.upload(np.ascontiguousarray(x, dtype=np.float32))
    dst: DeviceImage = stage.enqueue(rt, src, origin)
    out = rt.download(dst)
    rt.release(src)
    rt.release(dst)
    return out if dst.interleaved else np.moveaxis(out, 0, -1)


def test_roles():
    ml = cfa_from_name("ML/LS")
    assert (ml.layout, ml.kind, ml.bayer_roles) == ("bayer", "lms-bayer-double-l", (1, 0, 2))
    assert ml.bayer_phase() == "RGGB" and role_bayer(ml).name == "bayer-rggb"
    np.testing.assert_array_equal(ml.role_matrix() @ [10.0, 20.0, 30.0], [20.0, 10.0, 30.0])   # R=M, G=L, B=S
    for name in ("bayer", "lms-bayer", "bayer-bggr"):
        cfa = cfa_from_name(name)
        assert cfa.bayer_roles == (0, 1, 2) and cfa.role_cfa() is cfa
        np.testing.assert_array_equal(cfa.role_matrix(), np.eye(3))
    assert cfa_from_name("LL/MS").layout == "other"           # doubled on a row: not a Bayer layout


@pytest.mark.parametrize("name", ["malvar", "dlmmse", "ri", "ari"])
@pytest.mark.parametrize("pattern, origin", [("ML/LS", (0, 0)), ("SL/LM", (1, 3)), ("LS/ML", (-2, 5)), ("RG/BR", (3, -1))])
def test_roles_are_the_bayer_operator(name, pattern, origin):
    """The reference on the doubled-channel CFA equals the reference on the Bayer CFA of its roles,
    outputs permuted to the CFA's channel order."""
    cfa = cfa_from_name(pattern)
    stage, bayer = STAGES[name](cfa), STAGES[name](role_bayer(cfa))
    x = mosaic(scene("discs", OUT + 2 * stage.halo, len(pattern) + origin[0]), cfa, origin).astype(np.float64)
    np.testing.assert_allclose(stage.reference(x, origin), channel_order(bayer.reference(x, origin), cfa),
                               rtol=0, atol=1e-12)


@pytest.mark.parametrize("name", ["malvar", "dlmmse", "ri", "ari"])
@pytest.mark.parametrize("pattern, origin", [("ML/LS", (0, 0)), ("SL/LM", (1, 3)), ("RG/BR", (-2, -5))])
def test_kernel_equals_reference(rt, name, pattern, origin):
    """Each kernel against its reference on the new layouts (the reference is the definition of correct),
    with the bounds each demosaic's own test file uses; and every measured sample in its channel's plane."""
    cfa = cfa_from_name(pattern)
    stage = STAGES[name](cfa)
    size = OUT + 2 * stage.halo
    x = mosaic(scene("edges" if name != "ari" else "discs", size, 3), cfa, origin)
    ref = stage.reference(x.astype(np.float64), origin)
    out = run_device(rt, stage, x, origin)
    assert out.shape == ref.shape
    err = np.abs(out - ref)
    if name == "ri":                                        # tests/modules/test_demosaic_ri.py's bounds
        assert err.max() <= 2e-4 and err.mean() <= 2e-6, (err.max(), err.mean())
    elif name == "ari":                                     # tests/modules/test_demosaic_ari_cl.py's bounds
        assert err.max() <= 1e-3 and err.mean() <= 1e-5, (err.max(), err.mean())
    else:
        assert_close(out, ref, f"{name} {pattern}")
    h = stage.halo
    channel = cfa.channel_map(size, size, origin)[h:size - h, h:size - h]
    inner = x[h:size - h, h:size - h]
    for c in range(3):                                      # the sample kept, in its own channel
        np.testing.assert_allclose(out[..., c][channel == c], inner[channel == c], atol=2e-6)


def test_fused_matrix_follows_the_roles(rt):
    """RI and DLMMSE fold a following colour matrix into their last kernel: with the roles' permutation
    in it, the device output is the reference's channel-order output times the matrix."""
    cfa = cfa_from_name("ML/LS")
    for make in (DemosaicRI, DemosaicDLMMSE):
        plain = make(cfa)
        fused = plain.fuse(__import__("clisp.modules.colour.stage", fromlist=["ColourMatrix"]).ColourMatrix(P_LMS))
        size = OUT + 2 * plain.halo
        x = mosaic(scene("ramps", size, 1), cfa, (0, 0))
        want = np.einsum("ij,hwj->hwi", P_LMS, plain.reference(x.astype(np.float64), (0, 0)))
        assert_close(run_device(rt, fused, x, (0, 0)), want, make.__name__)


@pytest.mark.parametrize("name", ["malvar", "dlmmse", "ri", "ari"])
def test_tiled_equals_whole(name):
    assert_tiled_equals_whole(STAGES[name], (150, 170), cfa_from_name("ML/LS"))
