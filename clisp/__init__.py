"""clisp: an OpenCL image signal processor for raw sensor data (LMS camera and Bayer baseline).

Array API (rawpy users ask for arrays)::

    import clisp
    sim = clisp.simulate(scene_linear_srgb, cfa="lms", gain=8, seed=1)   # -> SimResult(raw, truth)
    rgb = clisp.process(sim.raw)                                         # -> H x W x 3 linear sRGB float32
    raw = clisp.read_raw("camera.dng"); clisp.write_raw("ours.dng", sim.raw)
"""
from __future__ import annotations

# The public API, imported eagerly (OpenCL itself starts only on first use). The layers below it:
# clisp.engine (runtime, tiling, streaming), clisp.io (raw files, EXIF, image writers), clisp.sim
# (the simulator), clisp.modules (the processing stages), clisp.pipeline (stages into a run).
from .io.rawfile import read_raw, write_raw
from .pipeline import process
from .sim.simulate import simulate
from .version import __version__

__all__ = ["simulate", "process", "read_raw", "write_raw", "__version__"]
