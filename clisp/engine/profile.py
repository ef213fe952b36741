"""Where a run's time goes: device time per stage and kernel, host time per activity.

``clisp process --profile`` turns it on. Device times come from OpenCL event profiling (the
queue is created with ``PROFILING_ENABLE``): every kernel launch and every host-device copy is
recorded with the stage that enqueued it, and summed after the run from the events' START/END
counters. Host times are wall-clock seconds per activity (``decode`` of the raw file, ``read``
of tile windows, ``write`` of output bands, ``wait`` for the device on the main thread), each
summed over the threads that did it; the reader and writer threads overlap the device, so host
and device sums may exceed the wall time.

How busy the device was (issue 41): each tile loop (Pipeline.stream) is a :class:`Loop`, its wall
time and the events enqueued during it; ``device busy`` is the union of those kernel and copy
events (the time the device had work running) over the loops' wall time. Beside it, the host's
cost of launching: seconds inside :meth:`Runtime.launch_named` and inside each kernel enqueue (the
pyopencl call), launches per tile, and the bytes each copy moved. ``clisp process --profile``
prints them; an in-process caller gets them from :func:`recording`::

    with recording() as prof:
        clisp.process(raw)
    prof.summary()["device_busy"]
"""
from __future__ import annotations

import threading
import time
from collections import defaultdict
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Iterator


@dataclass
class Loop:
    """One tile loop: the events enqueued during it (indices into Profile.events), its tiles and
    its wall time in seconds."""

    first: int
    last: int = -1
    tiles: int = 0
    seconds: float = 0.0


@dataclass
class Profile:
    """Events and host timers of one run. ``stage`` labels the launches enqueued next."""

    stage: str = "-"
    path: str = "-"
    """The skip path (clisp.pipeline.skip) of the tile part being enqueued, for :meth:`path_seconds`."""
    events: list[tuple[str, str, Any]] = field(default_factory=list)
    paths: list[str] = field(default_factory=list)
    host: dict[str, float] = field(default_factory=lambda: defaultdict(float))
    host_bytes: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    loops: list[Loop] = field(default_factory=list)
    enqueues: int = 0
    """Kernel enqueues (one launch_exact is up to four: its block and ragged strips)."""
    enqueue_seconds: float = 0.0
    """Host seconds inside the kernel enqueue calls (pyopencl's invoker and the driver's enqueue)."""
    named_calls: int = 0
    named_seconds: float = 0.0
    """Host seconds inside Runtime.launch_named (argument checks, conversion, its enqueues)."""
    moved: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    """Bytes by transfer: 'upload' and 'download' copies, 'in place' (a map of host memory the
    device shares: nothing copied)."""
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def record(self, what: str, event: Any, nbytes: int = 0, transfer: str = "") -> None:
        """Keep ``event`` (an OpenCL event of a kernel or copy named ``what``) under the current
        stage; a copy's ``nbytes`` count under ``transfer`` ('upload', 'download', 'in place')."""
        self.events.append((self.stage, what, event))
        self.paths.append(self.path)
        if transfer:
            self.moved[transfer] += int(nbytes)

    def moved_without_event(self, transfer: str, nbytes: int) -> None:
        """Count ``nbytes`` under ``transfer`` for a copy that has no event (a buffer made from a host
        array: Runtime.upload on a CPU device)."""
        self.moved[transfer] += int(nbytes)

    def enqueued(self, seconds: float) -> None:
        """Count one kernel enqueue that took ``seconds`` of host time."""
        self.enqueues += 1
        self.enqueue_seconds += seconds

    def named(self, seconds: float) -> None:
        """Count one Runtime.launch_named call that took ``seconds`` of host time."""
        self.named_calls += 1
        self.named_seconds += seconds

    def begin_loop(self) -> Loop:
        """A tile loop starts: the events recorded from now on are its own (until :meth:`end_loop`)."""
        loop = Loop(len(self.events))
        self.loops.append(loop)
        return loop

    def end_loop(self, loop: Loop, seconds: float, tiles: int) -> None:
        """The tile loop ``loop`` ended (every event it enqueued complete) after ``seconds`` of wall time."""
        loop.last, loop.seconds, loop.tiles = len(self.events), seconds, tiles

    def busy_seconds(self) -> tuple[float, float]:
        """(device busy, tile loops' wall) in seconds: the union of the loops' kernel and copy
        events (the device's own clock) and the sum of their wall times."""
        busy = 0.0
        for loop in self.loops:
            spans = sorted((e.profile.start, e.profile.end) for _, _, e in self.events[loop.first:loop.last]
                           if _waited(e))
            busy += union_length(spans) * 1e-9
        return busy, sum(loop.seconds for loop in self.loops)

    def summary(self) -> dict[str, float]:
        """The figures of :meth:`report`'s first lines as numbers: device_busy (fraction of the tile
        loops' wall time), device_busy_s, loop_s, tiles, launches_per_tile (kernel enqueues),
        named_per_tile, host_us_per_launch_named, host_us_per_enqueue, and bytes_upload,
        bytes_download, bytes_in_place."""
        busy, wall = self.busy_seconds()
        tiles = sum(loop.tiles for loop in self.loops)
        return {"device_busy": busy / wall if wall > 0 else float("nan"), "device_busy_s": busy, "loop_s": wall,
                "tiles": float(tiles),
                "launches_per_tile": self.enqueues / tiles if tiles else float("nan"),
                "named_per_tile": self.named_calls / tiles if tiles else float("nan"),
                "host_us_per_launch_named": 1e6 * self.named_seconds / self.named_calls if self.named_calls
                else float("nan"),
                "host_us_per_enqueue": 1e6 * self.enqueue_seconds / self.enqueues if self.enqueues else float("nan"),
                "bytes_upload": float(self.moved.get("upload", 0)),
                "bytes_download": float(self.moved.get("download", 0)),
                "bytes_in_place": float(self.moved.get("in place", 0))}

    def busy_lines(self) -> list[str]:
        """The device-busy, launch-cost and transfer lines that open :meth:`report`."""
        f = self.summary()
        mb = 1e-6
        return [f"device busy {100 * f['device_busy']:.0f} % of the tile loop ({f['device_busy_s']:.3f} s of "
                f"{f['loop_s']:.3f} s: the union of its kernel and copy events)",
                f"host per launch_named {f['host_us_per_launch_named']:.0f} us ({self.named_calls} calls), "
                f"per enqueue {f['host_us_per_enqueue']:.0f} us ({self.enqueues} enqueues); "
                f"{f['launches_per_tile']:.1f} launches per tile ({int(f['tiles'])} tiles)",
                f"bytes moved: upload {f['bytes_upload'] * mb:.1f} MB, download {f['bytes_download'] * mb:.1f} MB, "
                f"read in place {f['bytes_in_place'] * mb:.1f} MB"]

    @contextmanager
    def timed(self, activity: str, nbytes: int = 0) -> Iterator[None]:
        """Add the wall time of the block (and ``nbytes`` moved) to host ``activity``."""
        start = time.perf_counter()
        try:
            yield
        finally:
            with self._lock:
                self.host[activity] += time.perf_counter() - start
                self.host_bytes[activity] += nbytes

    def device_seconds(self) -> dict[tuple[str, str], tuple[float, int]]:
        """{(stage, kernel or copy): (device seconds, launches)} from the events' counters."""
        totals: dict[tuple[str, str], list[float]] = defaultdict(lambda: [0.0, 0])
        for stage, what, event in self.events:
            event.wait()
            t = totals[(stage, what)]
            t[0] += (event.profile.end - event.profile.start) * 1e-9
            t[1] += 1
        return {key: (v[0], int(v[1])) for key, v in totals.items()}

    def path_seconds(self) -> dict[str, float]:
        """{skip path: device seconds} of the launches and copies enqueued under each
        (:func:`path_label`; '-' before any)."""
        totals: dict[str, float] = defaultdict(float)
        for (_, _, event), path in zip(self.events, self.paths):
            event.wait()
            totals[path] += (event.profile.end - event.profile.start) * 1e-9
        return dict(totals)

    def report(self, megapixels: float, wall: float) -> str:
        """A table: per stage and kernel the device time, share and MP/s; then the host activities."""
        device = self.device_seconds()
        total = sum(s for s, _ in device.values()) or float("nan")
        lines = [f"profile: {megapixels:.1f} MP, wall {wall:.3f} s ({megapixels / wall:.1f} MP/s)",
                 *self.busy_lines(),
                 f"{'device: stage / kernel':<46}{'s':>8}{'share':>8}{'MP/s':>9}{'launches':>9}"]
        by_stage: dict[str, float] = defaultdict(float)
        for (stage, _), (s, _) in device.items():
            by_stage[stage] += s
        for stage in sorted(by_stage, key=lambda k: -by_stage[k]):
            s = by_stage[stage]
            rate = f" {megapixels / s:8.1f}" if s >= RATE_MIN_SECONDS else f"{'-':>9}"
            lines.append(f"  {stage:<44}{s:8.3f}{s / total:8.1%}{rate}")
            for (st, what), (ks, n) in sorted(device.items(), key=lambda kv: -kv[1][0]):
                if st == stage and len([k for k in device if k[0] == stage]) > 1:
                    lines.append(f"    {what:<42}{ks:8.3f}{ks / total:8.1%}{'':9}{n:9d}")
        lines.append(f"  {'device total':<44}{total:8.3f}")
        lines.append("host (summed over threads; overlaps the device):")
        for activity, s in sorted(self.host.items(), key=lambda kv: -kv[1]):
            moved = self.host_bytes.get(activity, 0)
            rate = f"{moved / s / 1e9:6.2f} GB/s" if moved and s else ""
            lines.append(f"  {activity:<44}{s:8.3f}  {rate}")
        return "\n".join(lines)


RATE_MIN_SECONDS = 0.001
"""A stage's MP/s is shown from this much device time on ('-' below: a download of a few bytes gave
'1787345.5', which ran into the share column)."""

def union_length(spans: list[tuple[int, int]]) -> int:
    """Total length covered by the sorted (start, end) ``spans`` (overlaps counted once).

    >>> union_length([(0, 4), (2, 6), (8, 9)])
    7
    """
    total, current = 0, None
    for start, end in spans:
        if current is None or start > current[1]:
            if current is not None:
                total += current[1] - current[0]
            current = [start, end]
        else:
            current[1] = max(current[1], end)
    return total + (current[1] - current[0] if current is not None else 0)


def _waited(event: Any) -> bool:
    """Wait for ``event``; False when it carries no profiling times (a driver that does not time
    that command)."""
    event.wait()
    try:
        return event.profile.end >= event.profile.start > 0
    except Exception:                               # pyopencl raises RuntimeError (PROFILING_INFO_NOT_AVAILABLE)
        return False


_ACTIVE: Profile | None = None


def active() -> Profile | None:
    """The profile being recorded, or None (the usual case: no overhead)."""
    return _ACTIVE


def start() -> Profile:
    """Start recording into a new Profile (the runtime must be created with profiling on)."""
    global _ACTIVE
    _ACTIVE = Profile()
    return _ACTIVE


def stop() -> None:
    """Stop recording (:func:`active` is None again)."""
    global _ACTIVE
    _ACTIVE = None


@contextmanager
def recording() -> Iterator[Profile]:
    """Record every run in the block into a new :class:`Profile` (the process's runtime switches to
    event profiling when the block's first run asks for it: clisp.engine.runtime.get_runtime), for
    an in-process caller: its :meth:`Profile.summary` holds the
    figures ``clisp process --profile`` prints (device busy, host time per launch, launches per
    tile, bytes moved), :meth:`Profile.report` the whole table."""
    global _ACTIVE
    previous = _ACTIVE
    profile = start()
    try:
        yield profile
    finally:
        _ACTIVE = previous


@contextmanager
def host_timer(activity: str, nbytes: int = 0) -> Iterator[None]:
    """Time a host activity into the active profile; a no-op when none is active."""
    profile = _ACTIVE
    if profile is None:
        yield
    else:
        with profile.timed(activity, nbytes):
            yield


def path_label(name: str) -> None:
    """Label the launches enqueued from now on with skip path ``name`` (when profiling)."""
    if _ACTIVE is not None:
        _ACTIVE.path = name


def stage_label(name: str) -> None:
    """Label the launches enqueued from now on with stage ``name`` (when profiling)."""
    if _ACTIVE is not None:
        _ACTIVE.stage = name
