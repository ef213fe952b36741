"""The ``clisp`` console script and ``python -m clisp``: for a command that runs on the OpenCL
device, the device is brought up on a thread (clisp.engine.device_start) while the command line
loads (clisp.app.cli, 0.2-0.6 s of imports) and reads its raw; then :func:`clisp.app.cli.console`."""
from __future__ import annotations

import os
import sys
from collections.abc import Sequence

DEVICE_COMMANDS = ("process", "demo")
"""Commands whose run needs the device (unless ``--backend reference``)."""


def uses_device(argv: Sequence[str]) -> bool:
    """Whether the command line ``argv`` (without the program name) runs on the OpenCL device.

    >>> uses_device(["process", "a.dng", "-o", "a.tif"]), uses_device(["process", "--backend", "reference", "a.dng"])
    (True, False)
    >>> uses_device(["info"]), uses_device([])
    (False, False)
    """
    command = next((a for a in argv if not a.startswith("-")), None)
    if command not in DEVICE_COMMANDS:
        return False
    pairs = zip(argv, list(argv[1:]) + [""])
    return not any(a == "--backend=reference" or (a == "--backend" and b == "reference") for a, b in pairs)


def console(argv: Sequence[str] | None = None) -> None:
    """Begin the device's bring-up where the command needs it, then run the command line."""
    arguments = list(sys.argv[1:] if argv is None else argv)
    if uses_device(arguments):
        from ..engine import device_start        # here: other commands never import pyopencl or ctypes
        from ..errors import ClispError          # here: with the line above
        try:
            device_start.begin(os.environ.get("CLISP_DEVICE"))
        except ClispError:
            pass                              # no pyopencl: the command says so when it needs the device
    from .cli import console as run_command_line
    run_command_line(arguments)
