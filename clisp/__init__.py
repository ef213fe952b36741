"""clisp: an OpenCL image signal processor for raw sensor data (LMS camera and Bayer baseline).

Array API (rawpy users ask for arrays)::

    import clisp
    sim = clisp.simulate(scene_linear_srgb, cfa="lms", gain=8, seed=1)   # -> SimResult(raw, truth)
    rgb = clisp.process(sim.raw)                                         # -> H x W x 3 linear sRGB float32
"""
from __future__ import annotations

from typing import Any

__version__ = "0.1.0"
__all__ = ["simulate", "process", "read_raw", "write_raw", "__version__"]


def __getattr__(name: str) -> Any:
    # Lazy imports keep `import clisp` fast and free of OpenCL start-up.
    if name == "simulate":
        from .simulate import simulate
        return simulate
    if name == "process":
        from .pipeline import process
        return process
    if name in ("read_raw", "write_raw"):
        from . import rawfile
        return getattr(rawfile, name)
    raise AttributeError(f"module 'clisp' has no attribute {name!r}")
