"""Resizing to a long edge (``--resize N``): an anti-aliasing low-pass, then sampling, in linear light,
on the device; separable, horizontal then vertical.

The filter is Lanczos-3 (sinc(x) sinc(x / 3), |x| < 3) stretched by the scale factor, so that its
cutoff is the OUTPUT's Nyquist frequency: output pixel i of an axis of n_in -> n_out pixels (scale
s = n_in / n_out >= 1) has its centre at input coordinate c = (i + 0.5) s, and is the sum of the
input pixels j whose centres lie within 3 s of it, weighted by L((j + 0.5 - c) / s), the weights
normalised to sum 1. At the image's edges the kernel is cut and renormalised (no mirrored pixels).
This is the convolution-based resampling of Pillow's ``Image.resize(..., Image.LANCZOS)``
(libImaging/Resample.c, ``precompute_coeffs``: support = 3 s, the same centres, the same cut and
normalisation), run in float on linear values; the kernel is C. E. Duchon, "Lanczos filtering in
one and two dimensions", J. Appl. Meteorology 18 (1979) 1016-1022 (see also K. Turkowski,
"Filters for common resampling tasks", Graphics Gems, 1990). Measured aliasing on a zone plate:
tools/bench_resize.py, docs/RESULTS.md.

Steps, each a kernel in ``resize.cl`` (radius in input pixels along the step's axis)::

    resize_rows      r = 3 s_x   horizontal: each input row to out_w pixels, into a window of rows
    resize_columns   r = 3 s_y   vertical: each output row from the window's rows
    (tone curve)                 sRGB outputs: clisp.modules.colour ToneCurve, after the resampling

The reference (:func:`resize_reference`) runs the same tap tables (:func:`filter_taps`) in float64.
The device path streams (:class:`StreamingResize`): rows arrive in bands, each band's rows go
through ``resize_rows`` into a rolling window on the device that holds the rows the next output
rows need (fewer than the vertical taps, plus one chunk), and every output row whose taps have
arrived is computed, tone-mapped and handed on. An output row's value depends only on the image's
rows, never on how they arrived in bands: tiled equals whole, bit for bit.

Example: a flat image stays flat, a 3:2 image goes to 3:2::

    >>> resized_size(4000, 6000, 2048)
    (1365, 2048)
    >>> out = resize_reference(np.full((40, 60, 3), 0.25), 14, 20)
    >>> out.shape, bool(np.allclose(out, 0.25))
    ((14, 20, 3), True)
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from ...errors import ClispError
from ...engine.profile import stage_label
from ...engine.runtime import DeviceImage, Runtime, get_runtime
from ...engine.streaming import BandSink, aligned_empty
from ...engine.tiling import Tile, TilePlan
from ..colour.stage import ToneCurve, tone_curve_for

LOBES = 3
"""Lanczos-3: the kernel's half-width in output pixels (sinc(x) sinc(x / LOBES), |x| < LOBES)."""

MIN_LONG_EDGE = 16
"""Smallest ``--resize`` (pixels of the long edge), as ``--tile``'s smallest tile."""

CHUNK_ROWS = 64
"""Input rows per ``resize_rows`` launch. The device window holds 2 x (vertical taps) + CHUNK_ROWS
rows of the output's width (2.4 MiB for 6000 x 4000 to 2048), whatever the pipeline's band height."""

OUTPUTS = ("linear", "srgb", "srgb16", "srgb8")
"""What :class:`StreamingResize` hands on: linear float32, sRGB-encoded float32, 16-bit sRGB codes
(clisp.pipeline.build_pipeline's output kinds)."""


def lanczos(x: np.ndarray) -> np.ndarray:
    """The Lanczos-3 kernel sinc(x) sinc(x / 3) for |x| < 3, else 0 (x in output pixels)."""
    x = np.asarray(x, dtype=np.float64)
    return np.where(np.abs(x) < LOBES, np.sinc(x) * np.sinc(x / LOBES), 0.0)


def resized_size(height: int, width: int, long_edge: int) -> tuple[int, int]:
    """(height, width) of an image of ``height x width`` whose long edge becomes ``long_edge``
    pixels, the short edge in proportion (rounded half up, at least 1). Never larger: when
    ``long_edge`` is at least the long edge, the size stays."""
    longest = max(height, width)
    if long_edge >= longest:
        return height, width
    scale = long_edge / longest
    if width >= height:
        return max(1, math.floor(height * scale + 0.5)), long_edge
    return long_edge, max(1, math.floor(width * scale + 0.5))


def check_long_edge(value: Any) -> int:
    """The ``--resize`` value as an int; ClispError when it is not a whole number of at least
    MIN_LONG_EDGE pixels (``2048``, not ``2048.5``, ``2k`` or ``8``)."""
    text = str(value).strip()
    if not text.isdigit() or int(text) < MIN_LONG_EDGE:
        raise ClispError(f"--resize {text}: the long edge must be a whole number of pixels, "
                         f"at least {MIN_LONG_EDGE}")
    return int(text)


def resize_note(source: tuple[int, int], target: tuple[int, int], long_edge: int | None) -> str:
    """What ``clisp process`` says after the output's size: ' (resized from WxH)', ' (--resize N:
    long edge M kept, never enlarged)', or '' without --resize. ``source``, ``target``: (height,
    width) before and after."""
    if not long_edge:
        return ""
    if target == source:
        return f" (--resize {long_edge}: long edge {max(source)} kept, never enlarged)"
    return f" (resized from {source[1]}x{source[0]})"


@dataclass(frozen=True)
class Taps:
    """The resampling of one axis, n_in -> n_out pixels: output pixel i is
    sum_k weights[i, k] * input[starts[i] + k], k = 0 .. count - 1 (all indices inside the input)."""

    starts: np.ndarray      # (n_out,) int32, first input pixel
    weights: np.ndarray     # (n_out, count) float64, each row sums to 1

    @property
    def count(self) -> int:
        return int(self.weights.shape[1])


def filter_taps(n_in: int, n_out: int) -> Taps:
    """The tap table of one axis (see the module docstring): Lanczos-3 stretched by s = n_in / n_out
    (not below 1), centred on (i + 0.5) s, taps = 2 ceil(3 s) + 1 (at most n_in) consecutive input
    pixels, shifted inward at the edges, where the kernel's cut part has weight 0; normalised."""
    if n_in < 1 or n_out < 1:
        raise ValueError(f"cannot resample {n_in} pixels to {n_out}")
    scale = n_in / n_out
    stretch = max(scale, 1.0)
    support = LOBES * stretch
    count = min(n_in, 2 * math.ceil(support) + 1)
    centres = (np.arange(n_out) + 0.5) * scale
    first = np.floor(centres - support + 0.5).astype(np.int64)
    starts = np.clip(first, 0, n_in - count)
    pixels = starts[:, None] + np.arange(count)
    weights = lanczos((pixels + 0.5 - centres[:, None]) / stretch)
    weights /= weights.sum(axis=1, keepdims=True)
    return Taps(starts.astype(np.int32), weights)


def resample_axis(x: np.ndarray, taps: Taps, axis: int) -> np.ndarray:
    """``x`` resampled along ``axis`` (0: rows, y; 1: columns, x) by ``taps``, float64."""
    moved = np.moveaxis(np.asarray(x, dtype=np.float64), axis, 0)
    shape = (-1,) + (1,) * (moved.ndim - 1)
    out = sum(taps.weights[:, k].reshape(shape) * moved[taps.starts + k] for k in range(taps.count))
    return np.moveaxis(out, 0, axis)


def resize_reference(image: np.ndarray, out_h: int, out_w: int) -> np.ndarray:
    """The NumPy reference: H x W x C linear ``image`` to out_h x out_w x C, float64; horizontal
    pass, then vertical (the kernels' order)."""
    h, w = image.shape[:2]
    rows = resample_axis(image, filter_taps(w, out_w), axis=1)
    return resample_axis(rows, filter_taps(h, out_h), axis=0)


@dataclass
class ResizedRows:
    """Output rows ``y0 .. y0 + len(rows)`` from one :meth:`StreamingResize.push`: ``rows`` holds
    them once :meth:`wait` returns (the device copies them in); until then the device may still
    read the pushed input rows."""

    y0: int
    rows: np.ndarray
    event: Any = None
    keep: tuple = field(default_factory=tuple)

    def wait(self) -> None:
        if self.event is not None:
            self.event.wait()
        self.keep = ()


class StreamingResize:
    """Rows of an image in, rows of the resized image out, on the device, in order.

    ``source``: (height, width) of the image to resize; ``target``: (out_h, out_w); ``output``:
    'linear' (float32), 'srgb' (encoded float32), 'srgb16' or 'srgb8' (16- or 8-bit codes), the tone curve
    applied after the resampling. ``offset``: (top, left) of the image inside the rows pushed
    (a crop: pushed rows are that many rows and columns larger; the rest is dropped).
    :meth:`push` enqueues and returns at once; every call comes from one thread (the runtime's
    buffer pool is not shared between threads). :meth:`close` releases the device window.
    """

    def __init__(self, rt: Runtime, source: tuple[int, int], target: tuple[int, int], output: str = "linear",
                 offset: tuple[int, int] = (0, 0)) -> None:
        if output not in OUTPUTS:
            raise ClispError(f"unknown output {output!r}; expected one of {', '.join(OUTPUTS)}")
        self.rt = rt
        self.in_h, self.in_w = (int(v) for v in source)
        self.out_h, self.out_w = (int(v) for v in target)
        self.top, self.left = (int(v) for v in offset)
        self.tone = tone_curve_for(output, interleaved=True)
        self.out_dtype = np.dtype(np.float32) if self.tone is None else self.tone.out_dtype
        self.defines = {"INTERLEAVED": int(self.tone is None)}     # resize_columns' output layout
        self.rows = filter_taps(self.in_w, self.out_w)
        self.columns = filter_taps(self.in_h, self.out_h)
        self._tables = [rt.constant(t.starts.astype(np.int32)) for t in (self.rows, self.columns)] + \
                       [rt.constant(t.weights.astype(np.float32)) for t in (self.rows, self.columns)]
        self._ends = self.columns.starts.astype(np.int64) + self.columns.count   # rows output i needs
        self.capacity = 2 * self.columns.count + CHUNK_ROWS
        self.window: DeviceImage | None = None
        self.base = 0             # image row held in window row 0
        self.have = 0             # image rows received
        self.next_row = 0         # first output row not computed

    @property
    def window_bytes(self) -> int:
        """Bytes of the device window (what a run holds besides its output rows)."""
        return self.capacity * 3 * self.out_w * 4

    def computable(self, have: int) -> int:
        """The output rows 0 .. n - 1 whose input rows are among the first ``have``: n."""
        return int(np.searchsorted(self._ends, have, side="right"))

    def push(self, rows: np.ndarray, y0: int) -> ResizedRows:
        """Enqueue rows ``y0 ..`` (h x W x 3 float32, W = the image's width plus the offset's
        columns and more) and return the output rows they complete. Rows must follow each other."""
        rt = self.rt
        a, b = max(y0, self.top), min(y0 + rows.shape[0], self.top + self.in_h)
        first = self.next_row
        if a >= b:
            return ResizedRows(first, np.empty((0, self.out_w, 3), self.out_dtype))
        if a - self.top != self.have:
            raise ClispError(f"resize: rows from {a - self.top} pushed after {self.have}")
        stage_label("resize")
        host = np.ascontiguousarray(rows, dtype=np.float32)
        flat = host.reshape(host.shape[0], -1)
        src = rt.host_input(flat) or rt.upload(flat)
        if self.window is None:
            self.window = rt.acquire(3, self.capacity, self.out_w)
        out = np.empty((self.computable(b - self.top) - first, self.out_w, 3), self.out_dtype)
        starts_x, starts_y, weights_x, weights_y = self._tables
        for r in range(a, b, CHUNK_ROWS):
            count = min(CHUNK_ROWS, b - r)
            self._make_room(count)
            rt.launch_named("resize", "resize_rows", self.out_w, count, dict(
                src=src, dst=self.window, starts=starts_x, weights=weights_x, taps=self.rows.count,
                src_stride=flat.shape[1], src_x0=self.left, src_row0=r - y0, dst_width=self.out_w,
                dst_row0=self.have - self.base), self.defines)
            self.have += count
            end = self.computable(self.have)
            if end > self.next_row:
                self._columns(self.next_row, end, out, first, starts_y, weights_y)
                self.next_row = end
        if src.host is None:
            rt.release(src)                   # the in-order queue reads it before any reuse
        event = rt.cl.enqueue_marker(rt.queue)
        rt.queue.flush()
        return ResizedRows(first, out, event, (host, src))

    def _make_room(self, count: int) -> None:
        """Move the rows still needed to the window's top when ``count`` more would not fit. Fewer
        than the vertical taps are needed (the next output row's), and they lie more than that
        far down, so the copy never overlaps itself."""
        if self.have - self.base + count <= self.capacity:
            return
        keep = int(self.columns.starts[self.next_row]) if self.next_row < self.out_h else self.have
        row_bytes = 3 * self.out_w * 4
        if self.have > keep:
            self.rt.cl.enqueue_copy(self.rt.queue, self.window.buffer, self.window.buffer,
                                    byte_count=(self.have - keep) * row_bytes,
                                    src_offset=(keep - self.base) * row_bytes, dst_offset=0)
        self.base = keep

    def _columns(self, j0: int, j1: int, out: np.ndarray, first: int, starts: Any, weights: Any) -> None:
        """Output rows j0 .. j1 - 1: the vertical pass, the tone curve, the copy into ``out``."""
        rt, n = self.rt, j1 - j0
        dst = rt.acquire(3, n, self.out_w)
        rt.launch_named("resize", "resize_columns", self.out_w, n, dict(
            window=self.window, dst=dst, starts=starts, weights=weights, taps=self.columns.count,
            width=self.out_w, window_row0=self.base, out_row0=j0, out_rows=n),
            self.defines)
        if self.tone is not None:
            planar, dst = dst, self.tone.enqueue(rt, dst, (0, 0))
            rt.release(planar)
        else:
            dst.interleaved = True
        rt.download_region(dst, out, j0 - first, 0, n, self.out_w)
        rt.release(dst)

    def close(self) -> None:
        """Give the window back to the runtime's pool (after the last push's event)."""
        if self.window is not None:
            self.rt.release(self.window)
            self.window = None


def resize_image(image: np.ndarray, out_h: int, out_w: int, output: str = "linear", rt: Runtime | None = None,
                 band: int = 256, write: Callable[[int, np.ndarray], None] | None = None) -> np.ndarray | None:
    """An H x W x 3 linear image resized on the device to out_h x out_w x 3 (``output`` as
    :class:`StreamingResize`), pushed ``band`` rows at a time. ``write(y0, rows)``: hand the output
    rows on as they come (returns None) instead of returning the whole output."""
    rt = rt or get_runtime()
    resizer = StreamingResize(rt, image.shape[:2], (out_h, out_w), output)
    out = None if write is not None else np.empty((out_h, out_w, 3), resizer.out_dtype)
    try:
        for y0 in range(0, image.shape[0], band):
            part = resizer.push(image[y0:y0 + band], y0)
            part.wait()
            if write is not None:
                if len(part.rows):
                    write(part.y0, part.rows)
            else:
                out[part.y0:part.y0 + len(part.rows)] = part.rows
    finally:
        rt.queue.finish()
        resizer.close()
    return out


class ResizeSink(BandSink):
    """A :class:`BandSink` whose complete bands go through a :class:`StreamingResize` (enqueued
    on the thread that runs the tiles, as every other launch) and whose writer thread writes the
    resized rows with ``write(y0, rows)`` once the device has copied them out. The band buffers are
    page-aligned, so a device that shares host memory reads them in place (Runtime.host_input).
    A band's buffer is reused only after its resized rows were written, hence after the device
    read it."""

    def __init__(self, write: Callable[[int, np.ndarray], None], plan: TilePlan, width: int,
                 resizer: StreamingResize) -> None:
        super().__init__(write, plan, width, 3, np.float32)
        self.resizer = resizer
        nbytes = int(np.prod(self.shape)) * 4
        self.buffers = [aligned_empty(nbytes).view(np.float32).reshape(self.shape) for _ in self.buffers]

    def done(self, tile: Tile) -> None:
        self.left[tile.y0] -= 1
        if self.left[tile.y0] == 0:
            slot = self._slot(tile)
            resized = self.resizer.push(self.buffers[slot][:tile.h], tile.y0)
            self.pending[slot] = self.executor.submit(self._write_resized, resized)

    def _write_resized(self, resized: ResizedRows) -> None:
        resized.wait()
        if len(resized.rows):
            self.write(resized.y0, resized.rows)
