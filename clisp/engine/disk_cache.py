"""clisp's cache folder on disk and the fingerprint of the code that fills it.

What is kept there can always be recomputed: the binaries of built OpenCL programs
(clisp.engine.program_store) and the chroma denoiser's noise calibrations
(clisp.modules.chroma_denoise.stage.calibrate_noise). A missing, damaged or unwritable cache only
costs time.
"""
from __future__ import annotations

import hashlib
import os
from pathlib import Path

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
