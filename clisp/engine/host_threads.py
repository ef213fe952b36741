"""Large host copies and reductions split over the host's cores.

On a discrete GPU the device finishes a 24 MP call in a few milliseconds; what is left is the host
moving the pixels: a 144 MB 16-bit sRGB result copied out of pinned memory into the caller's new
array (whose pages are touched for the first time), the mosaic copied into pinned staging, a
maximum per block over the raw. NumPy does each on one core and releases the GIL while it does,
so row bands of one array on a pool of threads scale with the cores (clisp/engine/README.md has
the figures). One pool, shared by the process and made on first use; small arrays stay on the
calling thread, where a thread's hand-off would cost more than it saves.
"""
from __future__ import annotations

import os
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TypeVar

import numpy as np

T = TypeVar("T")
R = TypeVar("R")

MAX_THREADS = 16
"""At most this many copy threads (a copy saturates memory bandwidth well before 16 cores)."""

MIN_BAND_BYTES = 4 << 20
"""Bands of at least this many bytes each: below it a copy stays on one thread."""

_POOL: ThreadPoolExecutor | None = None
_LOCK = threading.Lock()


def usable_cores() -> int:
    """The CPU cores this process may run on (its affinity, e.g. a container's share), else all."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):                       # not on Linux
        return os.cpu_count() or 1


def _pool() -> ThreadPoolExecutor:
    global _POOL
    with _LOCK:
        if _POOL is None:
            _POOL = ThreadPoolExecutor(min(MAX_THREADS, usable_cores()), thread_name_prefix="clisp-copy")
        return _POOL


def bands(rows: int, nbytes: int, multiple: int = 1) -> list[tuple[int, int]]:
    """(start, stop) row ranges splitting ``rows`` rows of ``nbytes`` bytes in all into one band
    per usable core (at most MAX_THREADS), each at least MIN_BAND_BYTES and starting on a multiple
    of ``multiple`` rows; one band where the array is small or the host has one core.

    >>> bands(8, 1000)                       # 1000 bytes: one band on any host
    [(0, 8)]
    """
    count = max(1, min(MAX_THREADS, usable_cores(), nbytes // MIN_BAND_BYTES, -(-rows // multiple)))
    step = -(-rows // count)
    step = -(-step // multiple) * multiple
    return [(start, min(start + step, rows)) for start in range(0, rows, step)]


def run_bands(work: Callable[[int, int], None], rows: int, nbytes: int, multiple: int = 1) -> None:
    """``work(start, stop)`` for every band of :func:`bands`, on the pool (the last on this
    thread); returns when all are done and re-raises the first error."""
    map_items(lambda span: work(*span), bands(rows, nbytes, multiple))


def map_items(work: Callable[[T], R], items: Sequence[T]) -> list[R]:
    """``[work(item) for item in items]``, the items on the pool (the last on this thread), for a
    few independent NumPy computations of a few milliseconds or more each (a thumbnail's three
    channels); re-raises the first error.

    >>> map_items(lambda x: x * x, [1, 2, 3])
    [1, 4, 9]
    """
    if len(items) < 2 or usable_cores() < 2:
        return [work(item) for item in items]
    futures = [_pool().submit(work, item) for item in items[:-1]]
    try:
        last = work(items[-1])
    finally:
        done = [future.result() for future in futures]
    return done + [last]


def touch(array: np.ndarray) -> list[Future]:
    """Start writing zeros over ``array`` by row bands on the pool, returning at once: its pages
    faulted in while the caller does other work (a device computing the result that will be copied
    there), so that the copy itself runs at memory speed; :func:`wait` for the futures before
    writing ``array``. None started for an array of one band (it is touched by its copy).

    >>> a = np.ones((2, 3)); wait(touch(a)); a.tolist()      # a small array: left as it was
    [[1.0, 1.0, 1.0], [1.0, 1.0, 1.0]]
    """
    spans = bands(array.shape[0], array.nbytes) if array.ndim else [(0, 0)]
    if len(spans) < 2:
        return []
    pool = _pool()
    return [pool.submit(array[a:b].fill, 0) for a, b in spans]


def wait(futures: Sequence[Future]) -> None:
    """Wait for every future (of :func:`touch`), re-raising the first error."""
    for future in futures:
        future.result()


def maximum(array: np.ndarray) -> float:
    """The largest element of a non-empty ``array``, by row bands of its first axis on the pool
    (NumPy releases the GIL in the reduction).

    >>> maximum(np.arange(12).reshape(4, 3))
    11.0
    """
    if array.ndim == 0:
        return float(array)
    spans = bands(array.shape[0], array.nbytes)
    return max(map_items(lambda span: float(array[span[0]:span[1]].max()), spans))


def copy(dst: np.ndarray, src: np.ndarray) -> None:
    """``dst[...] = src`` (same shape), by row bands of the first axis on the pool.

    >>> a = np.zeros((3, 2)); copy(a, np.ones((3, 2))); a.tolist()
    [[1.0, 1.0], [1.0, 1.0], [1.0, 1.0]]
    """
    if dst.shape != src.shape:
        raise ValueError(f"copy of {src.shape} into {dst.shape}")
    if dst.ndim == 0:
        dst[...] = src
        return
    run_bands(lambda a, b: np.copyto(dst[a:b], src[a:b]), dst.shape[0], dst.nbytes)
