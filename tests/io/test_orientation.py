"""Camera orientation (LibRaw's flip code) is applied to the processed image."""
from __future__ import annotations

import numpy as np
import pytest

import clisp
from clisp.sim.charts import demo_chart


@pytest.mark.parametrize("flip, expected", [(0, lambda a: a), (3, lambda a: a[::-1, ::-1]),
                                            (5, lambda a: np.rot90(a, 1)), (6, lambda a: np.rot90(a, -1))])
def test_flip_codes(flip: int, expected) -> None:
    sim = clisp.simulate(demo_chart().image[:64, :96], cfa="bayer", gain=None, optics="none")
    upright = clisp.process(sim.raw)
    sim.raw.metadata["flip"] = flip
    out = clisp.process(sim.raw)
    assert np.array_equal(out, expected(upright))
