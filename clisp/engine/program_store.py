"""Built OpenCL programs kept on disk, so that a later process loads a binary instead of compiling.

A record is one file in ``<cache_dir>/programs/``, named by the SHA-256 of everything the binary
depends on (platform, device, driver, clisp's version, the program's full source and its build
flags). It holds the device binary (``clGetProgramInfo(CL_PROGRAM_BINARIES)``) and the parameters of
every kernel in it, because a program created from a binary need not answer
``clGetKernelArgInfo`` (OpenCL 1.2, section 5.9.3: only programs built from source with
``-cl-kernel-arg-info`` must).

Why clisp keeps binaries itself: pyopencl leaves caching to drivers that cache source builds, and
PoCL, which does, runs clang's preprocessor over the program and its built-in headers to find its
cache entry: about 20 ms per program on a 2-core Xeon, where loading the binary takes 2-5 ms.

File layout (all integers little-endian): ``CLSPPRG1``, the length of a UTF-8 JSON header (8
bytes), the header ``{"binary": <bytes>, "kernels": {name: [[param, type, pointer], ...]}}``, the
binary. A record that cannot be read or does not match is ignored (the program is built from
source and the record rewritten).
"""
from __future__ import annotations

import hashlib
import json
import struct
from pathlib import Path
from typing import Iterable, Mapping, Sequence

from .disk_cache import keep_bytes

MAGIC = b"CLSPPRG1"

KernelParameters = Mapping[str, Sequence[tuple[str, str, bool]]]
"""Per kernel name, its parameters as (name, OpenCL type name, is a pointer)."""


def record_name(parts: Iterable[str]) -> str:
    """The record's file name for the identifying texts ``parts`` (SHA-256, hex).

    >>> record_name(["a", "b"]) == record_name(["a", "b"]) != record_name(["ab"])
    True
    """
    return hashlib.sha256("\0".join(parts).encode()).hexdigest()


def write_record(path: Path, binary: bytes, kernels: KernelParameters) -> bool:
    """Write the record atomically (a temporary file renamed into place); False when the folder is
    not writable (a read-only cache only costs the next process a build)."""
    header = json.dumps({"binary": len(binary),
                         "kernels": {k: [list(p) for p in ps] for k, ps in kernels.items()}}).encode()
    return keep_bytes(path, MAGIC + struct.pack("<Q", len(header)) + header + binary)


def read_record(path: Path) -> tuple[bytes, dict[str, tuple[tuple[str, str, bool], ...]]] | None:
    """(binary, kernel parameters) of the record at ``path``; None if it is missing or damaged."""
    try:
        data = path.read_bytes()
    except OSError:
        return None
    head = len(MAGIC) + 8
    if len(data) < head or data[:len(MAGIC)] != MAGIC:
        return None
    (size,) = struct.unpack("<Q", data[len(MAGIC):head])
    try:
        header = json.loads(data[head:head + size])
        binary = data[head + size:]
        if len(binary) != header["binary"] or not binary:
            return None
        kernels = {str(k): tuple((str(n), str(t), bool(p)) for n, t, p in ps) for k, ps in header["kernels"].items()}
    except (ValueError, KeyError, TypeError):
        return None
    return binary, kernels
