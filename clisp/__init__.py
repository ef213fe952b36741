"""clisp: an OpenCL image signal processor for raw sensor data (LMS camera and Bayer baseline).

Array API (rawpy users ask for arrays)::

    import clisp
    sim = clisp.simulate(scene_linear_srgb, cfa="lms", gain=8, seed=1)   # -> SimResult(raw, truth)
    rgb = clisp.process(sim.raw)                                         # -> H x W x 3 linear sRGB float32
    raw = clisp.read_raw("camera.dng"); clisp.write_raw("ours.dng", sim.raw)
"""
from __future__ import annotations

from .version import __version__  # noqa: E402

# Imported eagerly on purpose: the function ``simulate`` shares its name with the module
# ``clisp.simulate``; binding it here after the submodule loads keeps ``clisp.simulate`` the
# function however the submodule is imported later. OpenCL itself starts only on first use.
from .pipeline import process  # noqa: E402
from .rawfile import read_raw, write_raw  # noqa: E402
from .simulate import simulate  # noqa: E402

__all__ = ["simulate", "process", "read_raw", "write_raw", "__version__"]
