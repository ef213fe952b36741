"""Shared fixtures: the process-wide OpenCL runtime (PoCL on a machine without a GPU), a
fixed resident-set figure for the whole-process memory budget, and a fresh clisp cache folder."""
from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import pytest

import clisp.engine.memory
from clisp.engine import executor
from clisp.engine.runtime import get_runtime

os.environ.setdefault("CLISP_CACHE_DIR", tempfile.mkdtemp(prefix="clisp-test-cache-"))
"""clisp's records of built programs start empty in every test run (unless the caller set the
folder), as on a fresh machine: the first-build path runs in the tests, not only on users'
machines. The compiler's own cache (PoCL's) is shared, so nothing is compiled twice."""

TEST_PROCESS_RSS = 200 * 2**20
"""What the memory planner is told the process holds. ``--mem`` budgets a clisp process; the
test process grows past 1 GiB over the suite (every program built, every test's arrays), which
would make the default --mem of in-process CLI calls depend on test order. Subprocess tests
(tools' smoke tests) see the real figure."""


MAX_WORKERS = 4
"""At most this many worker processes for ``-n auto`` (pyproject's addopts). Each worker holds its
own OpenCL context, whose CPU device (PoCL) already uses every core for a kernel: the workers win
where the suite is single-threaded Python, NumPy references and first builds of programs (one
process: 113 % of 2 cores, 13:00 with empty caches; two workers: 191 %, 7:35), and more than a few
would only multiply the processes' memory."""


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:
    """pytest-xdist's ``-n auto``: one worker per core, at most MAX_WORKERS."""
    return max(1, min(os.cpu_count() or 1, MAX_WORKERS))


@pytest.fixture(scope="module")
def rt():
    return get_runtime()


@pytest.fixture(autouse=True)
def fixed_resident_set(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(clisp.engine.memory, "resident_bytes", lambda: TEST_PROCESS_RSS)


def has_cpu_device() -> bool:
    """Whether OpenCL lists a CPU device here (PoCL, from the pocl-binary-distribution wheel); a
    GPU-only machine (its driver's OpenCL, no PoCL) has none."""
    from clisp.engine.runtime import list_devices
    import pyopencl as cl
    try:
        return any(device.type & cl.device_type.CPU for _, _, _, device in list_devices())
    except Exception:
        return False


needs_cpu_device = pytest.mark.skipif(not has_cpu_device(), reason="needs a CPU OpenCL device (PoCL); "
                                      "this machine's OpenCL lists none (a GPU-only machine)")
"""For tests that ask for the CPU device by name (``Runtime("cpu")``): skipped, with the reason, where
there is none, instead of failing."""


@contextmanager
def discrete_gpu(monkeypatch: pytest.MonkeyPatch, rt: Any) -> Iterator[Any]:
    """``rt`` as the engine sees a discrete GPU (NVIDIA's OpenCL on an H200), on whatever device it
    is: no memory shared with the host (Runtime.host_unified False: the mosaic copied to the device
    once or the windows uploaded, transfers on a second queue, pinned staging buffers) and its
    buffers not counted against the host budget (executor.device_buffers_in_host_memory False, as
    for any device that is not a CPU). The second queue, the pools and the memoised plans are made
    anew inside and dropped after it; monkeypatch undoes the rest."""
    rt.finish()
    monkeypatch.setattr(rt, "host_unified", False)
    monkeypatch.setattr(rt, "_transfer_queue", None)
    monkeypatch.setattr(executor, "device_buffers_in_host_memory", lambda runtime: bool(runtime.host_unified))
    executor.PLANS.clear()            # a plan's memo key holds the device limits, not the predicate
    rt.trim_pool()
    rt.staging.trim()                 # staging left by earlier runs would make the counts depend on them
    try:
        yield rt
    finally:
        rt.finish()
        rt.trim_pool()
        rt.staging.trim()
        executor.PLANS.clear()


@pytest.fixture(params=["device", "discrete-gpu"])
def device_kind(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> Iterator[Any]:
    """The process's runtime as it is, and as a discrete GPU (:func:`discrete_gpu`): a test of the
    paths that differ runs both on a machine without a GPU."""
    rt = get_runtime()
    if request.param == "device":
        yield rt
    else:
        with discrete_gpu(monkeypatch, rt):
            yield rt
