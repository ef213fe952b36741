"""tools/bench_many_files.py (issue 29) on two small raws made in code."""
from __future__ import annotations

import sys

from paths import TOOLS

sys.path.insert(0, str(TOOLS))

import bench_many_files  # noqa: E402  (tools/ is not a package)


def test_bench_many_files_small(capsys):
    """Both ways write every output (the tool stops otherwise) and the ratio is reported."""
    assert bench_many_files.main(["--count", "2", "--size", "128x128", "--repeat", "1", "--preset", "fast"]) == 0
    out = capsys.readouterr().out
    assert "one process per raw" in out and "one process for all" in out and "throughput ratio" in out
