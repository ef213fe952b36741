"""A CFA as data (issue 32, item 1): every CFA kind through simulate, our DNG and process.

Kinds: the paper's LMS (4x4), Bayer RGB, L, M, S on the Bayer layout (lms-bayer), L doubled on the
Bayer layout ('ML/LS', issue 45: the Bayer demosaics read it by roles) and a pattern that is neither
layout ('LL/MS', L twice on a row: served by the any-CFA bilinear demosaic). Each is simulated from a scene
made in code, written and read back, and processed with the fast and the default preset; the PSNR
floors sit a few dB under what the pipeline measured when the test was written (docs/RESULTS.md has
the measured figures), so they catch a broken stage, not a small regression.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import clisp
from clisp.cfa import CFA, bayer_cfa, cfa_from_name, layout_of, lms_bayer_cfa, lms_cfa
from clisp.app.cli import main
from clisp.errors import ClispError
from clisp.io.imageio import read_image, write_image
from clisp.io.rawfile import read_raw, write_raw
from clisp.metrics import psnr
from clisp.pipeline import build_pipeline
from clisp.sim.colorimetry import P_LMS, WB_LMS
from clisp.sim.simulate import simulate

# (name, kind, spectral, layout, fast floor dB, default floor dB) at gain 1 on scene() below.
KINDS = [
    ("lms", "lms", "lms", "lms", 27.0, 36.0),
    ("bayer", "bayer", "rgb", "bayer", 33.0, 39.0),
    ("lms-bayer", "lms-bayer", "lms", "bayer", 27.0, 35.0),
    ("ML/LS", "lms-bayer-double-l", "lms", "bayer", 25.0, 36.0),
    ("LL/MS", "lms-other", "lms", "other", 25.0, 27.0),
]


def scene(height: int = 64, width: int = 96) -> np.ndarray:
    """Linear sRGB: smooth colour ramps, a saturated square and a grey bar (sharp edges)."""
    y, x = np.mgrid[0:height, 0:width] / max(height, width)
    out = np.stack([0.15 + 0.6 * x, 0.25 + 0.4 * np.sin(5 * y) ** 2, 0.15 + 0.5 * x * y], axis=-1)
    out[height // 4:height // 2, width // 4:width // 2] = (0.6, 0.15, 0.08)
    out[3 * height // 4:, :] = 0.4
    return out


def test_spectral_and_layout() -> None:
    """The two properties every stage reads, for the named CFAs, their phases and pattern strings."""
    for cfa in [lms_cfa((dy, dx)) for dy in range(4) for dx in range(4)]:
        assert (cfa.kind, cfa.spectral, cfa.layout) == ("lms", "lms", "lms")
    for phase in ("RGGB", "GRBG", "GBRG", "BGGR"):
        assert (bayer_cfa(phase).spectral, bayer_cfa(phase).layout) == ("rgb", "bayer")
        cfa = lms_bayer_cfa(phase)
        assert (cfa.kind, cfa.spectral, cfa.layout, cfa.channels) == ("lms-bayer", "lms", "bayer", ("L", "M", "S"))
        # L where R was, M where G was, S where B was
        np.testing.assert_array_equal(cfa.pattern, bayer_cfa(phase).pattern)
        assert cfa.bayer_phase() == phase
    assert cfa_from_name("lms-bayer").name == "lms-bayer"
    assert cfa_from_name("LMMS").name == "lms-bayer" and cfa_from_name("mlsm").name == "lms-bayer-grbg"
    assert cfa_from_name("RGGB").name == "bayer-rggb"
    assert cfa_from_name("LMLS/MLML/LSLM/MLML").name == "lms"
    doubled = cfa_from_name("LM/SL")                               # L doubled on the other diagonal
    assert (doubled.name, doubled.kind, doubled.layout, doubled.bayer_phase()) == (
        "LM/SL", "lms-bayer-double-l", "bayer", "GRBG")
    other = cfa_from_name("LL/MS")
    assert (other.name, other.kind, other.layout) == ("LL/MS", "lms-other", "other")
    assert layout_of(np.array([[0, 1], [1, 0]])) == "other"        # a channel missing
    with pytest.raises(ClispError, match="Bayer layout"):
        other.bayer_phase()


@pytest.mark.parametrize("name, kind, spectral, layout, fast_floor, default_floor", KINDS)
def test_kind_through_dng_and_process(tmp_path: Path, name: str, kind: str, spectral: str, layout: str,
                                      fast_floor: float, default_floor: float) -> None:
    sim = simulate(scene(), name, gain=1, seed=3)
    cfa = sim.raw.cfa
    assert (cfa.kind, cfa.spectral, cfa.layout) == (kind, spectral, layout)
    if spectral == "lms":                 # the colour side follows the channels, not the layout
        np.testing.assert_array_equal(sim.raw.colour_matrix, P_LMS)
        np.testing.assert_array_equal(sim.raw.wb, WB_LMS)
    path = tmp_path / "raw.dng"
    write_raw(path, sim.raw)
    raw = read_raw(path)
    assert (raw.cfa.name, raw.cfa.kind, raw.cfa.channels) == (cfa.name, cfa.kind, cfa.channels)
    np.testing.assert_array_equal(raw.cfa.pattern, cfa.pattern)
    np.testing.assert_array_equal(raw.data, sim.raw.data)
    for preset, floor in (("fast", fast_floor), (None, default_floor)):
        out = clisp.process(raw, preset=preset)
        assert out.shape == sim.truth.shape and np.all(np.isfinite(out))
        assert psnr(out, sim.truth, border=6) > floor, (name, preset)


def test_lms_bayer_takes_the_bayer_demosaics() -> None:
    """The presets pick the demosaic by layout, the chroma denoiser's space by the channels."""
    raw = simulate(scene(), "lms-bayer", gain=4, seed=1).raw
    names = {preset: build_pipeline(raw, preset=preset).stages for preset in ("fast", "balanced", "quality")}
    assert any(type(s).__name__ == "DemosaicRI" for s in names["quality"])
    assert any(type(s).__name__ == "DemosaicDLMMSE" for s in names["balanced"])
    denoise = [s for s in names["quality"] if type(s).__name__ == "ChromaDenoise"]
    assert denoise and denoise[0].space.name == "lms"
    truth = simulate(scene(), "lms-bayer", gain=4, seed=1).truth
    for demosaic in ("malvar", "dlmmse", "ri", "ari", "bilinear"):
        out = clisp.process(raw, demosaic=demosaic)
        assert np.all(np.isfinite(out)) and psnr(out, truth, border=6) > 31.0, demosaic


@pytest.mark.parametrize("cfa, demosaic, message", [
    ("lms-bayer", "guided", r"demosaic 'guided' works on lms CFAs, not lms-bayer \(the bayer layout\)"),
    ("lms-bayer", "hybrid", r"demosaic 'hybrid' works on lms CFAs, not lms-bayer \(the bayer layout\)"),
    ("lms", "ri", r"demosaic 'ri' works on bayer CFAs, not lms$"),
    ("lms", "malvar", r"needs a Bayer CFA \(RGGB, GRBG, GBRG or BGGR\), got lms"),
    ("LL/MS", "ri", r"demosaic 'ri' works on bayer CFAs, not lms-other \(the other layout\)"),
    ("LL/MS", "dlmmse", r"needs a Bayer CFA \(RGGB, GRBG, GBRG or BGGR\), got LL/MS"),
])
def test_demosaic_refuses_a_layout(cfa: str, demosaic: str, message: str) -> None:
    raw = simulate(scene(16, 16), cfa, gain=1, seed=1, optics="none").raw
    with pytest.raises(ClispError, match=message):
        build_pipeline(raw, demosaic=demosaic)


def test_cli_lms_bayer(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The issue's acceptance commands: simulate --cfa lms-bayer, then process to EXR; and the refusal."""
    png, raw, exr = tmp_path / "scene.png", tmp_path / "x.dng", tmp_path / "x.exr"
    write_image(png, scene(), encoded=False)
    assert main(["simulate", str(png), "-o", str(raw), "--cfa", "lms-bayer", "--gain", "4"]) == 0
    assert main(["process", str(raw), "-o", str(exr)]) == 0
    image, is_float = read_image(exr)
    assert is_float and image.shape == (64, 96, 3) and np.all(np.isfinite(image))
    capsys.readouterr()
    assert main(["process", str(raw), "-o", str(tmp_path / "y.exr"), "--demosaic", "guided"]) == 2
    err = capsys.readouterr().err
    assert "x.dng: demosaic 'guided' works on lms CFAs, not lms-bayer (the bayer layout)" in err
    assert not (tmp_path / "y.exr").exists()


def test_rawpy_opens_lms_bayer(tmp_path: Path) -> None:
    """LibRaw reads our LMS-on-Bayer DNG as a 2 x 2 CFA whose colours 0, 1, 2 sit where L, M, S are."""
    rawpy = pytest.importorskip("rawpy")
    sim = simulate(scene(), "lms-bayer", gain=1, seed=2)
    path = tmp_path / "lms_bayer.dng"
    write_raw(path, sim.raw)
    with rawpy.imread(str(path)) as r:
        pattern = np.asarray(r.raw_pattern)
        assert pattern.shape == (2, 2)
        desc = r.color_desc.decode()                                   # 'RGBG': index 3 is the second G
        colours = np.array([["RGB".index(desc[int(v)]) for v in row] for row in pattern])
        np.testing.assert_array_equal(colours, sim.raw.cfa.pattern)
        np.testing.assert_array_equal(r.raw_image_visible, sim.raw.data)
        assert r.postprocess(half_size=True).shape[:2] == (32, 48)


def test_l_doubled_takes_the_bayer_demosaics(tmp_path: Path) -> None:
    """Issue 45: L doubled on the Bayer layout gets the Bayer demosaics (RI under quality, DLMMSE under
    balanced, ARI under best) and the LMS colour side; --half-size bins it as any 2 x 2 CFA."""
    sim = simulate(scene(), "ML/LS", gain=4, seed=1)
    names = {preset: [type(s).__name__ for s in build_pipeline(sim.raw, preset=preset).stages]
             for preset in ("fast", "balanced", "quality", "best")}
    assert "DemosaicRI" in names["quality"] and "DemosaicDLMMSE" in names["balanced"]
    assert "DemosaicARI" in names["best"]
    denoise = [s for s in build_pipeline(sim.raw).stages if type(s).__name__ == "ChromaDenoise"]
    assert denoise and denoise[0].space.name == "lms"
    for demosaic in ("malvar", "dlmmse", "ri", "bilinear"):
        out = clisp.process(sim.raw, demosaic=demosaic)
        assert np.all(np.isfinite(out)) and psnr(out, sim.truth, border=6) > 30.0, demosaic
    half = clisp.process(sim.raw, half_size=True)
    assert half.shape == (32, 48, 3) and np.all(np.isfinite(half))


def test_l_doubled_raw_written_before_issue_45(tmp_path: Path) -> None:
    """A raw written when L doubled on 2 x 2 was the 'other' layout stores kind 'lms-other': it still reads."""
    from dataclasses import replace
    sim = simulate(scene(), "ML/LS", gain=1, seed=1)
    old = CFA(name="ML/LS", kind="lms-other", channels=("L", "M", "S"), pattern=sim.raw.cfa.pattern)
    write_raw(tmp_path / "old.dng", replace(sim.raw, cfa=old))
    raw = read_raw(tmp_path / "old.dng")
    assert (raw.cfa.name, raw.cfa.kind, raw.cfa.layout) == ("ML/LS", "lms-bayer-double-l", "bayer")
