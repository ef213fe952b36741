"""The OpenCL programs of one runtime: built once per process, kept on disk, built in parallel.

:class:`Programs` belongs to :class:`clisp.engine.runtime.Runtime` (the one owner of the context);
stages reach it through the runtime's ``program``, ``kernel`` and ``launch_named``. A program is
``<name>.cl`` of a stage folder with ``-D`` defines and optional host-generated text. Asked for:

1. in this process before: the same object;
2. built by an earlier process: loaded from its record (clisp.engine.program_store: the binary and
   the kernels' parameters; 2-5 ms on PoCL, where a source build that PoCL finds in its own cache
   still costs about 20 ms of preprocessing);
3. during a metering run (:meth:`collecting`): only noted; when the metering run ends,
   :meth:`build_wanted` builds every noted program at once, on PoCL shared out over helper
   processes (clisp.engine.program_builder) so that all cores compile;
4. otherwise: compiled from source, with a one-line notice on a terminal the first time this
   machine builds it.

A program compiled here is kept on disk: at once where the driver's binary is cheap, else when the
command ends (:meth:`save`; see :attr:`Programs.cheap_binaries`).
"""
from __future__ import annotations

import json
import re
import sys
import warnings
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Iterator

from . import program_store
from .disk_cache import cache_dir, device_identity
from .profile import host_timer
from .program_builder import build_and_keep, keep, kernel_parameters
from . import host_threads
from .host_threads import usable_cores as _usable_cores
from ..errors import ClispError
from ..version import __version__

if TYPE_CHECKING:
    import subprocess

BUILD_OPTIONS = ["-cl-std=CL1.2", "-cl-kernel-arg-info"]
"""Every program's build options besides its defines: OpenCL 1.2 (PoCL and GPU drivers alike), and
the parameters' names kept for launches by name (no effect on the code)."""

FIRST_BUILD_NOTICE = "clisp: compiling OpenCL kernels for {device} (first run only)..."
"""Printed once per process (on a terminal's stderr) when a program is built that this machine has not
built before for this device and clisp version: the compiler's cost, seconds per program on a CPU
device, is then the run's largest part."""

STDERR = object()
"""Programs.notice_stream's default: whatever ``sys.stderr`` is when a notice is due."""

MAX_HELPERS = 7
"""Most helper processes of one parallel build (each costs an interpreter, pyopencl and a context,
about 0.25 s of a core and 100 MB)."""

Key = tuple[str, tuple[str, ...]]
"""A program's key: (name, its -D flags followed by the generated text)."""


# -- sources ------------------------------------------------------------------------------
def kernel_sources() -> dict[str, Path]:
    """Every OpenCL source file of the package by file name: the programs ``<name>.cl`` and the
    headers ``*.h`` of the stage folders ``clisp/modules/<module>/``, of ``clisp/engine/`` and of
    ``clisp/scene/`` (the statistics pass; ``common.h`` is in ``clisp/modules/common/``). A program
    is named by its file's stem, which is its module's name, e.g. ``highlights`` ->
    ``clisp/modules/highlights/highlights.cl``."""
    global _SOURCES
    if _SOURCES is None:
        package = Path(__file__).resolve().parents[1]             # clisp/ (this file is clisp/engine/)
        found = [*package.glob("modules/*/*.cl"), *package.glob("modules/*/*.h"), *package.glob("engine/*.cl"),
                 *package.glob("engine/*.h"),
                 *package.glob("scene/*.cl")]
        _SOURCES = {path.name: path for path in sorted(found)}
        if "common.h" not in _SOURCES:
            raise ClispError(f"OpenCL kernel sources not found in {package}; reinstall clisp")
    return _SOURCES


_SOURCES: dict[str, Path] | None = None


def with_headers(text: str) -> str:
    """``text`` with each line ``#include "name.h"`` replaced by that header's text (kernel_path), so
    that the program cache and PoCL's own cache see every source they compile (no -I path)."""
    return _INCLUDE.sub(lambda m: kernel_path(m.group(1)).read_text(), text)


_INCLUDE = re.compile(r'^#include "([\w.]+\.h)"[ \t]*$', re.MULTILINE)


def kernel_path(file_name: str) -> Path:
    """Path of the OpenCL source ``file_name`` (``highlights.cl``, ``srgb.h``); ClispError if none."""
    sources = kernel_sources()
    if file_name not in sources:
        raise ClispError(f"kernel source {file_name} not found in clisp/modules/*/, clisp/engine/ or clisp/scene/")
    return sources[file_name]


ParameterInfo = tuple[str, str, bool]
"""A kernel parameter as the compiler reports it: (name, OpenCL type name, is a pointer)."""


@dataclass(frozen=True)
class Wanted:
    """A program noted during a metering run: its name, flags and generated text (what
    :meth:`Programs.get` takes), its file, full source and record."""

    name: str
    flags: tuple[str, ...]
    generated: str
    path: Path
    source: str
    record: Path


class Programs:
    """Program cache of one context (module docstring)."""

    def __init__(self, cl: Any, context: Any, platform: Any, device: Any) -> None:
        self.cl, self.context, self.platform, self.device = cl, context, platform, device
        self.built: dict[Key, Any] = {}
        """Programs of this process by key."""
        self.signatures: dict[tuple[str, tuple[str, ...], str], tuple[ParameterInfo, ...]] = {}
        self.notice_stream: Any = STDERR
        """Where the first-build notice goes (only when it is a terminal): STDERR (the process's
        stderr when the notice is due, which may have been replaced since), a stream, or None."""
        self.noticed = False
        self.cheap_binaries = "portable computing language" not in platform.name.lower()
        """Whether asking the driver for a program's binary costs nothing more. PoCL first compiles
        the generic work-group function of every kernel in the program (clGetProgramInfo). With
        POCL_WORK_GROUP_SPECIALIZATION=0 that is the function a launch runs, so asked for when the
        command ends (:meth:`save`) only the kernels this process did not launch cost more (0.3-0.5 s
        after a first run of a 0.25 MP raw on 2 Xeon cores); asked for right after the build, it
        would compile them all before the run needs them."""
        self._unsaved: dict[Key, tuple[Path, Any]] = {}
        self._wanted: dict[Key, Wanted] | None = None

    # -- asking ---------------------------------------------------------------------------
    def get(self, name: str, flags: tuple[str, ...], generated: str) -> Any | None:
        """The program ``<name>.cl`` with ``flags`` and ``generated`` text (module docstring); None
        while collecting, for a program that is only noted."""
        key = (name, flags + (generated,))
        prg = self.built.get(key)
        if prg is not None:
            return prg
        path, source = _program_source(name, generated)
        record = self.record_path(source, flags)
        if self._wanted is not None and record is not None:     # loaded or built with the others at the end
            self._wanted.setdefault(key, Wanted(name, flags, generated, path, source, record))
            return None
        with host_timer("load kept programs (start-up)"), warnings.catch_warnings():
            warnings.simplefilter("ignore")                   # pyopencl warns on non-empty build logs
            prg = self._load(record, key, flags) if record is not None else None
        if prg is None:
            if record is None or not record.exists():
                self.first_build_notice()
            with host_timer("build programs (a first run)"):
                prg = self._build(path, source, flags)
            if record is not None:
                self._keep_later(key, record, prg)
        self.built[key] = prg
        return prg

    def signature(self, name: str, flags: tuple[str, ...], generated: str, kernel_name: str) -> tuple[ParameterInfo, ...]:
        """The parameters of ``kernel_name`` in that program (a loaded record brings them)."""
        key = (name, flags + (generated,), kernel_name)
        if key not in self.signatures:
            prg = self.get(name, flags, generated)
            if key not in self.signatures:
                self.signatures[key] = tuple(kernel_parameters(self.cl, self.cl.Kernel(prg, kernel_name)))
        return self.signatures[key]

    # -- collecting and building at once -------------------------------------------------------
    @contextmanager
    def collecting(self) -> Iterator[None]:
        """Within the block, programs not built yet are noted, not built (:meth:`get` returns None);
        at its end they are built at once (:meth:`build_wanted`)."""
        if self._wanted is not None:
            raise RuntimeError("collecting does not nest")
        self._wanted = {}
        try:
            yield
        finally:
            wanted, self._wanted = self._wanted, None
        self.build_wanted(wanted)

    def build_wanted(self, wanted: dict[Key, Wanted]) -> None:
        """Build the ``wanted`` programs: on PoCL with more than one core and program, shared out over
        helper processes (clisp.engine.program_builder) and this one, longest sources first, each
        to the least loaded; the helpers' programs are then loaded from their records (a program a
        helper left out is built here)."""
        todo = self._load_kept([(key, w) for key, w in wanted.items() if key not in self.built])
        if not todo:
            return
        self.first_build_notice()
        helpers = min(MAX_HELPERS, _usable_cores() - 1, len(todo) - 1)
        if self.cheap_binaries or helpers < 1:
            for _, w in todo:
                self.get(w.name, w.flags, w.generated)
            return
        shares: list[list[tuple[Key, Wanted]]] = [[] for _ in range(helpers + 1)]
        loads = [0] * (helpers + 1)
        for key, w in sorted(todo, key=lambda item: -len(item[1].source)):
            i = loads.index(min(loads))
            shares[i].append((key, w))
            loads[i] += len(w.source)
        started = [self._start_helper(share) for share in shares[1:] if share]
        try:
            for key, w in shares[0]:
                try:
                    prg = build_and_keep(self.cl, self.context, w.source, list(w.flags) + BUILD_OPTIONS, w.record)
                except self.cl.Error as exc:
                    raise ClispError(f"OpenCL build of {w.path.name} failed on {self.device.name.strip()}:\n{exc}") from exc
                self.built[key] = prg
        except BaseException:
            for process in started:                          # a failed build or Ctrl-C: no helper outlives it
                if process is not None:
                    process.kill()
            raise
        finally:
            for process in started:
                if process is not None:
                    process.wait()
        for share in shares[1:]:
            for _, w in share:
                self.get(w.name, w.flags, w.generated)       # the helper's record, else built here

    def _load_kept(self, todo: list[tuple[Key, Wanted]]) -> list[tuple[Key, Wanted]]:
        """Load the programs of ``todo`` that have a record, on the host's threads (the driver's
        clBuildProgram of a binary releases the GIL); returns those left to build."""
        kept = [(key, w) for key, w in todo if w.record.exists()]
        with host_timer("load kept programs (start-up)"), warnings.catch_warnings():
            warnings.simplefilter("ignore")       # here: catch_warnings is not for threads (one process-wide filter)
            loaded = host_threads.map_items(lambda item: self._load(item[1].record, item[0], item[1].flags), kept)
        for (key, _), prg in zip(kept, loaded):
            if prg is not None:
                self.built[key] = prg
        return [(key, w) for key, w in todo if key not in self.built]

    def _start_helper(self, share: list[tuple[Key, Wanted]]) -> subprocess.Popen | None:
        """A helper process building ``share`` (None when it cannot start: this process builds it)."""
        import subprocess      # here: only a first build starts helpers (3 ms of every start-up otherwise)
        pi, di = _device_index(self.cl, self.platform, self.device)
        job = {"platform": pi, "device": di, "device_name": self.device.name,
               "programs": [{"record": str(w.record), "source": w.source, "options": list(w.flags) + BUILD_OPTIONS}
                            for _, w in share]}
        try:
            process = subprocess.Popen([sys.executable, "-m", "clisp.engine.program_builder"], stdin=subprocess.PIPE,
                                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            assert process.stdin is not None
            process.stdin.write(json.dumps(job).encode())
            process.stdin.close()
        except OSError:
            return None
        return process

    # -- records ------------------------------------------------------------------------------
    def record_path(self, source: str, flags: tuple[str, ...]) -> Path | None:
        """The file in :func:`cache_dir` that keeps this program's binary (clisp.engine.program_store):
        named by the device, its driver, clisp's version, the source and the flags. None without a
        home folder."""
        name = program_store.record_name([device_identity(self.platform, self.device), __version__, source,
                                          *flags, *BUILD_OPTIONS])
        try:
            return cache_dir() / "programs" / name
        except RuntimeError:                               # Path.home() without a home
            return None

    def _load(self, record: Path, key: Key, flags: tuple[str, ...]) -> Any | None:
        """The program built from the binary in ``record``, its kernels' parameters noted; None when
        the record is missing, damaged or refused by the driver. Callers silence pyopencl's build-log
        warnings (catch_warnings is one process-wide filter, not for threads: _load_kept)."""
        found = program_store.read_record(record)
        if found is None:
            return None
        binary, kernels = found
        options = list(flags) + BUILD_OPTIONS
        try:
            prg = self.cl.Program(self.context, [self.device], [binary]).build(options=options)
        except (self.cl.Error, ValueError):
            return None
        for kernel_name, params in kernels.items():
            self.signatures[(key[0], key[1], kernel_name)] = tuple(params)
        return prg

    def _build(self, path: Path, source: str, flags: tuple[str, ...]) -> Any:
        """Compile ``source`` (the text of ``path`` with its headers) with ``flags``."""
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # pyopencl warns on non-empty build logs
                return self.cl.Program(self.context, source).build(options=list(flags) + BUILD_OPTIONS)
        except self.cl.Error as exc:
            raise ClispError(f"OpenCL build of {path.name} failed on {self.device.name.strip()}:\n{exc}") from exc

    def _keep_later(self, key: Key, record: Path, prg: Any) -> None:
        """Keep ``prg`` in ``record`` now where that is cheap, else at :meth:`save`."""
        if self.cheap_binaries:
            keep(self.cl, prg, record)
        else:
            self._unsaved[key] = (record, prg)

    def save(self) -> int:
        """Keep the binaries of the programs this process compiled and has not kept yet, so that
        later processes load them; returns how many were written. The CLI calls it when a command
        ends (clisp.engine.runtime.save_built_programs), the warm-up when it is done."""
        kept = 0
        while self._unsaved:
            _, (record, prg) = self._unsaved.popitem()
            kept += keep(self.cl, prg, record)
        return kept

    # -- the notice ---------------------------------------------------------------------------
    def first_build_notice(self) -> None:
        """:data:`FIRST_BUILD_NOTICE`, once per runtime, when ``notice_stream`` is an open terminal."""
        stream = sys.stderr if self.notice_stream is STDERR else self.notice_stream
        if self.noticed or stream is None:
            return
        try:
            if not stream.isatty():
                return
            self.noticed = True
            print(FIRST_BUILD_NOTICE.format(device=self.device.name.strip()), file=stream, flush=True)
        except (AttributeError, ValueError, OSError):      # no isatty, a closed or broken stream
            return


def _program_source(name: str, generated: str) -> tuple[Path, str]:
    """(path of ``<name>.cl``, the program's full text: common.h, ``generated``, the file with its
    headers inlined)."""
    path = kernel_path(f"{name}.cl")
    try:
        return path, "\n".join([kernel_path("common.h").read_text(), generated, with_headers(path.read_text())])
    except OSError as exc:
        raise ClispError(f"kernel source {path} cannot be read: {exc}") from exc


def _device_index(cl: Any, platform: Any, device: Any) -> tuple[int, int]:
    """(platform index, device index) of ``device`` in cl.get_platforms() order."""
    for pi, p in enumerate(cl.get_platforms()):
        if p == platform:
            for di, d in enumerate(p.get_devices()):
                if d == device:
                    return pi, di
    raise ClispError(f"OpenCL device {device.name.strip()} not found among the platforms")
