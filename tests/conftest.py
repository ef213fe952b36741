"""Shared fixtures: the process-wide OpenCL runtime (PoCL on a machine without a GPU), and a
fixed resident-set figure for the whole-process memory budget."""
from __future__ import annotations

import pytest

import clisp.engine.memory
from clisp.engine.runtime import get_runtime

TEST_PROCESS_RSS = 200 * 2**20
"""What the memory planner is told the process holds. ``--mem`` budgets a clisp process; the
test process grows past 1 GiB over the suite (every program built, every test's arrays), which
would make the default --mem of in-process CLI calls depend on test order. Subprocess tests
(tools' smoke tests) see the real figure."""


@pytest.fixture(scope="module")
def rt():
    return get_runtime()


@pytest.fixture(autouse=True)
def fixed_resident_set(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(clisp.engine.memory, "resident_bytes", lambda: TEST_PROCESS_RSS)
