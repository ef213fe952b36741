"""--auto-exposure (clisp.scene.exposure): LibRaw's auto-bright rule, estimated from the raw, holds on the
output it is applied to."""
from __future__ import annotations

import numpy as np
import pytest

from clisp.scene.exposure import auto_exposure_ev
from clisp.pipeline import EXPOSURE_LIMIT, build_pipeline
from clisp.sim.charts import dead_leaves
from clisp.sim.simulate import simulate


@pytest.mark.parametrize("kind", ["lms", "bayer"])
def test_auto_exposure_takes_the_top_percent_to_white(kind: str) -> None:
    """A dim scene (dead leaves at a fifth of white, simulated at gain 4): after --auto-exposure the
    level 1 % of the output's pixels exceed, in its brightest channel, is white within 0.25 EV (the
    estimate works on CFA-tile means, whose 1 % level is below the pixels' on noise and fine
    texture: 1.14 for LMS's 4 x 4 tiles, 0.96 for Bayer's 2 x 2); --exposure adds to it."""
    scene = 0.2 * dead_leaves(160, seed=4)
    raw = simulate(scene, kind, gain=4, seed=1).raw
    pipeline = build_pipeline(raw, preset="fast", auto_exposure=True)
    out = pipeline.run(raw.data)
    top = np.percentile(out.reshape(-1, 3), 99, axis=0).max()
    assert abs(np.log2(top)) < 0.25 and pipeline.exposure_ev > 1.5
    plain = build_pipeline(raw, preset="fast", exposure=0.5, auto_exposure=True)
    assert plain.exposure_ev == pytest.approx(pipeline.exposure_ev + 0.5)          # --exposure adds to it


def test_auto_exposure_never_darkens_and_stays_in_range() -> None:
    """More than 1 % of the pixels at the sensor's white: no change (LibRaw's rule never darkens); a
    black frame: 0 EV, not infinite."""
    bright = np.full((96, 96, 3), 0.3)
    bright[:20] = 4.0                                      # a fifth of the frame clipped
    raw = simulate(bright, "bayer", gain=2, seed=0).raw
    assert auto_exposure_ev(raw, np.ones(3), EXPOSURE_LIMIT) == 0.0
    black = simulate(np.zeros((64, 64, 3)), "bayer", gain=1, seed=0).raw
    assert 0.0 <= auto_exposure_ev(black, np.ones(3), EXPOSURE_LIMIT) <= EXPOSURE_LIMIT
