"""tools/lms_oracle.py, tools/cfa_linear_bound.py and tools/bench_lms_demosaic.py (issue 28) on small
scenes made in code: the harnesses must reproduce what they stand for."""
from __future__ import annotations

import sys

import numpy as np

from paths import TOOLS

sys.path.insert(0, str(TOOLS))

import bench  # noqa: E402  (tools/ is not a package)
import bench_lms_demosaic  # noqa: E402
import cfa_linear_bound  # noqa: E402
import lms_oracle  # noqa: E402
from clisp.metrics import psnr  # noqa: E402
from clisp.pipeline import build_pipeline  # noqa: E402
from clisp.sim.charts import dead_leaves  # noqa: E402
from clisp.sim.simulate import simulate  # noqa: E402


def test_true_camera_is_what_the_sensor_sampled():
    """Without optics or noise the oracle's truth, sampled at the CFA sites, is the normalised mosaic
    (a wrong matrix, gain or channel order would not be)."""
    scene = dead_leaves(48, seed=3)
    for kind in ("lms", "bayer"):
        sim = simulate(scene, kind, gain=None, optics="none")
        true = lms_oracle.true_camera(sim.truth, kind, sim.raw.pass1_gains())
        mosaic = bench.normalised_mosaic(sim.raw)
        channel = sim.raw.cfa.channel_map(*mosaic.shape)
        sampled = np.take_along_axis(true, channel[..., None].astype(np.intp), axis=-1)[..., 0]
        np.testing.assert_allclose(sampled, mosaic, atol=1e-5)


def test_oracle_variants_split_and_join():
    rng = np.random.default_rng(0)
    est, true = rng.random((8, 8, 3)), rng.random((8, 8, 3))
    v = lms_oracle.lms_variants(est, true)
    np.testing.assert_allclose(lms_oracle.lms_variants(true, true)["only luminance"], true)
    np.testing.assert_allclose(v["true luminance"][..., 0] - v["true luminance"][..., 1], est[..., 0] - est[..., 1])
    np.testing.assert_allclose(v["true S"][..., 2], true[..., 2])
    b = lms_oracle.bayer_variants(est, true)
    np.testing.assert_allclose(b["true chroma"][..., 1], est[..., 1])
    np.testing.assert_allclose(b["true chroma"][..., 0] - b["true chroma"][..., 1], true[..., 0] - true[..., 1])


def test_oracle_default_is_the_pipeline():
    """The oracle's "default" scores as the whole default pipeline (the split at the demosaic and
    the after-stages reproduce it), and handing it the true chroma helps."""
    scene = dead_leaves(128, seed=5)
    scores, rms = lms_oracle.run_scene(scene, "noiseless", "lms")
    sim = simulate(scene, "lms", gain=None, optics="airy", seed=0)
    whole = psnr(build_pipeline(sim.raw, output="linear").run(sim.raw.data), sim.truth, border=10)
    assert abs(scores["default"] - whole) < 0.05
    assert scores["only luminance"] > scores["default"] + 1.0
    assert set(rms) == {"Y", "C", "S"} and all(v > 0 for v in rms.values())


def test_linear_bank_needs_its_phase():
    """Per-phase filters trained on one chart reproduce it; applied one pixel off their phase they
    fail (the phase bookkeeping is what makes them work)."""
    scene = dead_leaves(96, seed=7)
    for kind, period in (("lms", 4), ("bayer", 2)):
        bank = cfa_linear_bound.LinearBank(kind, period, 5)
        sim = simulate(scene, kind, gain=None, optics="airy")
        mosaic = bench.normalised_mosaic(sim.raw).astype(np.float64)
        bank.add(mosaic, sim.truth)
        bank.solve()
        good = psnr(bank.apply(mosaic), sim.truth, border=10)
        shifted = bank.apply(mosaic[:, 1:])
        off = psnr(shifted, sim.truth[:, 1:], border=10)
        assert good > 20 and off < good - 6, (kind, good, off)


def test_bench_lms_demosaic_runs(capsys):
    assert bench_lms_demosaic.main(["--shape", "96x128", "--repeat", "1", "--methods", "guided,bilinear"]) == 0
    out = capsys.readouterr().out
    assert "DemosaicLMSGuided" in out and "DemosaicBilinear" in out and out.count("MP/s") == 2



def test_linear_bank_bands_are_the_whole_patches():
    """The banded patches (memory) equal the whole image's, rows of every phase."""
    rng = np.random.default_rng(3)
    mosaic = rng.random((150, 37))
    bank = cfa_linear_bound.LinearBank("lms", 4, 5)
    whole = cfa_linear_bound.patches(mosaic, 5)
    for y0, y1 in cfa_linear_bound.bands(150):
        np.testing.assert_array_equal(bank.band_patches(mosaic, y0, y1), whole[y0:y1])


def test_linear_bank_trained_with_noise_denoises():
    """Trained on noisy mosaics against the clean truth (issue 45), the bank is the linear joint
    demosaic and denoise for that noise: on a noisy held-out chart it beats the noiseless-trained one."""
    banks = cfa_linear_bound.train_banks(["bayer", "ML/LS"], [None, 16.0], 1, 5)
    assert banks[("ML/LS", 16.0)].period == 2
    scenes = {"dl": [("dl", dead_leaves(96, seed=11))]}
    scores = cfa_linear_bound.score_banks(banks, scenes)
    for cfa in ("bayer", "ML/LS"):
        sim = simulate(scenes["dl"][0][1], cfa, gain=16, optics="airy", seed=0)
        mosaic = bench.normalised_mosaic(sim.raw).astype(np.float64)
        noiseless_bank = psnr(banks[(cfa, None)].apply(mosaic), sim.truth, border=10)
        assert scores[("dl", cfa, 16.0)] > noiseless_bank + 0.3, (cfa, scores, noiseless_bank)   # measured +0.7
