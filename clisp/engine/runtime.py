"""The one place that owns OpenCL: device choice, context, queue, program cache and buffer pool.

Stages never create contexts; they ask the process-wide :func:`get_runtime` for kernels and buffers.

Device choice (``CLISP_DEVICE``):
    unset          a GPU if any platform has one, else a CPU device, preferring PoCL
    ``gpu``/``cpu`` the first device of that type
    ``P`` or ``P:D`` platform index P (and device index D), as listed by ``clisp info --device``
    any other text the first device whose platform or device name contains it (case-insensitive)
"""
from __future__ import annotations

import bisect
import os
import sys
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Iterator, Mapping

import numpy as np

from . import host_threads, profile
from .programs import Programs, kernel_path
from ..errors import ClispError

LOCAL_SIZE = (32, 4)
"""Work-group shape (x, y) for 2-D image kernels; global sizes are rounded up to it and kernels
bounds-check. 32 along x keeps reads coalesced on GPUs and gives PoCL a vectorisable inner loop."""


POCL_DEFAULTS = {"POCL_WORK_GROUP_SPECIALIZATION": "0"}
"""PoCL settings clisp sets unless the environment already has them (read when OpenCL starts).

``POCL_WORK_GROUP_SPECIALIZATION=0``: PoCL compiles one generic work-group function per kernel (any
work-group size and global offset), not one per work-group size and one more per global offset
(launch_exact launches a kernel's main block at offset 0 and its ragged strips at other offsets);
it is also the function a program's binary holds (clisp.engine.programs). On 2 Intel Xeon cores with empty caches the
first ``clisp process`` of a 24 MP Bayer DNG (quality) took 12.4 s against 20.3 s, a 0.26 MP one
6.6 s against 13.1 s; warm runs of the same DNG 4.36-4.65 s against 4.46-4.55 s, of a 24 MP LMS
DNG 6.6-7.2 s against 6.4-6.8 s (docs/RESULTS.md, issue 29)."""


def _import_cl() -> Any:
    for name, value in POCL_DEFAULTS.items():
        os.environ.setdefault(name, value)
    try:
        import pyopencl as cl    # deferred: OpenCL starts on first use, not at `import clisp`
    except ImportError as exc:  # pragma: no cover - dependency missing
        raise ClispError("pyopencl is not installed; run: pip install pyopencl pocl-binary-distribution") from exc
    return cl


def list_devices() -> list[tuple[int, int, Any, Any]]:
    """All (platform index, device index, platform, device) visible to OpenCL."""
    cl = _import_cl()
    try:
        platforms = cl.get_platforms()
    except cl.Error as exc:
        raise ClispError(f"no OpenCL platform found ({exc}); install pocl-binary-distribution") from exc
    found = []
    for pi, platform in enumerate(platforms):
        try:
            devices = platform.get_devices()
        except cl.Error:
            continue
        for di, device in enumerate(devices):
            found.append((pi, di, platform, device))
    if not found:
        raise ClispError("no OpenCL device found; install pocl-binary-distribution (CPU) or a GPU driver")
    return found


def choose_device(spec: str | None = None) -> tuple[Any, Any]:
    """Pick (platform, device) by ``spec`` (see module docstring); raises ClispError if nothing matches."""
    cl = _import_cl()
    found = list_devices()
    spec = (spec or "").strip()
    if not spec:
        gpus = [f for f in found if f[3].type & cl.device_type.GPU]
        if gpus:
            return gpus[0][2], gpus[0][3]
        cpus = [f for f in found if f[3].type & cl.device_type.CPU]
        pocl = [f for f in cpus if "portable" in f[2].name.lower() or "pocl" in f[2].vendor.lower()]
        pick = (pocl or cpus or found)[0]
        return pick[2], pick[3]
    if spec.lower() in ("gpu", "cpu"):
        kind = cl.device_type.GPU if spec.lower() == "gpu" else cl.device_type.CPU
        match = [f for f in found if f[3].type & kind]
    elif spec.replace(":", "").isdigit():
        try:
            parts = [int(v) for v in spec.split(":")]
        except ValueError as exc:
            raise ClispError(f"CLISP_DEVICE={spec!r} is not P or P:D (platform and device index)") from exc
        match = [f for f in found if f[0] == parts[0] and (len(parts) == 1 or f[1] == parts[1])]
    else:
        key = spec.lower()
        match = [f for f in found if key in f[2].name.lower() or key in f[3].name.lower()]
    if not match:
        names = "; ".join(f"{p}:{d} {pl.name} / {dev.name}" for p, d, pl, dev in found)
        raise ClispError(f"CLISP_DEVICE={spec!r} matches no OpenCL device (available: {names})")
    return match[0][2], match[0][3]


def _define_flags(defines: Mapping[str, Any]) -> list[str]:
    flags = []
    for key, value in sorted(defines.items()):
        if isinstance(value, float):
            value = repr(float(value)) + "f"
        flags.append(f"-D{key}={value}")
    return flags


SCALARS = {"int": np.int32, "uint": np.uint32, "float": np.float32, "short": np.int16, "ushort": np.uint16,
           "char": np.int8, "uchar": np.uint8, "long": np.int64, "ulong": np.uint64}
"""NumPy types of the OpenCL scalar parameter types a launch converts to."""


@dataclass(frozen=True)
class Parameter:
    """A kernel parameter: its name, OpenCL type name ('float*', 'int', ...) and whether it is a
    pointer (global or constant memory)."""

    name: str
    type_name: str
    pointer: bool

    def convert(self, value: Any) -> Any:
        """``value`` as the kernel takes it: a DeviceImage's buffer, a scalar as the declared type."""
        if self.pointer:
            return value.buffer if isinstance(value, DeviceImage) else value
        scalar = SCALARS.get(self.type_name)
        return value if scalar is None else scalar(value)


def _conversions(params: tuple[Parameter, ...]) -> tuple[tuple[int, ...], tuple[tuple[int, Any, bool], ...]]:
    """(indices of the pointer parameters, (index, NumPy type, whether a Python int passes as it is)
    of the typed scalars): Parameter.convert's work split by kind, so that a launch by name does it
    inline. An integer parameter takes a Python int as it is (the kernel's scalar types are set, so
    pyopencl packs it as that type, with the range check NumPy's conversion makes); a float one
    converts every value (a finite value beyond float32's range becomes inf there, where packing it
    would raise)."""
    pointers = tuple(i for i, p in enumerate(params) if p.pointer)
    scalars = tuple((i, SCALARS[p.type_name], np.dtype(SCALARS[p.type_name]).kind in "iu")
                    for i, p in enumerate(params) if not p.pointer and p.type_name in SCALARS)
    return pointers, scalars


@dataclass
class DeviceImage:
    """A planar float32 (or raw-typed) image on the device: ``channels`` planes of ``height x width``."""

    buffer: Any
    channels: int
    height: int
    width: int
    dtype: np.dtype
    interleaved: bool = False
    capacity: int = 0           # bytes of ``buffer`` (at least nbytes: pooled buffers are reused larger)
    host: np.ndarray | None = None   # the host array that is the buffer's storage (Runtime.host_image)
    staging: np.ndarray | None = None   # a staging buffer it was filled from (Runtime.resident_mosaic)
    pooled: bool = True         # False: a buffer of its own (Runtime.upload on a CPU device), dropped on release

    @property
    def nbytes(self) -> int:
        return self.channels * self.height * self.width * np.dtype(self.dtype).itemsize


class Runtime:
    """OpenCL context, in-order queue, program cache and buffer pool for one device."""

    def __init__(self, spec: str | None = None, profiling: bool = False) -> None:
        cl = _import_cl()
        self.cl = cl
        spec = spec if spec is not None else os.environ.get("CLISP_DEVICE")
        started = sys.modules.get("clisp.engine.device_start")      # the CLI's bring-up on a thread, if begun
        prepared = started.take(spec) if started is not None else None
        if prepared is not None:
            self.platform, self.device, self.context = prepared
        else:
            self.platform, self.device = choose_device(spec)
            self.context = cl.Context([self.device])
        self.profiling = profiling
        props = cl.command_queue_properties.PROFILING_ENABLE if profiling else 0
        self.queue = cl.CommandQueue(self.context, properties=props)
        self.programs = Programs(cl, self.context, self.platform, self.device)
        self._kernels: dict[tuple[str, tuple[str, ...], str], Any] = {}
        self._signatures: dict[tuple[str, tuple[str, ...], str], tuple[Parameter, ...]] = {}
        self._launchers: dict[tuple, tuple] = {}   # launch_named's kernel, names and conversions
        self._flag_cache: dict[tuple, tuple[str, ...]] = {}
        self.pool = BufferPool(lambda n: cl.Buffer(self.context, cl.mem_flags.READ_WRITE, n))
        self._constants: dict[tuple[str, tuple[int, ...], bytes], Any] = {}
        self._meter: BufferPool | None = None
        self._pool_for: Any = None               # trim_pool's ``keep`` of the last run
        self.host_unified = bool(self.device.host_unified_memory)
        # the host's own CPU: a USE_HOST_PTR buffer it writes is the array itself (settle_host_image)
        self.host_is_device = bool(self.device.type & cl.device_type.CPU)
        self._transfer_queue: Any = None
        self.staging = HostStaging(self)
        self._counters: dict[str, tuple[Any, np.ndarray | None]] = {}   # buffer, host storage (CPU)

    def enable_profiling(self) -> None:
        """Switch to a queue with event profiling (same context, so every buffer stays valid);
        kernels are re-wrapped so that their launches are recorded (clisp.engine.profile)."""
        if not self.profiling:
            self.finish()
            self.queue = self.cl.CommandQueue(self.context,
                                              properties=self.cl.command_queue_properties.PROFILING_ENABLE)
            self._transfer_queue = None
            self.profiling = True
            self._kernels.clear()
            self._launchers.clear()

    @property
    def transfer_queue(self) -> Any:
        """The queue of uploads and downloads between tiles: on a device that shares host memory
        the compute queue itself (a copy is the same cores' memcpy); on a discrete device a second
        in-order queue, so that a window's upload and a result's download overlap the kernels of
        another tile (the DMA engines run beside the compute units). Kernels are only ever
        enqueued on :attr:`queue`, from one thread: a ``cl.Kernel``'s arguments are state, and one
        kernel object shared by two queues or threads would race."""
        if self.host_unified:
            return self.queue
        if self._transfer_queue is None:
            props = self.cl.command_queue_properties.PROFILING_ENABLE if self.profiling else 0
            self._transfer_queue = self.cl.CommandQueue(self.context, properties=props)
        return self._transfer_queue

    def finish(self) -> None:
        """Wait until every command of both queues has completed."""
        self.queue.finish()
        if self._transfer_queue is not None:
            self._transfer_queue.finish()

    def _behind_compute(self) -> list[Any] | None:
        """For a copy of the transfer queue into a pooled buffer: a marker of the compute queue
        (flushed), so that the copy waits for every kernel already enqueued, among them the last
        users of a buffer the pool hands out again (the pool takes a buffer back once its kernels
        are enqueued, not done); None where the compute queue does the copies itself (README.md:
        the race it closes)."""
        if self.transfer_queue is self.queue:
            return None
        marker = self.cl.enqueue_marker(self.queue)
        self.queue.flush()
        return [marker]

    def _after(self, event: Any) -> None:
        """Make the compute queue's next commands wait for ``event`` (of the transfer queue)."""
        if self.transfer_queue is not self.queue:
            self.cl.enqueue_barrier(self.queue, wait_for=[event])

    def describe(self) -> str:
        """One line naming platform and device, e.g. for ``clisp info --device``."""
        d = self.device
        return (f"{self.platform.name} ({self.platform.version}) / {d.name.strip()}, "
                f"{d.max_compute_units} compute units, {d.global_mem_size / 2**30:.1f} GiB")

    # -- programs -------------------------------------------------------------------------
    def _flags(self, defines: Mapping[str, Any] | None) -> tuple[str, ...]:
        """The ``-D`` options of ``defines`` (sorted by name), memoised on the defines' items: a
        launch by name looks its program up twice, and formatting 20 defines each time was most of
        its host cost."""
        if not defines:
            return ()
        try:
            key = tuple(defines.items())
            flags = self._flag_cache.get(key)
        except TypeError:                                # an unhashable value: format it each time
            return tuple(_define_flags(defines))
        if flags is None:
            flags = self._flag_cache[key] = tuple(_define_flags(defines))
        return flags

    def program(self, name: str, defines: Mapping[str, Any] | None = None, generated: str = "") -> Any:
        """The program ``<name>.cl`` (clisp.engine.programs.kernel_path) with ``-D`` defines, built once
        per process, loaded from disk when an earlier process built it (clisp.engine.programs).

        ``generated``: host-generated source (e.g. a filter's weights as literals) placed before
        the file's text; part of the cache key. None during a metering run for a program that is
        only noted (built when the metering run ends).
        """
        return self.programs.get(name, self._flags(defines), generated)

    def save_programs(self) -> int:
        """Keep the binaries of the programs this process compiled (clisp.engine.programs.Programs.save)."""
        return self.programs.save()

    def header(self, name: str) -> str:
        """Text of the header ``name`` (e.g. ``srgb.h``, for host-generated program text)."""
        path = kernel_path(name)
        try:
            return path.read_text()
        except OSError as exc:
            raise ClispError(f"kernel source {path} cannot be read: {exc}") from exc

    def kernel(self, name: str, kernel_name: str, defines: Mapping[str, Any] | None = None,
               generated: str = "") -> Any:
        """A cached kernel object of the program ``<name>.cl`` (see :meth:`program`)."""
        flags = self._flags(defines)
        key = (name, flags + (generated,), kernel_name)
        if key not in self._kernels:
            if self._meter is not None:
                self.program(name, defines, generated)          # built or noted: nothing launches
                kernel = _skipped_launch
            else:
                kernel = self.cl.Kernel(self.program(name, defines, generated), kernel_name)
                kernel.set_scalar_arg_dtypes(self.scalar_dtypes(name, kernel_name, defines, generated))
                if self.profiling:
                    kernel = _ProfiledKernel(kernel, kernel_name)
            self._kernels[key] = kernel
        return self._kernels[key]

    def signature(self, name: str, kernel_name: str, defines: Mapping[str, Any] | None = None,
                  generated: str = "") -> tuple["Parameter", ...]:
        """The parameters of ``kernel_name`` in the program ``<name>.cl`` as the compiler reads them
        (macros expanded): name, type and whether it is a pointer; cached per build."""
        flags = self._flags(defines)
        key = (name, flags + (generated,), kernel_name)
        if key not in self._signatures:
            self._signatures[key] = tuple(Parameter(*p) for p in
                                          self.programs.signature(name, flags, generated, kernel_name))
        return self._signatures[key]

    def scalar_dtypes(self, name: str, kernel_name: str, defines: Mapping[str, Any] | None = None,
                      generated: str = "") -> list[Any]:
        """Per parameter of ``kernel_name``, the NumPy type its scalar value is packed as (None for a
        pointer or a type SCALARS does not name): set on every kernel object (pyopencl's
        ``set_scalar_arg_dtypes``), so a launch packs its scalars with one struct call. Untyped, pyopencl
        converts each scalar through the buffer protocol: 26-35 us per launch of a three-argument
        kernel on PoCL against 3-5 us typed (engine README)."""
        return [None if p.pointer else SCALARS.get(p.type_name)
                for p in self.signature(name, kernel_name, defines, generated)]

    def launch_named(self, name: str, kernel_name: str, width: int, height: int, args: Mapping[str, Any],
                     defines: Mapping[str, Any] | None = None, generated: str = "",
                     group: tuple[int, int] | None = None, x0: int = 0, exact: bool = True,
                     inward: bool = False, depth: int = 1) -> None:
        """Enqueue ``kernel_name`` of the program ``<name>.cl`` over exactly width x height outputs
        (:func:`launch_exact`; ``exact`` False: rounded up to LOCAL_SIZE, :meth:`launch`, for kernels
        that check their bounds; ``inward``: launch_exact's one launch, for kernels that take their
        coordinates from common.h's inward_id; ``depth``: that many work-groups along a third
        index, one deep, for the steps of a kernel that runs several at once, the step its
        get_group_id(2)) with its arguments by name: ``args`` maps every parameter's name to
        its value, a DeviceImage or buffer for a pointer (a DeviceImage passes its buffer), a
        Python or NumPy number for a scalar (converted to the declared type). A missing or unknown
        name is a ClispError naming them. For example (clisp/modules/highlights/stage.py)::

            rt.launch_named("highlights", "hl_near", w1, h1, dict(rows=rows, dst=near, w1=w1, h1=h1,
                            reach=reach, nbx=nbx, nby=nby), defines)
        """
        if self._meter is not None:
            self.program(name, defines, generated)              # built or noted: nothing launches
            return
        recording = profile.active()
        start = time.perf_counter() if recording is not None else 0.0
        flags = self._flags(defines)
        key = (name, flags, generated, kernel_name)
        launcher = self._launchers.get(key)
        if launcher is None:                     # resolved once per program, defines and kernel
            params = self.signature(name, kernel_name, defines, generated)
            launcher = self._launchers[key] = (self.kernel(name, kernel_name, defines, generated),
                                               tuple(p.name for p in params), *_conversions(params))
        kernel, names, pointers, scalars = launcher
        try:
            values = [args[n] for n in names]
        except KeyError:
            values = None
        if values is not None:                   # Parameter.convert, inline (a quality call has 500 arguments)
            for i in pointers:
                if type(values[i]) is DeviceImage:
                    values[i] = values[i].buffer
            for i, scalar, takes_int in scalars:
                if not (takes_int and type(values[i]) is int):
                    values[i] = scalar(values[i])
        if values is None or len(args) != len(names):
            missing, unknown = [n for n in names if n not in args], [n for n in args if n not in names]
            raise ClispError(f"{name}.cl {kernel_name}: missing arguments {missing}, unknown {unknown}")
        if exact:
            launch_exact(self, kernel, width, height, *values, group=group or WORK_GROUP, x0=x0, inward=inward,
                         depth=depth)
        else:
            self.launch(kernel, width, height, *values, depth=depth)
        if recording is not None:
            recording.named(time.perf_counter() - start)

    # -- buffers --------------------------------------------------------------------------
    def acquire(self, channels: int, height: int, width: int, dtype: Any = np.float32) -> DeviceImage:
        """A device image from the pool: the smallest released buffer that is large enough, else
        a new one (see BufferPool)."""
        nbytes = max(1, channels * height * width * np.dtype(dtype).itemsize)
        pool = self._meter if self._meter is not None else self.pool
        buf, capacity = pool.acquire(nbytes)
        pending = pool.pending.pop(id(buf), None)
        if pending is not None:                  # a download of the transfer queue still reads it
            self._after(pending)
        return DeviceImage(buf, channels, height, width, np.dtype(dtype), capacity=capacity)

    def release(self, image: DeviceImage, after: Any = None) -> None:
        """Return a device image's buffer to the pool (a host image's is not pooled: dropped; a
        staged mosaic gives its staging buffer back). ``after``: an event of the transfer queue
        that still reads the buffer (a download): whoever acquires it next waits for it on the
        device (:meth:`acquire`), never on the host."""
        if image.staging is not None:
            self.staging.give(image.staging)
            image.staging = None
        if image.host is not None or not image.pooled:
            return
        pool = self._meter if self._meter is not None else self.pool
        if after is not None and self.transfer_queue is not self.queue:
            pool.pending[id(image.buffer)] = after
        pool.release(image.buffer, image.capacity)

    def trim_pool(self, keep: Any = None) -> None:
        """Free every pooled buffer not in use (before a run whose tiles have other sizes, so that
        the pool holds what this run needs and no more). Only when no queued work uses them.
        ``keep``: what the run's buffers depend on (its schedule and window shape): when it equals
        the last run's, the pool already holds exactly what the run needs, and is kept (a 0.26 MP
        call then reuses its buffers instead of faulting in fresh pages)."""
        if keep is not None and keep == self._pool_for:
            return
        self.finish()
        self.pool.trim()
        self._pool_for = keep

    @contextmanager
    def metering(self) -> Iterator["BufferPool"]:
        """Within the block nothing is allocated or run: acquire/release act on a simulated pool
        (empty at the start, same policy as the real one) and every kernel launch is skipped. A
        pipeline's tile enqueued here measures exactly the device buffers that tile would create
        from an empty pool (.created, .largest). The programs it asks for that are not built yet
        are noted and built when the block ends, all at once (in parallel on PoCL,
        clisp.engine.programs), so a metered run also builds what the real one needs."""
        if self._meter is not None:
            raise RuntimeError("metering runs do not nest")
        self._meter = BufferPool(lambda n: object())
        saved = self._kernels
        self._kernels = {}
        try:
            with self.programs.collecting():
                yield self._meter
        finally:
            self._meter = None
            self._kernels = saved

    def counter(self, name: str) -> Any:
        """The device uint32 named ``name`` that kernels count into (atomic_add), one per runtime,
        created zeroed on first use. The count belongs to the run, not to a stage object (the stages
        of a schedule are shared by every run of one camera and settings: executor.SCHEDULES):
        Pipeline.stream zeroes the counters before a run and reads them into RunStats.counts after
        it; runs on one runtime do not overlap (pipeline.DEVICE_LOCK). On a CPU device
        (:attr:`host_is_device`) the counter's storage is a host array the host zeroes and reads
        itself: no fill command before a run and no blocking copy after it (0.07 and 0.12 ms of a
        0.26 MP call on PoCL)."""
        held = self._counters.get(name)
        if held is None:
            if self.host_is_device and self.host_unified:
                host = aligned_empty(4).view(np.uint32)
                host[0] = 0
                flags = self.cl.mem_flags.READ_WRITE | self.cl.mem_flags.USE_HOST_PTR
                held = self._counters[name] = (self.cl.Buffer(self.context, flags, hostbuf=host), host)
            else:
                flags = self.cl.mem_flags.READ_WRITE | self.cl.mem_flags.COPY_HOST_PTR
                held = self._counters[name] = (self.cl.Buffer(self.context, flags, hostbuf=np.zeros(1, np.uint32)),
                                               None)
        return held[0]

    def reset_counters(self) -> None:
        """Zero every counter before a run: written by the host where it is the counter's storage
        (nothing of an earlier run is in flight: Pipeline.stream finishes its queue), else enqueued
        (the run's kernels count from 0)."""
        for buf, host in self._counters.values():
            if host is not None:
                host[0] = 0
            else:
                self.cl.enqueue_fill_buffer(self.queue, buf, np.uint32(0), 0, 4)

    def read_counters(self) -> dict[str, int]:
        """Every counter's value after a run whose queue has finished (Pipeline.stream); a device
        buffer is copied back (the copy waits for the queue's commands before it)."""
        out = {}
        for name, (buf, host) in self._counters.items():
            if host is None:
                host = np.zeros(1, np.uint32)
                self.cl.enqueue_copy(self.queue, host, buf, is_blocking=True)
            out[name] = int(host[0])
        return out

    def constant(self, values: np.ndarray) -> Any:
        """A small read-only device buffer holding ``values`` (CFA patterns, per-channel constants),
        cached by content so tiles of one run share it."""
        host = np.ascontiguousarray(values)
        key = (host.dtype.str, host.shape, host.tobytes())
        if key not in self._constants:
            flags = self.cl.mem_flags.READ_ONLY | self.cl.mem_flags.COPY_HOST_PTR
            self._constants[key] = self.cl.Buffer(self.context, flags, hostbuf=host)
        return self._constants[key]

    def upload(self, array: np.ndarray) -> DeviceImage:
        """Copy a planar host array (C x H x W, or H x W for one plane) to a pooled device image
        (while metering only its buffer is counted: a stage may upload a window's small tables).
        On a CPU device the copy is a buffer of its own, made from the array (COPY_HOST_PTR) and
        dropped on release: PoCL's write into a buffer waits, holding the GIL, until every command
        queued before it has run (a 4 KB write behind a 0.5 s kernel took 0.5 s; the highlight
        stage's tables stalled a 24 MP quality run's host for 1.9 s of its 2.6 s, README.md)."""
        array = np.ascontiguousarray(array)
        if array.ndim not in (2, 3):
            raise ValueError(f"upload needs H x W or C x H x W, got shape {array.shape}")
        channels = 1 if array.ndim == 2 else array.shape[0]
        height, width = array.shape[-2:]
        if self.host_is_device and self.host_unified and self._meter is None and array.size:
            flags = self.cl.mem_flags.READ_WRITE | self.cl.mem_flags.COPY_HOST_PTR
            active = profile.active()
            if active is not None:
                active.moved_without_event("upload", array.nbytes)
            return DeviceImage(self.cl.Buffer(self.context, flags, hostbuf=array), channels, height, width,
                               array.dtype, capacity=array.nbytes, pooled=False)
        image = self.acquire(channels, height, width, array.dtype)
        if self._meter is None:
            event = _record_copy("upload", array.nbytes, self.cl.enqueue_copy(
                self.transfer_queue, image.buffer, array, is_blocking=False, wait_for=self._behind_compute()))
            self._after(event)
        return image

    def zeroed(self, count: int, dtype: Any = np.uint32) -> DeviceImage:
        """``count`` zeros of ``dtype`` on the device for the queue's next commands (a tile's atomic
        append count), :meth:`release` d like any device image. On a CPU device a buffer made from
        host zeros (COPY_HOST_PTR): no command, where a fill was one more command for PoCL to wake its
        threads for before a tile's first kernel (about 0.1 ms of a 0.26 MP call); elsewhere a
        pooled buffer filled on the queue. Nothing is enqueued while metering (and on a CPU device
        nothing counted: the buffer is not the pool's)."""
        zeros = np.zeros((1, count), dtype)
        if self.host_is_device and self.host_unified:
            if self._meter is not None:
                return DeviceImage(object(), 1, 1, count, zeros.dtype, capacity=zeros.nbytes, pooled=False)
            return self.upload(zeros)
        image = self.acquire(1, 1, count, dtype)
        if self._meter is None:
            self.cl.enqueue_fill_buffer(self.queue, image.buffer, zeros.dtype.type(0), 0, zeros.nbytes)
        return image

    def resident_mosaic(self, array: np.ndarray) -> DeviceImage:
        """The whole H x W mosaic ``array`` (uint16 or float32) on the device, for each tile's
        window to be gathered there (:meth:`gather_window`): read in place where the device shares
        host memory and the array is aligned (:meth:`host_source`); else copied once into a
        staging buffer (:class:`HostStaging`: page-aligned, or pinned on a discrete device, and
        reused across calls and files), which a shared-memory device then reads in place and a
        discrete one receives in one upload of the transfer queue. :meth:`release` gives the
        staging buffer back. Read in place, ``array`` must not change until the run's last event;
        staged, it may change once this returns."""
        whole = self.host_source(array)
        if whole is not None:
            return whole
        staged = self.staging.take(array.nbytes)
        view = staged[:array.nbytes].view(array.dtype).reshape(array.shape)
        with profile.host_timer("stage the mosaic (host copy)", array.nbytes):
            host_threads.copy(view, array)
        if self.host_unified:
            image = self._host_plane(view)
            if image is None:
                self.staging.give(staged)
                raise RuntimeError("a staging buffer the device does not read in place")
        else:
            image = self.acquire(1, array.shape[0], array.shape[1], array.dtype)
            event = _record_copy("upload", array.nbytes, self.cl.enqueue_copy(
                self.transfer_queue, image.buffer, view, is_blocking=False, wait_for=self._behind_compute()))
            self._after(event)
            self.transfer_queue.flush()
        image.staging = staged
        return image

    def interleave(self, image: DeviceImage) -> DeviceImage:
        """Planar C x H x W -> pixel-interleaved H x W x C on the device (``interleaved`` set)."""
        kernel = self.kernel("layout", "interleave", {"NCH": image.channels})
        dst = self.acquire(image.channels, image.height, image.width, image.dtype)
        self.launch(kernel, image.width, image.height, image.buffer, dst.buffer,
                    np.int32(image.width), np.int32(image.height))
        dst.interleaved = True
        return dst

    def download(self, image: DeviceImage, into: np.ndarray | None = None) -> np.ndarray:
        """Copy a device image to a host array: H x W x C if interleaved, else C x H x W
        (H x W when C == 1). ``into``: a contiguous array of that shape to fill instead."""
        if image.interleaved:
            shape: tuple[int, ...] = (image.height, image.width, image.channels)
        elif image.channels == 1:
            shape = (image.height, image.width)
        else:
            shape = (image.channels, image.height, image.width)
        host = np.empty(shape, dtype=image.dtype) if into is None else into
        if host.shape != shape or not host.flags.c_contiguous:
            raise ValueError(f"download target {host.shape} does not match device image {shape}")
        _record("download", self.cl.enqueue_copy(self.queue, host, image.buffer, is_blocking=True),
                host.nbytes, "download")
        return host

    def host_image(self, array: np.ndarray) -> DeviceImage | None:
        """An interleaved device image whose storage is ``array`` itself (H x W x C, C-contiguous),
        for a last stage to write its output straight into the host's band buffer. Only on a device
        that shares host memory (PoCL's CPU device), where it saves the download copy; None
        elsewhere (a discrete GPU keeps its download) and while metering."""
        if array.ndim != 3:
            return None
        height, width, channels = array.shape
        return self._wrap_host(array, self.cl.mem_flags.WRITE_ONLY, channels, height, width, interleaved=True)

    def host_input(self, array: np.ndarray) -> DeviceImage | None:
        """A one-plane device image whose storage is the H x W host array ``array`` itself, for
        the first stage to read in place: on a device that shares host memory (PoCL's CPU device)
        this spares the upload copy. None elsewhere, while metering, or where ``array`` is not
        C-contiguous or not aligned to the device's base address alignment (the caller uploads).
        ``array`` must not change until the tile's last event has completed."""
        return self._host_plane(array)

    def host_source(self, array: np.ndarray) -> DeviceImage | None:
        """A device image over a whole H x W host mosaic, read in place, for :meth:`gather_window`
        (same conditions as :meth:`host_input`)."""
        return self._host_plane(array)

    def _host_plane(self, array: np.ndarray) -> DeviceImage | None:
        if array.ndim != 2:
            return None
        height, width = array.shape
        return self._wrap_host(array, self.cl.mem_flags.READ_ONLY, 1, height, width, interleaved=False)

    def gather_window(self, whole: DeviceImage, y0: int, x0: int, h: int, w: int, period: int) -> DeviceImage:
        """The h x w window at (y0, x0) of the one-plane image ``whole``, CFA-mirror padded outside it,
        as a pooled device image: tiling.gather_window done by the device (clisp/engine/gather.cl), so a
        mosaic already in memory that the device reads in place (host_source) needs no host copy per
        tile. The columns inside the mosaic are one vectorised launch, those outside it (at most the
        halo on each side) their own small launches."""
        src_h, src_w = whole.height, whole.width
        if min(src_h, src_w) < max(period, 2):
            raise ClispError(f"mosaic of {src_w}x{src_h} is smaller than one CFA tile")
        dst = self.acquire(1, h, w, whole.dtype)
        raw_t = "ushort" if whole.dtype == np.uint16 else "float"
        args = (whole.buffer, dst.buffer, np.int32(src_h), np.int32(src_w), np.int32(y0), np.int32(x0), np.int32(w))
        if h * w <= GATHER_ONE_LAUNCH:          # one launch of the mirroring kernel over the whole window
            edge = self.kernel("gather", "gather_window", {"RAW_T": raw_t, "CFA_PERIOD": period, "MIRROR_X": 1})
            edge(self.queue, (w, h), None, *args)
            return dst
        inside = (min(max(-x0, 0), w), min(max(src_w - x0, 0), w))      # window columns inside the mosaic
        if inside[1] > inside[0]:
            kernel = self.kernel("gather", "gather_window", {"RAW_T": raw_t, "CFA_PERIOD": period, "MIRROR_X": 0})
            launch_exact(self, kernel, inside[1] - inside[0], h, *args, x0=inside[0])
        edge = self.kernel("gather", "gather_window", {"RAW_T": raw_t, "CFA_PERIOD": period, "MIRROR_X": 1})
        for start, stop in ((0, inside[0]), (max(inside[1], inside[0]), w)):
            if stop > start:
                edge(self.queue, (stop - start, h), None, *args, global_offset=(start, 0))
        return dst

    def _wrap_host(self, array: np.ndarray, access: Any, channels: int, height: int, width: int,
                   interleaved: bool) -> DeviceImage | None:
        """A USE_HOST_PTR device image over ``array`` (host_image, host_input); None where the
        device does not share host memory, while metering, or for an empty, strided or unaligned
        array (below the device's base address alignment)."""
        if not self.host_unified or self._meter is not None or not array.flags.c_contiguous or array.size == 0:
            return None
        if array.ctypes.data % max(1, int(self.device.mem_base_addr_align) // 8):
            return None            # PoCL would keep an aligned copy of it, copied in and out around each use
        buffer = self.cl.Buffer(self.context, access | self.cl.mem_flags.USE_HOST_PTR, hostbuf=array)
        return DeviceImage(buffer, channels, height, width, array.dtype, interleaved=interleaved,
                           capacity=array.nbytes, host=array)

    def settle_host_image(self, image: DeviceImage) -> Any:
        """Enqueue, without waiting, what makes a host image's pixels readable in its array: on a
        CPU device (:attr:`host_is_device`) a marker, after which the commands that wrote the array
        are complete (the array is their storage: _wrap_host takes only aligned arrays, which PoCL
        uses as they are); elsewhere a map for reading and its unmap (no copy where the device uses
        the array itself). Returns the event after which the host may read the array. The marker
        is one command where the map is two: 50 us less of a 1.1 ms call (0.26 MP, fast, PoCL)."""
        if self.host_is_device:
            return _record("download", self.cl.enqueue_marker(self.queue), image.nbytes, "in place")
        mapped, _ = self.cl.enqueue_map_buffer(self.queue, image.buffer, self.cl.map_flags.READ, 0,
                                               (image.nbytes,), np.uint8, is_blocking=False)
        return _record("download", mapped.base.release(self.queue), image.nbytes, "in place")

    def download_region(self, image: DeviceImage, into: np.ndarray, y0: int, x0: int,
                        rows: int, cols: int) -> Any:
        """Enqueue, without waiting, a copy of the top-left ``rows x cols`` pixels of an
        interleaved device image into ``into[y0:y0+rows, x0:x0+cols]`` (``into``: a C-contiguous
        H' x W' x C host array of the image's dtype). Returns the copy's event; ``into`` must not
        be read before it completes."""
        if not image.interleaved or into.ndim != 3 or into.shape[2] != image.channels \
                or into.dtype != image.dtype or not into.flags.c_contiguous:
            raise ValueError(f"download target {into.shape} {into.dtype} does not fit device image "
                             f"{image.height}x{image.width}x{image.channels} {image.dtype}")
        pixel = image.channels * np.dtype(image.dtype).itemsize
        queue = self.transfer_queue
        wait = None if queue is self.queue else [self.cl.enqueue_marker(self.queue)]   # after the tile's kernels
        self.queue.flush()
        event = _record_copy("download", rows * cols * pixel, self.cl.enqueue_copy(
            queue, into, image.buffer, is_blocking=False, buffer_origin=(0, 0, 0),
            host_origin=(x0 * pixel, y0, 0), region=(cols * pixel, rows, 1),
            buffer_pitches=(image.width * pixel,), host_pitches=(into.shape[1] * pixel,), wait_for=wait))
        queue.flush()
        return event

    def launch(self, kernel: Any, width: int, height: int, *args: Any, depth: int = 1) -> None:
        """Enqueue a 2-D kernel over ``width x height`` output pixels (rounded up to LOCAL_SIZE);
        ``depth``: that many work-groups along a third index, one deep (a kernel doing several
        steps at once, the step its get_group_id(2))."""
        lx, ly = LOCAL_SIZE
        gsize = ((width + lx - 1) // lx * lx, (height + ly - 1) // ly * ly)
        if depth == 1:
            kernel(self.queue, gsize, LOCAL_SIZE, *args)
        else:
            kernel(self.queue, (*gsize, depth), (lx, ly, 1), *args)


def aligned_empty(nbytes: int, align: int = 4096) -> np.ndarray:
    """An uninitialised uint8 array of ``nbytes`` whose data starts on an ``align``-byte boundary
    (a page: a device sharing host memory then uses it in place, Runtime._wrap_host)."""
    raw = np.empty(nbytes + align, dtype=np.uint8)
    start = -raw.ctypes.data % align
    return raw[start:start + nbytes]


GATHER_ONE_LAUNCH = 1 << 20
"""Windows of at most this many pixels are gathered in one launch of the kernel that mirrors both
axes, not in a vectorised launch over the inside columns (up to four: launch_exact's block and
strips) and one per mirrored side: on PoCL a launch costs tens of microseconds of the host and of
the device's dispatch, more than the mirroring costs a 0.26 MP window (6 launches were about 0.3 ms
of a 2.3 ms call)."""


class HostStaging:
    """Host buffers that hand data to the device and back: page-aligned arrays on a device that
    shares host memory (it reads them in place), pinned memory on a discrete device (buffers made
    with ALLOC_HOST_PTR and mapped once: the DMA engine reads and writes them at the bus's speed,
    where a pageable array is first copied by the driver). Reused across tiles, calls and files:
    ``take(nbytes)`` hands out the smallest free buffer of at least ``nbytes`` (uint8, possibly
    longer), else a new one; ``give`` takes it back. Nothing handed to a caller is ever a staging
    buffer: a later call would overwrite it.

    Pinned on a discrete device only once it is asked for again: a buffer the first time is
    pageable (page-aligned, its pages touched on the host's threads), and when a later take would
    reuse it, a pinned one replaces it. Pinning costs more than it saves in one use: on the H200
    host a new pinned 144 MB buffer took 80 ms, a DMA into touched pageable memory 14.4 ms against
    2.6 ms pinned (README.md), so a one-file ``clisp process`` would pay 80 ms to save 12."""

    def __init__(self, rt: "Runtime") -> None:
        self._rt = rt
        self._free: list[np.ndarray] = []
        self._keep: dict[int, Any] = {}          # id(array) -> its pinned cl.Buffer (kept alive, mapped)
        self._lock = threading.Lock()

    def take(self, nbytes: int) -> np.ndarray:
        with self._lock:
            fits = [b for b in self._free if b.size >= nbytes]
            best = min(fits, key=len) if fits else None
            if best is not None:
                self._free = [b for b in self._free if b is not best]
                if self._rt.host_unified or id(best) in self._keep:
                    return best
        if best is not None:                        # a pageable one asked for again: pinned, of its size
            return self._new(best.size, pinned=True)
        return self._new(max(int(nbytes), 1))

    def give(self, array: np.ndarray) -> None:
        with self._lock:
            if all(b is not array for b in self._free):
                self._free.append(array)

    def trim(self) -> None:
        """Drop the free buffers (their pinned memory goes back to the driver)."""
        with self._lock:
            for array in self._free:
                self._keep.pop(id(array), None)
            self._free = []

    def _new(self, nbytes: int, pinned: bool = False) -> np.ndarray:
        """A new buffer: page-aligned on a device sharing host memory; on a discrete one pinned when
        ``pinned``, else page-aligned with its pages touched (a DMA into fresh pages is 4x slower)."""
        rt = self._rt
        if rt.host_unified:
            return aligned_empty(nbytes)
        if not pinned:
            array = aligned_empty(nbytes)
            host_threads.wait(host_threads.touch(array))
            return array
        cl = rt.cl
        buffer = cl.Buffer(rt.context, cl.mem_flags.READ_WRITE | cl.mem_flags.ALLOC_HOST_PTR, nbytes)
        array, _ = cl.enqueue_map_buffer(rt.transfer_queue, buffer, cl.map_flags.READ | cl.map_flags.WRITE, 0,
                                         (nbytes,), np.uint8, is_blocking=True)
        with self._lock:
            self._keep[id(array)] = buffer
        return array


class BufferPool:
    """Device buffers kept for reuse. ``acquire(n)`` hands out the smallest free buffer of at
    least n bytes, else creates one of exactly n bytes. Windows shrink by each stage's halo, so
    buffers released by early stages serve later ones: on a 24 MP LMS raw (quality preset) the
    pool created 363 bytes per window pixel when it reused only equal sizes, 85 with best fit
    (the peak of buffers in use at once is 44; Bayer quality: 100, 68 and 41). ``created``: bytes of all buffers alive;
    ``largest``: the largest one."""

    def __init__(self, create: Any) -> None:
        self._create = create
        self._sizes: list[int] = []          # free buffers, sorted by size
        self._buffers: list[Any] = []
        self.created = 0
        self.largest = 0
        self.pending: dict[int, Any] = {}    # id(buffer) -> an event that still reads it (Runtime.release)

    def acquire(self, nbytes: int) -> tuple[Any, int]:
        """(buffer, its size in bytes) of at least ``nbytes``."""
        i = bisect.bisect_left(self._sizes, nbytes)
        if i < len(self._sizes):
            return self._buffers.pop(i), self._sizes.pop(i)
        buffer = self._create(nbytes)
        self.created += nbytes
        self.largest = max(self.largest, nbytes)
        return buffer, nbytes

    def release(self, buffer: Any, size: int) -> None:
        """Return ``buffer`` (of ``size`` bytes) for reuse."""
        i = bisect.bisect_left(self._sizes, size)
        self._sizes.insert(i, size)
        self._buffers.insert(i, buffer)

    def trim(self) -> None:
        """Free every buffer not in use."""
        for buffer, size in zip(self._buffers, self._sizes):
            self.created -= size
            release = getattr(buffer, "release", None)
            if release is not None:
                release()
        self._sizes, self._buffers, self.pending = [], [], {}


def _skipped_launch(*args: Any, **kwargs: Any) -> None:
    """A kernel launch during a metering run: nothing happens."""
    return None


def _record(what: str, event: Any, nbytes: int = 0, transfer: str = "") -> Any:
    """Hand ``event`` to the active profile (clisp.engine.profile), if any; returns it. A copy's
    ``nbytes`` count under ``transfer`` ('upload', 'download', 'in place')."""
    active = profile.active()
    if active is not None:
        active.record(what, event, nbytes, transfer)
    return event


def _record_copy(transfer: str, nbytes: int, event: Any) -> Any:
    """:func:`_record` of a copy named after its ``transfer``."""
    return _record(transfer, event, nbytes, transfer)


class _ProfiledKernel:
    """A kernel whose every launch is recorded in the active profile, with the host time of its
    enqueue (profiling runtimes only)."""

    def __init__(self, kernel: Any, name: str) -> None:
        self.kernel, self.name = kernel, name

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        start = time.perf_counter()
        event = self.kernel(*args, **kwargs)
        active = profile.active()
        if active is not None:
            active.enqueued(time.perf_counter() - start)
        return _record(self.name, event)


WORK_GROUP = (64, 4)
"""Work-group shape (x, y) of :func:`launch_exact`, the launch of every kernel without bounds checks.
Wider along x gives each vectorised work-group longer rows; 4 rows share the vertical taps (the LMS
hybrid at 24 MP on PoCL: 39 MP/s against 31-37 for (32, 4), (64, 2), (128, 1); README.md)."""

def group_within(width: int, height: int, group: tuple[int, int] = WORK_GROUP) -> tuple[int, int]:
    """``group`` with each side cut to the largest power of two within ``width`` / ``height``
    outputs (launch_exact's rule: few distinct shapes, so few work-group compilations on PoCL; an
    inward launch needs at least one whole group of outputs).

    >>> group_within(100, 3), group_within(1000, 1000)
    ((64, 2), (64, 4))
    """
    return min(group[0], 1 << (width.bit_length() - 1)), min(group[1], 1 << (height.bit_length() - 1))


def launch_exact(rt: "Runtime", kernel: object, width: int, height: int, *args: object,
                 group: tuple[int, int] = WORK_GROUP, x0: int = 0, inward: bool = False, depth: int = 1) -> None:
    """Enqueue ``kernel`` over exactly width x height outputs without bounds checks (global ids
    along x offset by ``x0``).

    Schedule: whole ``group`` work-groups (default WORK_GROUP) over the largest multiple-of-group block, then the ragged
    right/bottom strips as one group-wide launch shifted inward to end at the edge (it recomputes some
    outputs with identical values). A side shorter than the group gets the largest power of two that
    fits (few distinct shapes, so few work-group compilations on PoCL). Kernels thus carry no bounds
    check and PoCL vectorises them (6-15x, measured; see clisp/modules/demosaic_lms/demosaic_lms.cl).

    ``inward``: the kernel takes its coordinates from common.h's inward_id (the last work-group
    shifted inward to end at the edge, within the kernel): one launch over whole groups covers the
    outputs, the same work-groups as the block and strips above in one command. On PoCL each
    command costs 10-20 us of dispatch beside its enqueue, and a ragged window otherwise takes up
    to four (engine README). ``depth`` (inward launches only): the same over that many work-groups
    along a third index (one deep), for a kernel doing several steps at once (RI's line directions).
    """
    lx, ly = group_within(width, height, group)
    if inward:
        size = (-(-width // lx) * lx, -(-height // ly) * ly)
        if depth == 1:
            kernel(rt.queue, size, (lx, ly), *args, global_offset=(x0, 0))
        else:
            kernel(rt.queue, (*size, depth), (lx, ly, 1), *args, global_offset=(x0, 0, 0))
        return
    if depth != 1:
        raise ValueError(f"a launch of depth {depth} is an inward one")
    full_w, full_h = width // lx * lx, height // ly * ly
    xs = [(0, full_w)] + ([(width - lx, lx)] if full_w < width else [])
    ys = [(0, full_h)] + ([(height - ly, ly)] if full_h < height else [])
    for gx, gw in xs:
        for gy, gh in ys:
            kernel(rt.queue, (gw, gh), (lx, ly), *args, global_offset=(x0 + gx, gy))


_RUNTIME: Runtime | None = None


def save_built_programs() -> None:
    """:meth:`Runtime.save_programs` of the process-wide runtime, if one was created."""
    if _RUNTIME is not None:
        _RUNTIME.save_programs()


DEVICE_LOCK = threading.RLock()
"""Held by whatever enqueues on the process's runtime or changes its pools: building a pipeline
(the noise calibration's kernels, the planner's metering runs, which swap the kernel cache) and a
run's tile loop (clisp.pipeline.process_file, process_with_stats). Several files then go through
one process at once (``clisp process RAW... -o OUTDIR``, a batch worker's threads) with their
decoding and writing overlapping another file's device work, while one thread at a time launches:
a ``cl.Kernel`` holds its arguments as state, and the runtime shares one per program and defines.
Reentrant: a locked caller may call locked code."""


def get_runtime(profiling: bool = False) -> Runtime:
    """The process-wide runtime, created on first use. ``profiling``: create it with event
    profiling on (``clisp process --profile``; an existing runtime switches to a profiling queue),
    as it is whenever a profile is being recorded (clisp.engine.profile.recording)."""
    global _RUNTIME
    profiling = profiling or profile.active() is not None      # a recording (profile.recording) needs its events
    with DEVICE_LOCK:
        if _RUNTIME is None:
            _RUNTIME = Runtime(profiling=profiling)
        elif profiling and not _RUNTIME.profiling:
            _RUNTIME.enable_profiling()
        return _RUNTIME
