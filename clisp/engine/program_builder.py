"""Build OpenCL programs in helper processes, so that a first run compiles on every CPU core.

PoCL compiles one program at a time per process (threads do not help: its compiler is serialised),
and a first run of the quality preset compiles about ten programs and their kernels, seconds of
work that one core does while the others idle. :meth:`clisp.engine.runtime.Runtime.build_programs`
shares the programs out: it starts helpers (``python -m clisp.engine.program_builder``), gives each
a list of programs on its standard input, builds its own share meanwhile, and loads the helpers'
results from the program store (clisp.engine.program_store) when they exit. A helper that fails
costs nothing but time: the runtime builds whatever it left out.

A helper's job (JSON on standard input)::

    {"platform": 0, "device": 0, "device_name": "pthread-...", "programs":
     [{"record": "/home/u/.cache/clisp/programs/<sha256>", "source": "...", "options": ["-D...", ...]}]}

It builds each program for that device, asks for its binary (on PoCL this compiles the generic
work-group function of every kernel, which is what a launch runs with
POCL_WORK_GROUP_SPECIALIZATION=0) and writes the record. Its exit status is the number of programs
it could not build (capped at 100).
"""
from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path
from typing import Any

from . import program_store


def kernel_parameters(cl: Any, kernel: Any) -> list[tuple[str, str, bool]]:
    """``kernel``'s parameters as the compiler reports them (macros expanded): (name, OpenCL type
    name, is a pointer), for a program built from source with ``-cl-kernel-arg-info``."""
    info, qualifier = cl.kernel_arg_info, cl.kernel_arg_address_qualifier
    return [(kernel.get_arg_info(i, info.NAME), kernel.get_arg_info(i, info.TYPE_NAME),
             kernel.get_arg_info(i, info.ADDRESS_QUALIFIER) != qualifier.PRIVATE)
            for i in range(kernel.get_info(cl.kernel_info.NUM_ARGS))]


def build_and_keep(cl: Any, context: Any, source: str, options: list[str], record: Path) -> Any:
    """Build ``source`` with ``options`` in ``context`` and keep its binary and kernel parameters in
    ``record``; returns the program (cl.RuntimeError when it does not build)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")                   # pyopencl warns on non-empty build logs
        prg = cl.Program(context, source).build(options=options)
    keep(cl, prg, record)
    return prg


def keep(cl: Any, prg: Any, record: Path) -> bool:
    """Write ``prg``'s binary and its kernels' parameters to ``record``; False when the driver gives
    no binary or the folder is not writable."""
    try:
        binary = prg.get_info(cl.program_info.BINARIES)[0]
        kernels = {k.function_name: kernel_parameters(cl, k) for k in prg.all_kernels()}
    except (cl.Error, cl.RuntimeError, IndexError):
        return False
    return bool(binary) and program_store.write_record(record, bytes(binary), kernels)


def main() -> int:
    """Run the job on standard input (module docstring); returns the exit status."""
    job = json.load(sys.stdin)
    import pyopencl as cl   # here, not at the top: clisp.engine.programs imports this module before OpenCL starts
    device = cl.get_platforms()[job["platform"]].get_devices()[job["device"]]
    if device.name != job["device_name"]:
        return min(len(job["programs"]), 100)
    context = cl.Context([device])
    failed = 0
    for item in job["programs"]:
        try:
            build_and_keep(cl, context, item["source"], item["options"], Path(item["record"]))
        except cl.Error:
            failed += 1
    return min(failed, 100)


if __name__ == "__main__":
    sys.exit(main())
