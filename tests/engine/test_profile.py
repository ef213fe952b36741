"""How busy the device was (clisp.engine.profile, issue 41): the union of a tile loop's events over
its wall time, the host's cost per launch, launches per tile and the bytes moved."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from clisp.engine.profile import Profile, recording, union_length


def _event(start_ms: float, end_ms: float) -> SimpleNamespace:
    return SimpleNamespace(wait=lambda: None, profile=SimpleNamespace(start=int(start_ms * 1e6), end=int(end_ms * 1e6)))


def test_union_counts_overlaps_once() -> None:
    assert union_length([]) == 0
    assert union_length([(0, 4), (2, 6), (8, 9)]) == 7
    assert union_length([(0, 10), (1, 2), (3, 4)]) == 10


def test_busy_is_the_union_of_the_loops_events_over_their_wall() -> None:
    """Events outside a tile loop (a calibration's, say) do not count; overlapping events (a copy
    beside a kernel on a second queue) count once; the wall is the loops' own."""
    prof = Profile()
    prof.record("calibration", _event(0, 50))
    loop = prof.begin_loop()
    prof.record("k1", _event(100, 110))
    prof.record("upload", _event(105, 120), 4096, "upload")        # overlaps k1
    prof.record("k2", _event(130, 140))
    prof.enqueued(20e-6)
    prof.enqueued(40e-6)
    prof.named(100e-6)
    prof.end_loop(loop, 0.050, tiles=2)
    prof.record("after", _event(200, 300))
    f = prof.summary()
    assert f["device_busy_s"] == pytest.approx(0.030)                # 100..120 and 130..140
    assert f["device_busy"] == pytest.approx(0.6)
    assert f["launches_per_tile"] == 1.0 and f["named_per_tile"] == 0.5
    assert f["host_us_per_enqueue"] == pytest.approx(30.0) and f["host_us_per_launch_named"] == pytest.approx(100.0)
    assert f["bytes_upload"] == 4096 and f["bytes_download"] == 0
    assert prof.busy_lines()[0].startswith("device busy 60 % of the tile loop")


def test_recording_in_process(demo_raw_small) -> None:
    """An in-process caller gets the figures --profile prints: a run's loop, its device busy share
    (a fraction of its wall), its launches and the output's bytes."""
    import clisp
    from clisp.engine import profile
    clisp.process(demo_raw_small, preset="fast", output="srgb16")           # warm
    before = profile.active()
    with recording() as prof:
        out = clisp.process(demo_raw_small, preset="fast", output="srgb16")
    f = prof.summary()
    assert f["tiles"] >= 1 and 0 < f["device_busy"] <= 1.0 + 1e-9
    assert f["launches_per_tile"] >= 1 and f["host_us_per_enqueue"] > 0         # fast Bayer: one fused kernel
    assert f["bytes_upload"] + f["bytes_download"] + f["bytes_in_place"] >= out.nbytes
    assert profile.active() is before                                       # recording ends with the block


@pytest.fixture(scope="module")
def demo_raw_small():
    from clisp.sim.charts import demo_chart
    from clisp.sim.simulate import simulate
    scene = demo_chart().image
    return simulate(np.ascontiguousarray(scene[:96, :128]), cfa="bayer", gain=4, seed=3).raw
