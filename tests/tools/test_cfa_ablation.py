"""tools/cfa_ablation.py (issue 32, item 2) on a scene made in code: per-channel PSNR for the three
sensors that agrees with clisp.metrics.psnr, differs between sensors, and a denoiser that changes the
noisy figures but not the noiseless ones."""
from __future__ import annotations

import sys

import numpy as np
import pytest

from paths import TOOLS

sys.path.insert(0, str(TOOLS))

import cfa_ablation as ab  # noqa: E402  (tools/ is not a package)
import paper_tables as pt  # noqa: E402
from clisp.metrics import psnr  # noqa: E402
from clisp.modules.chroma_denoise.stage import ChromaDenoiseParams  # noqa: E402
from clisp.sim.charts import dead_leaves  # noqa: E402

PIPELINES = (("bayer", "ri"), ("lms-bayer", "ri"), ("lms", "guided"))


@pytest.fixture(scope="module")
def scores() -> dict:
    runner = pt.Runner(ChromaDenoiseParams(), None)
    scene = dead_leaves(96, seed=3)
    return {g: ab.scene_scores(scene, g, runner, PIPELINES) for g in (None, 16)}


def test_channel_psnr_matches_the_metric():
    rng = np.random.default_rng(0)
    truth = rng.uniform(0, 1, (40, 40, 3))
    out = truth + rng.normal(0, [0.01, 0.02, 0.04], (40, 40, 3))
    v = ab.channel_psnr(out, truth, border=4)
    assert v[0] == pytest.approx(psnr(out, truth, border=4))
    assert v[1] > v[2] > v[3]                                      # more noise in B than G than R


def test_three_sensors_per_channel_and_they_differ(scores):
    for g, per in scores.items():
        assert set(per) == {(k, n, d) for k, n in PIPELINES for d in (True, False)}
        for v in per.values():
            assert v.shape == (4,) and np.all(np.isfinite(v)) and np.all(v > 10)
        reds = [per[(k, n, True)][1] for k, n in PIPELINES]
        blues = [per[(k, n, True)][3] for k, n in PIPELINES]
        assert min(abs(a - b) for a, b in [(reds[0], reds[1]), (reds[1], reds[2]), (reds[0], reds[2])]) > 0.05
        assert max(blues) - min(blues) > 0.05
    # the L filter in place of R costs red on the Bayer layout without the denoiser (paper's step 1)
    assert scores[16][("lms-bayer", "ri", False)][1] < scores[16][("bayer", "ri", False)][1] - 1.0


def test_denoiser_runs_only_with_noise(scores):
    for k, n in PIPELINES:
        np.testing.assert_array_equal(scores[None][(k, n, True)], scores[None][(k, n, False)])
        assert not np.allclose(scores[16][(k, n, True)], scores[16][(k, n, False)])
