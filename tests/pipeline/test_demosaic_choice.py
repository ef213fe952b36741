"""The noise-adaptive stage choice (clisp.pipeline.demosaic_choice, issue 30): the rule on its calibration table
and what build_pipeline picks at low and high noise."""
from __future__ import annotations

import numpy as np
import pytest

from clisp.modules.demosaic_lms_guided.stage import DemosaicLMSGuided
from clisp.pipeline import build_pipeline
from clisp.sim.simulate import simulate
from clisp.pipeline.demosaic_choice import ALTERNATIVES, ERROR_BUDGET_DB, WORST_BUDGET_DB, Alternative, noise_sigma


def _alternative(rows) -> Alternative:
    return Alternative("test", "DemosaicLMSGuided", lambda s: s, tuple(rows), 0.5)


def test_threshold_is_the_start_of_the_run_within_budget() -> None:
    ok, too_lossy, too_bad_somewhere = (-0.01, -0.05), (-0.05, -0.05), (-0.01, -0.2)
    assert _alternative([(0.01, *too_lossy), (0.02, *ok), (0.04, *ok)]).threshold() == 0.02
    # a row out of budget above a good one: only the run at the top counts
    assert _alternative([(0.01, *ok), (0.02, *too_bad_somewhere), (0.04, *ok)]).threshold() == 0.04
    assert _alternative([(0.01, *ok), (0.04, *too_lossy)]).threshold() == float("inf")
    assert -ERROR_BUDGET_DB > -WORST_BUDGET_DB


def test_the_shipped_calibration_allows_one_pass_only_at_the_highest_noise() -> None:
    (one_pass,) = ALTERNATIVES
    rows = sorted(one_pass.calibration)
    assert one_pass.threshold() == rows[-1][0]          # gain 64 of the simulated sensor, no lower


def _raw(gain: float):
    rng = np.random.default_rng(0)
    scene = np.clip(0.3 + 0.1 * rng.standard_normal((96, 128, 3)), 0, 1)
    return simulate(scene, "lms", gain=gain, optics="none", seed=1).raw


@pytest.mark.parametrize("gain, passes", [(4.0, 2), (64.0, 1)])
def test_build_pipeline_picks_by_noise(gain, passes) -> None:
    raw = _raw(gain)
    pipe = build_pipeline(raw, skip=True)
    (demosaic,) = [s for s in pipe.stages if isinstance(s, DemosaicLMSGuided)]
    assert demosaic.params.passes == passes
    assert pipe.stage_choice is not None and (pipe.stage_choice.alternative is not None) == (passes == 1)
    assert "noise-adaptive choice" in pipe.stage_choice.explain()
    # --no-skip (skip=False) and the plain API (skip=None) keep the preset's stage
    for skip in (False, None):
        kept = [s for s in build_pipeline(raw, skip=skip).stages if isinstance(s, DemosaicLMSGuided)]
        assert kept[0].params.passes == 2


def test_noise_sigma_of_the_simulated_sensor_grows_with_gain() -> None:
    from clisp.scene.noise import raw_noise
    sigmas = [noise_sigma(raw_noise(_raw(g)), 0) for g in (1.0, 16.0, 64.0)]
    assert sigmas[0] < sigmas[1] < sigmas[2]
    assert sigmas[2] == pytest.approx(sorted(ALTERNATIVES[0].calibration)[-1][0], rel=0.01)
