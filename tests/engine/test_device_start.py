"""The device brought up on a thread while the command line loads (clisp.engine.device_start)."""
from __future__ import annotations

import os
import sys

import numpy as np
import pytest

from clisp.engine import device_start
from clisp.engine.runtime import Runtime, _import_cl, choose_device

SPEC = os.environ.get("CLISP_DEVICE")
"""The device the runtimes of this test session use (a Runtime reads CLISP_DEVICE when given None)."""


@pytest.fixture
def fresh(monkeypatch):
    """device_start as in a new process (it brings a device up once per process)."""
    monkeypatch.setattr(device_start, "_STARTED", {})
    return device_start


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the loader is found in /proc/self/maps")
def test_the_loader_pyopencl_calls_is_found():
    """The slow calls go through ctypes (the GIL released) only where pyopencl's own loader is found."""
    _import_cl()
    library = device_start._loader()
    assert library is not None and hasattr(library, "clCreateContext")


def test_the_context_brought_up_works_and_is_taken_once(fresh):
    cl = _import_cl()
    fresh.begin(SPEC)
    platform, device, context = fresh.take(SPEC)
    assert (platform, device) == choose_device(SPEC)
    queue = cl.CommandQueue(context)
    values = np.arange(64, dtype=np.float32)
    buffer = cl.Buffer(context, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=values)
    back = np.empty_like(values)
    cl.enqueue_copy(queue, back, buffer).wait()
    assert np.array_equal(back, values)
    assert fresh.take(SPEC) is None


def test_a_runtime_takes_the_context_of_its_own_spec_only(fresh):
    fresh.begin(SPEC)
    assert fresh.take("no such device anywhere") is None          # begun for another spec
    fresh._STARTED.clear()
    fresh.begin(SPEC)
    prepared = fresh._STARTED
    rt = Runtime(None)
    assert prepared["taken"] and rt.context is prepared["result"][2]


def test_a_spec_nothing_matches_is_left_to_the_runtime(fresh):
    fresh.begin("no such device anywhere")
    assert fresh.take("no such device anywhere") is None
