"""Smoke test of tools/bench_bandwidth.py on a small simulated mosaic (no ../shared data)."""
from __future__ import annotations

import sys

import numpy as np

from paths import TOOLS

sys.path.insert(0, str(TOOLS))

import bench_bandwidth  # noqa: E402  (tools/ is not a package)


def test_bandwidth_figures_are_finite() -> None:
    from clisp.engine.runtime import get_runtime
    rt = get_runtime()
    assert bench_bandwidth.copy_bandwidth(rt, nbytes=4 * 2**20, repeat=1) > 0
    raw = bench_bandwidth.test_raw((320, 240), None)
    assert raw.shape == (240, 320) and raw.cfa.kind == "bayer"
    for output, out_bytes in (("linear", 240 * 320 * 12), ("srgb16", 240 * 320 * 6)):
        copy = lambda: bench_bandwidth.copy_bandwidth(rt, nbytes=4 * 2**20, repeat=1)   # noqa: E731
        seconds, bandwidth, tally, plan = bench_bandwidth.pipeline_bandwidth(raw, output, 1, copy)
        assert np.isfinite(seconds) and seconds > 0 and bandwidth > 0 and "tiles of" in plan
        assert tally["upload"] >= 2 * raw.data.nbytes                  # read + write, halos included
        assert tally["kernels"] >= raw.data.nbytes + out_bytes
        # one full-width tile: the last kernel writes the host's array itself where it can
        assert tally["download"] == (0 if rt.host_unified else 2 * out_bytes)
