"""The simulated sensor's defects (clisp.sim.defects) and simulate's options for them."""
from __future__ import annotations

import numpy as np
import pytest

from clisp.cfa import bayer_cfa, lms_cfa
from clisp.errors import ClispError
from clisp.io.opcodes import gain_map_at, selects
from clisp.sim import defects as sd
from clisp.sim.simulate import simulate

SCENE = np.full((64, 96, 3), 0.3)


def test_fixed_pattern_is_seeded():
    d = sd.SensorDefects(hot=0.002, warm=0.003, dead=0.001, seed=4)
    shape = (64, 96)
    sites = [sd.defect_sites(d, shape, k) for k in ("hot", "warm", "dead")]
    assert [len(s) for s in sites] == [round(0.002 * 64 * 96), round(0.003 * 64 * 96), round(0.001 * 64 * 96)]
    assert len(np.unique(np.concatenate(sites))) == sum(map(len, sites))        # no pixel twice
    assert all(np.array_equal(a, sd.defect_sites(d, shape, k)) for a, k in zip(sites, ("hot", "warm", "dead")))
    other = sd.SensorDefects(hot=0.002, warm=0.003, dead=0.001, seed=5)
    assert not np.array_equal(sites[0], sd.defect_sites(other, shape, "hot"))


def test_truth_is_the_ideal_sensor_and_the_rest_of_the_raw_too():
    d = sd.SensorDefects(hot=0.01, dead=0.01, dark_current=0.0, seed=2)
    clean = simulate(SCENE, cfa="bayer", gain=4, seed=3)
    sim = simulate(SCENE, cfa="bayer", gain=4, seed=3, defects=d)
    np.testing.assert_array_equal(sim.truth, clean.truth)
    bad = sd.bad_sites(d, clean.raw.shape)
    np.testing.assert_array_equal(sim.raw.data[~bad], clean.raw.data[~bad])
    assert np.all(sim.raw.data[sd.dead_mask(d, clean.raw.shape)] < 80)            # black 64 + read noise
    assert sim.raw.metadata["sensor"]["hot"] == 0.01


def test_dark_frames_average_to_the_expected_dark():
    d = sd.SensorDefects(dark_current=200.0, exposure_time=1.0, hot=0.002, seed=1)
    raw = simulate(SCENE, cfa="lms", gain=2, seed=1, defects=d).raw
    frames = sd.frames(raw, d, "dark", 8, 2.0, 100)
    mean = np.mean([f.data.astype(float) for f in frames], axis=0)
    expected = sd.expected_dark(d, raw.shape, 2.0, sd.NoiseModel())
    unclipped = expected < 1000
    assert abs(float(np.mean(mean[unclipped] - expected[unclipped]))) < 0.2
    assert np.corrcoef(mean[unclipped], expected[unclipped])[0, 1] > 0.95     # the fixed pattern is there
    assert frames[0].metadata["frame"] == "dark" and frames[0].metadata["sensor"]["exposure_time"] == 1.0


def test_flat_frames_and_gain_maps_follow_the_shading():
    d = sd.SensorDefects(shading=0.5, seed=1)
    cfa = bayer_cfa()
    s = sd.shading(d, cfa, (64, 96))
    assert s[32, 48] > 0.99 and s.min() < 0.5                                   # corners below the luminance falloff
    flat = sd.flat_frame(d, cfa, (64, 96), 4.0, sd.NoiseModel(), 1).astype(float)
    assert abs(flat[28:36, 44:52].mean() - (64 + sd.FLAT_LEVEL * 959)) < 10
    ys, xs = np.mgrid[0:64, 0:96]
    g = np.ones((64, 96))
    for op in sd.gain_map_opcodes(d, cfa, (64, 96)):
        g = np.where(selects(op, ys, xs), g * gain_map_at(op, ys, xs), g)
    assert np.max(np.abs(g * s - 1)) < 2e-3                                     # the map undoes the shading


def test_defects_are_checked():
    with pytest.raises(ClispError, match="at most half"):
        sd.SensorDefects(hot=0.4, dead=0.2)
    with pytest.raises(ClispError, match="shading"):
        sd.SensorDefects(shading=0.0)


def test_simulate_cli_writes_frames_and_opcodes(tmp_path, capsys):
    from clisp.app.cli import main
    from clisp.io.imageio import write_image
    from clisp.io.rawfile import read_raw
    write_image(tmp_path / "s.png", np.full((32, 48, 3), 0.4), encoded=False)
    out = tmp_path / "r.dng"
    assert main(["simulate", str(tmp_path / "s.png"), "-o", str(out), "--cfa", "lms", "--gain", "4", "--hot-pixels",
                 "0.01:0.3", "--dead-pixels", "0.005", "--shading", "0.6", "--gainmap", "--bad-pixel-list",
                 "--dark-frames", "2", "--flat-frames", "1"]) == 0
    assert "2 dark and 1 flat frames beside it" in capsys.readouterr().out
    raw = read_raw(out)
    names = [op.name for op in raw.metadata["opcodes"]]
    assert names.count("GainMap") == 16 and names.count("FixBadPixelsList") == 1
    assert raw.metadata["sensor"]["hot_level"] == 0.3
    assert read_raw(tmp_path / "r_dark02.dng").metadata["frame"] == "dark"
    assert read_raw(tmp_path / "r_flat01.dng").metadata["gain"] == 1.0
