"""The OpenCL device brought up on a thread while the command line loads and reads its raw.

A GPU driver's bring-up is slow and holds no Python work: on the H200 host of issue 41, NVIDIA's
OpenCL took 0.38 s to enumerate its platform and create a context, as long as all of clisp's
imports. pyopencl makes both calls with the GIL held, so a thread running them through pyopencl
would stall the imports it was meant to overlap. Here the two slow calls, ``clGetPlatformIDs``
(the ICD loader opens every vendor's driver) and ``clCreateContext``, go through ctypes, which
releases the GIL, on the very loader library pyopencl links; the device is chosen with
:func:`clisp.engine.runtime.choose_device` in between (cheap once the drivers are open), and the
context is handed to pyopencl (``Context.from_int_ptr``), whose :class:`~clisp.engine.runtime.Runtime`
takes it over (:func:`take`).

The thread imports nothing: :func:`begin` runs on the main thread after pyopencl's import, so two
threads never import at once. Whatever fails on the thread (no loader found, no device matching
``CLISP_DEVICE``) leaves nothing behind: the runtime then chooses and creates as it always does,
and reports the error itself.
"""
from __future__ import annotations

import ctypes
import os
import threading
from typing import Any

from .runtime import _import_cl, choose_device

_LOCK = threading.Lock()
_STARTED: dict[str, Any] = {}          # "spec", "thread", "result": the one bring-up of this process


def begin(spec: str | None) -> None:
    """Start bringing up the device ``spec`` (CLISP_DEVICE's syntax) on a daemon thread, once per
    process; :func:`take` collects it."""
    with _LOCK:
        if _STARTED:
            return
        cl = _import_cl()                                   # here, on the calling thread: the thread imports nothing
        thread = threading.Thread(target=_bring_up, args=(cl, spec), name="clisp-device-start", daemon=True)
        _STARTED.update(spec=spec, thread=thread, result=None)
        thread.start()


def take(spec: str | None) -> tuple[Any, Any, Any] | None:
    """(platform, device, context) that :func:`begin` brought up for ``spec``, waiting for it;
    None when nothing was begun, it failed, it was for another spec or it was taken already."""
    with _LOCK:
        if not _STARTED or _STARTED.get("taken"):
            return None
        _STARTED["taken"] = True
    _STARTED["thread"].join()
    result = _STARTED["result"]
    if result is None or _STARTED["spec"] != spec:
        return None
    return result


def _bring_up(cl: Any, spec: str | None) -> None:
    """The thread: drivers opened and the context created with the GIL released (ctypes)."""
    try:
        library = _loader()
        if library is not None:
            count = ctypes.c_uint32(0)
            library.clGetPlatformIDs(0, None, ctypes.byref(count))      # opens the vendors' drivers
        platform, device = choose_device(spec)
        _STARTED["result"] = (platform, device, _context(cl, library, device))
    except Exception:  # noqa: BLE001 - any failure here: the runtime tries again and says why (no traceback)
        _STARTED["result"] = None


def _context(cl: Any, library: Any, device: Any) -> Any:
    """A context of ``device``: created through ctypes when the loader was found, else by pyopencl."""
    if library is None:
        return cl.Context([device])
    create = library.clCreateContext
    create.restype = ctypes.c_void_p
    create.argtypes = [ctypes.c_void_p, ctypes.c_uint32, ctypes.POINTER(ctypes.c_void_p), ctypes.c_void_p,
                       ctypes.c_void_p, ctypes.POINTER(ctypes.c_int32)]
    devices = (ctypes.c_void_p * 1)(device.int_ptr)
    status = ctypes.c_int32(0)
    pointer = create(None, 1, devices, None, None, ctypes.byref(status))
    if status.value != 0 or not pointer:
        return cl.Context([device])
    return cl.Context.from_int_ptr(pointer, retain=False)


def _loader() -> Any | None:
    """The OpenCL ICD loader this process's pyopencl calls (ctypes), found among the libraries
    mapped into the process (Linux; pyopencl, imported by then, has mapped it); None elsewhere or
    when it is not found."""
    try:
        with open("/proc/self/maps") as maps:
            fields = [line.split() for line in maps]
    except OSError:
        return None
    paths = sorted({f[5] for f in fields if len(f) == 6 and os.path.basename(f[5]).startswith("libOpenCL")})
    for path in paths:
        try:
            return ctypes.CDLL(path)
        except OSError:
            continue
    return None
