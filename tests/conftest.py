"""Shared fixtures: the process-wide OpenCL runtime (PoCL on a machine without a GPU)."""
from __future__ import annotations

import pytest

from clisp.runtime import get_runtime


@pytest.fixture(scope="module")
def rt():
    return get_runtime()
