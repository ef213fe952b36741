"""clisp's cache folder on disk and the fingerprint of the code that fills it.

What is kept there can always be recomputed: the binaries of built OpenCL programs
(clisp.engine.program_store), the chroma denoiser's noise calibrations
(clisp.modules.chroma_denoise.stage.calibrate_noise) and the device bytes of a pipeline's tiles
(clisp.engine.executor.Pipeline.tile_cost), each for one device and one clisp code. A missing,
damaged or unwritable cache only costs time.
"""
from __future__ import annotations

import hashlib
import json
import os
import tempfile
from pathlib import Path
from typing import Any

_FINGERPRINT: str | None = None


def cache_dir() -> Path:
    """clisp's cache folder: $CLISP_CACHE_DIR, else $XDG_CACHE_HOME/clisp, else ~/.cache/clisp
    (RuntimeError from Path.home() when there is no home folder)."""
    if os.environ.get("CLISP_CACHE_DIR"):
        return Path(os.environ["CLISP_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "clisp"


def code_fingerprint() -> str:
    """SHA-256 (hex) of the relative path, size and modification time of every ``.py``, ``.cl`` and
    ``.h`` file of the installed clisp package, computed once per process (about 1 ms: no file is
    read). Results cached on disk carry it, so an edited or reinstalled clisp never reads a result
    an older code computed; clisp's version alone does not change while it is developed."""
    global _FINGERPRINT
    if _FINGERPRINT is None:
        package = Path(__file__).resolve().parents[1]
        digest = hashlib.sha256()
        for root, dirs, files in os.walk(package):
            dirs[:] = sorted(d for d in dirs if d != "__pycache__")
            for name in sorted(files):
                if name.endswith((".py", ".cl", ".h")):
                    path = os.path.join(root, name)
                    st = os.stat(path)
                    digest.update(f"{os.path.relpath(path, package)}\0{st.st_size}\0{st.st_mtime_ns}\0".encode())
        _FINGERPRINT = digest.hexdigest()
    return _FINGERPRINT


def device_identity(platform: Any, device: Any) -> str:
    """The OpenCL platform and device as results kept for them are named: platform name and version,
    device name and version, driver version (a driver update invalidates them)."""
    return "\0".join([platform.name, platform.version, device.name, device.version, device.driver_version])


def entry_name(*parts: bytes | str) -> str:
    """A kept result's file name: the SHA-256 (hex) of ``parts`` and :func:`code_fingerprint`.

    >>> entry_name("a", b"b") == entry_name("a", b"b") != entry_name("ab")
    True
    """
    digest = hashlib.sha256(code_fingerprint().encode())
    for part in parts:
        digest.update(b"\0" + (part.encode() if isinstance(part, str) else part))
    return digest.hexdigest()


def read_json(kind: str, name: str) -> Any | None:
    """The JSON value kept as ``<cache>/<kind>/<name>.json``; None if missing, damaged or unreadable."""
    try:
        return json.loads((cache_dir() / kind / f"{name}.json").read_text())
    except (OSError, RuntimeError, ValueError):
        return None


def write_json(kind: str, name: str, value: Any) -> None:
    """Keep ``value`` as ``<cache>/<kind>/<name>.json`` (:func:`keep_bytes`)."""
    try:
        keep_bytes(cache_dir() / kind / f"{name}.json", json.dumps(value).encode())
    except (RuntimeError, TypeError, ValueError):
        pass


def keep_bytes(path: Path, data: bytes) -> bool:
    """Write ``data`` to ``path`` in the cache, atomically (a temporary file beside it, renamed into
    place, so a reader never sees half of it); False when the folder cannot be written (a cache that
    cannot keep a result only costs time)."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".partial-")
        with os.fdopen(fd, "wb") as out:
            out.write(data)
        os.replace(tmp, path)
        return True
    except OSError:
        return False
