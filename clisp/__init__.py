"""clisp: an OpenCL image signal processor for raw sensor data (LMS camera and Bayer baseline).

Array API (rawpy users ask for arrays)::

    import clisp
    scene = clisp.read_scene("photo.png")                              # H x W x 3 linear sRGB
    sim = clisp.simulate(scene, cfa="lms", gain=8, seed=1)             # -> SimResult(raw, truth)
    rgb = clisp.process(sim.raw)                                         # -> H x W x 3 linear sRGB float32
    raw = clisp.read_raw("camera.dng"); clisp.write_raw("ours.dng", sim.raw)
"""
from __future__ import annotations

# The public API, imported on first use (PEP 562), so that `import clisp.<module>` (a helper process
# of the program builder, clisp.engine.program_builder) does not pay for the whole package. The
# layers below it: clisp.engine (runtime, tiling, streaming), clisp.io (raw files, EXIF, image
# writers), clisp.sim (the simulator), clisp.modules (the processing stages), clisp.pipeline
# (stages into a run).
from .version import __version__

_PUBLIC = {"read_raw": "io.rawfile", "write_raw": "io.rawfile", "process": "pipeline", "simulate": "sim.simulate",
           "read_scene": "io.imageio"}

__all__ = ["simulate", "process", "read_raw", "write_raw", "read_scene", "__version__"]


def __getattr__(name: str) -> object:
    if name in _PUBLIC:
        from importlib import import_module   # here: only on the first use of a public name
        value = getattr(import_module(f".{_PUBLIC[name]}", __name__), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'clisp' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_PUBLIC])
