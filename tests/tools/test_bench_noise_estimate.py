"""tools/bench_noise_estimate.py (issue 42: the camera-raw noise estimate as good as before) on a
scene made in code: an even grey field at gain 16 has no texture to inflate the estimate, so the
error the tool reports is small, and it grows when the estimate is told a wrong model."""
from __future__ import annotations

import sys

import numpy as np

from paths import TOOLS

sys.path.insert(0, str(TOOLS))

import bench_noise_estimate  # noqa: E402  (tools/ is not a package)
from clisp.io.rawfile import write_raw  # noqa: E402
from clisp.sim.simulate import simulate  # noqa: E402


def test_an_even_grey_field_is_estimated_within_a_tenth(tmp_path):
    scene = np.full((256, 384, 3), 0.18, dtype=np.float32)
    for cfa in ("bayer", "lms"):
        path = tmp_path / f"grey-{cfa}.dng"
        write_raw(path, simulate(scene, cfa=cfa, gain=16, seed=3).raw)
        errors = bench_noise_estimate.child_errors([str(path)])
        assert len(errors) == 1 and len(errors[0]) == 3
        assert max(errors[0]) < 0.1, (cfa, errors)


def test_the_error_is_against_the_model_the_file_carries(tmp_path, monkeypatch):
    """The same estimate against a model with twice the sigma reads about 0.5 off: the tool
    compares with the DNG's own sensor model, not with itself."""
    from clisp.scene import noise
    path = tmp_path / "grey.dng"
    write_raw(path, simulate(np.full((256, 384, 3), 0.18, dtype=np.float32), cfa="bayer", gain=16, seed=3).raw)
    real = noise.raw_noise

    def doubled(raw, estimate=None, statistics=None):
        found = real(raw, estimate=estimate, statistics=statistics)
        return found if estimate else found.scaled(2.0)

    monkeypatch.setattr(noise, "raw_noise", doubled)
    errors = bench_noise_estimate.child_errors([str(path)])
    assert all(0.4 < e < 0.6 for e in errors[0]), errors
