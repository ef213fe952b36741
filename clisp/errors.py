"""The one exception type that the CLI turns into a one-line message and a non-zero exit."""
from __future__ import annotations


class ClispError(Exception):
    """A user-facing error: bad input, unsupported format, missing OpenCL, failed kernel build."""
