"""The process's resident memory, for ``clisp process --mem`` (a promise about the whole process).

``--mem`` bounds the peak resident set of the process: the interpreter and libraries, the decoded
raw when it is in memory, the OpenCL runtime's buffers (on a CPU device they are pages of this
process) and every host buffer of the tiles in flight. The planner measures what the process
already holds when it plans (:func:`resident_bytes`), adds RSS_MARGIN for what it cannot count,
and gives the rest to the tiles (Pipeline.tile_cost counts those exactly).
"""
from __future__ import annotations

import os
import resource
import sys

RSS_MARGIN = 128 * 2**20
"""Resident bytes the planner cannot count tile by tile: PoCL compiling a kernel for a new
work-group size on first launch (LLVM's arenas when its cache is cold), the allocator's
fragmentation, small constant tables and Python temporaries. The largest excess over the planned
bytes measured by tools/check_mem.py was 65 MiB, so 128 leaves about 60 (README.md)."""


def resident_bytes() -> int:
    """Current resident set of this process in bytes (Linux /proc); elsewhere the peak so far."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return peak_resident_bytes()


def peak_resident_bytes() -> int:
    """Peak resident set of this process so far in bytes (getrusage)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(peak) if sys.platform == "darwin" else int(peak) * 1024


def format_bytes(n: float) -> str:
    """'812M', '1.5G': binary units, as --mem takes them."""
    if n >= 2**30:
        return f"{n / 2**30:.2f}".rstrip("0").rstrip(".") + "G"
    return f"{max(1, round(n / 2**20))}M"
