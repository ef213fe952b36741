"""Where a run's time goes: device time per stage and kernel, host time per activity.

``clisp process --profile`` turns it on. Device times come from OpenCL event profiling (the
queue is created with ``PROFILING_ENABLE``): every kernel launch and every host-device copy is
recorded with the stage that enqueued it, and summed after the run from the events' START/END
counters. Host times are wall-clock seconds per activity (``decode`` of the raw file, ``read``
of tile windows, ``write`` of output bands, ``wait`` for the device on the main thread), each
summed over the threads that did it; the reader and writer threads overlap the device, so host
and device sums may exceed the wall time.
"""
from __future__ import annotations

import threading
import time
from collections import defaultdict
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any, Iterator


@dataclass
class Profile:
    """Events and host timers of one run. ``stage`` labels the launches enqueued next."""

    stage: str = "-"
    path: str = "-"
    """The skip path (clisp.skip) of the tile part being enqueued, for :meth:`path_seconds`."""
    events: list[tuple[str, str, Any]] = field(default_factory=list)
    paths: list[str] = field(default_factory=list)
    host: dict[str, float] = field(default_factory=lambda: defaultdict(float))
    host_bytes: dict[str, int] = field(default_factory=lambda: defaultdict(int))
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def record(self, what: str, event: Any) -> None:
        """Keep ``event`` (an OpenCL event of a kernel or copy named ``what``) under the current stage."""
        self.events.append((self.stage, what, event))
        self.paths.append(self.path)

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

_ACTIVE: Profile | None = None


def active() -> Profile | None:
    """The profile being recorded, or None (the usual case: no overhead)."""
    return _ACTIVE


def start() -> Profile:
    """Start recording into a new Profile (the runtime must be created with profiling on)."""
    global _ACTIVE
    _ACTIVE = Profile()
    return _ACTIVE


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
