"""tools/reproduce_paper.py --protocol (issue 32, item 4; ../shared/SPEC.md section 9) on small scenes
made in code: the srgb-as-linear reading must hand the simulator the files' encoded values, score
differently from the linear one, and ``both`` must print the two Table 1s side by side."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from paths import TOOLS

sys.path.insert(0, str(TOOLS))

import paper_tables as pt  # noqa: E402  (tools/ is not a package)
import reproduce_paper as rp  # noqa: E402
from clisp.io.imageio import write_image  # noqa: E402
from clisp.modules.chroma_denoise.stage import ChromaDenoiseParams  # noqa: E402
from clisp.sim.charts import dead_leaves  # noqa: E402
from clisp.sim.colorimetry import srgb_encode  # noqa: E402


def _scene_file(folder: Path, name: str, size: int = 64, seed: int = 1,
                rmin: float = 2.0) -> tuple[Path, np.ndarray]:
    """A dead-leaves scene written as a 16-bit sRGB-encoded file; returns (path, encoded values)."""
    folder.mkdir(parents=True, exist_ok=True)
    encoded = srgb_encode(dead_leaves(size, seed=seed, rmin=rmin))
    path = folder / name
    write_image(path, encoded, encoded=True)
    return path, encoded


def test_srgb_as_linear_feeds_the_encoded_values(tmp_path):
    path, encoded = _scene_file(tmp_path, "a.png", size=66)     # 66: the 4 px crop must bite
    scene = rp.protocol_scene(path, "srgb-as-linear")
    assert scene.shape == (64, 64, 3)
    np.testing.assert_allclose(scene, encoded[:64, :64], atol=1.0 / 65535)
    linear = rp.protocol_scene(path, "linear")
    assert np.abs(linear - scene).max() > 0.1                   # the linear reading decodes
    with pytest.raises(ValueError):
        rp.protocol_scene(path, "gamma")


def test_srgb_as_linear_scores_the_paper_reading(tmp_path):
    """Noiseless Bayer (DLMMSE) on a dead-leaves crop (discs of 8 px radius and up, so that the
    demosaic's error is not all aliasing): the encoded values taken as linear score above the
    linear chain (measured +1.9 dB here; SPEC section 9: about 6 dB on Kodak); equal scores would
    mean the option does nothing."""
    path, _ = _scene_file(tmp_path, "b.png", size=96, seed=1, rmin=8.0)
    runner = pt.Runner(ChromaDenoiseParams(), None)
    lms = next(n for n in pt.LMS_PREFERENCE if n in pt.DEMOSAICS)
    linear = rp.protocol_item((path, None, "linear"), runner, lms, "dlmmse")
    encoded = rp.protocol_item((path, None, "srgb-as-linear"), runner, lms, "dlmmse")
    assert len(linear) == len(encoded) == 2                      # (Bayer, LMS)
    assert encoded[0] > linear[0] + 1.0                          # Bayer: the paper's absolute level


def test_both_prints_the_two_table1s_side_by_side(tmp_path, capsys):
    _scene_file(tmp_path / "kodak", "k1.png", size=64, seed=3)
    _scene_file(tmp_path / "mcmaster", "1.tif", size=64, seed=4)
    assert rp.main(["--data", str(tmp_path), "--table1-only", "--protocol", "both", "--levels", "none"]) == 0
    out = capsys.readouterr().out
    assert "| linear: ours (lead) |" in out and "| srgb-as-linear: ours (lead) |" in out
    rows = [line for line in out.splitlines() if line.startswith("| Kodak | no noise |")
            or line.startswith("| IMAX (McMaster) | no noise |")]
    assert len(rows) == 2
    for row in rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        assert cells[2] == "42.79/43.15 (+0.36)" or cells[2] == "37.26/39.31 (+2.05)"   # the paper's
        assert cells[3] != cells[5]                              # the two protocols' figures differ


def test_levels_and_protocol_options():
    assert rp.parse_levels("none,4,64") == [None, 4, 64]
    with pytest.raises(Exception):
        rp.parse_levels("3")
    with pytest.raises(SystemExit):
        rp.main(["--protocol", "gamma", "--table1-only"])
