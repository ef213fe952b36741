"""Running a pipeline: :func:`process` (the public API: a raw to an image in memory) and
:func:`process_file` (the CLI's path: a raw to a file, streamed in bands), with the crops,
orientation and output encodings they share.
"""
from __future__ import annotations

import time
from contextlib import closing, nullcontext
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from .build import HALF_SIZE_DOWNSCALE, build_pipeline
from ..errors import ClispError
from ..io.exif import output_attributes
from ..io.rawfile import read_raw
from ..io.rawimage import RawImage
from ..engine.executor import DEFAULT_BUDGET, Pipeline, RunStats, device_limits
from ..engine.runtime import DEVICE_LOCK, get_runtime
from ..engine.streaming import BandSink, array_sink, progress_bar, window_source
from ..engine.tiling import MIN_TILE, TilePlan, make_plan
from ..modules.colour.stage import tone_curve_for
from ..modules.resize.stage import (ResizeSink, StreamingResize, check_long_edge, resize_image, resize_reference,
                                    resized_size)


FILES_IN_FLIGHT = 2
"""Files one process has under way at once on a device that shares host memory (``clisp process
RAW... -o OUTDIR``): one on the device while the other is decoded or its last bands written and
the file closed (clisp.engine.runtime.DEVICE_LOCK lets one thread at a time on the device).
Twelve 3 MP Bayer raws to TIFF on 2 PoCL cores: quality 4.4-5.3 s against 5.1-6.3 s one at a
time, fast 0.35-0.46 against 0.37-0.46 (docs/RESULTS.md, issue 41)."""

GPU_FILES_IN_FLIGHT = 3
"""The same on a discrete device, and the threads of a ``clisp batch`` worker there: decode the
next, run this one, write the last, on the host's cores while the GPU runs."""


def orient(image: np.ndarray, flip: int) -> np.ndarray:
    """Apply LibRaw's ``sizes.flip`` code (0 none, 3 180 degrees, 5 90 CCW, 6 90 CW) to H x W x C."""
    if flip == 3:
        return image[::-1, ::-1]
    if flip == 5:
        return np.rot90(image, 1)
    if flip == 6:
        return np.rot90(image, -1)
    return image


def crop_of(raw: RawImage) -> tuple[int, int, int, int] | None:
    """The crop ``raw`` declares, (top, left, height, width) in its mosaic's coordinates
    (``metadata['crop']``: a DNG's DefaultCrop, see clisp.io.camera), or None for the whole mosaic
    (none declared, or one that does not lie inside the mosaic)."""
    crop = raw.metadata.get("crop")
    try:
        top, left, height, width = (int(v) for v in crop)
    except (TypeError, ValueError):
        return None
    h, w = raw.shape
    if top < 0 or left < 0 or height <= 0 or width <= 0 or top + height > h or left + width > w:
        return None
    return None if (top, left, height, width) == (0, 0, h, w) else (top, left, height, width)


def output_crop(crop: tuple[int, int, int, int] | None, pipeline: Pipeline,
                shape: tuple[int, int]) -> tuple[int, int, int, int] | None:
    """``crop`` (:func:`crop_of`, in the mosaic of ``shape``) on ``pipeline``'s output: the same for a
    pipeline that keeps the grid; with ``--half-size`` (downscale 2) the output pixels whose blocks
    hold any of it (an even crop, the usual, halves exactly).

    >>> from clisp.cfa import bayer_cfa
    >>> from clisp.modules.half_size.stage import HalfSize
    >>> output_crop((12, 8, 100, 61), Pipeline(bayer_cfa(), [HalfSize(bayer_cfa(), [0] * 3, [1] * 3)]), (200, 100))
    (6, 4, 50, 31)
    """
    return scaled_crop(crop, pipeline.downscale, shape)


def scaled_crop(crop: tuple[int, int, int, int] | None, s: int,
                shape: tuple[int, int]) -> tuple[int, int, int, int] | None:
    """``crop`` in the mosaic of ``shape`` on an output ``s`` times smaller (rounded up, as
    Pipeline.output_shape): the output pixels whose blocks hold any of it.

    >>> scaled_crop((12, 8, 100, 61), 2, (200, 100))
    (6, 4, 50, 31)
    """
    if crop is None or s == 1:
        return crop
    top, left, height, width = crop
    out_h, out_w = -(-int(shape[0]) // s), -(-int(shape[1]) // s)
    bottom, right = min(-(-(top + height) // s), out_h), min(-(-(left + width) // s), out_w)
    return top // s, left // s, bottom - top // s, right - left // s


def cropped_writes(write: Callable[[int, np.ndarray], None],
                   crop: tuple[int, int, int, int]) -> Callable[[int, np.ndarray], None]:
    """``write(y0, rows)`` of a band sink for the whole mosaic's rows, passing on only the crop's
    rows and columns, renumbered from the crop's top. The pipeline runs on the whole mosaic (the
    crop's border pixels see their real neighbours, and tiled still equals whole), the output
    holds the crop; memory stays one band."""
    top, left, height, width = crop

    def write_cropped(y0: int, rows: np.ndarray) -> None:
        a, b = max(y0, top), min(y0 + rows.shape[0], top + height)
        if a < b:
            write(a - top, rows[a - y0:b - y0, left:left + width])
    return write_cropped


def output_size(raw: RawImage, crop: bool = True, half_size: bool = False) -> tuple[int, int]:
    """(height, width) of the image :func:`process_file` makes of ``raw`` before any resize: the
    crop the raw declares (:func:`crop_of`; with ``crop`` False the whole mosaic), halved with
    ``half_size`` (:func:`scaled_crop`), turned upright."""
    s = HALF_SIZE_DOWNSCALE if half_size else 1
    region = scaled_crop(crop_of(raw) if crop else None, s, raw.shape)
    height, width = (-(-raw.shape[0] // s), -(-raw.shape[1] // s)) if region is None else region[2:]
    return (width, height) if int(raw.metadata.get("flip", 0) or 0) in (5, 6) else (height, width)


def _crop_image(image: np.ndarray, crop: tuple[int, int, int, int] | None) -> np.ndarray:
    if crop is None:
        return image
    top, left, height, width = crop
    return image[top:top + height, left:left + width]


def process_with_stats(raw: RawImage, tile: int | None = None, backend: str = "opencl", crop: bool = True,
                       **options: Any) -> tuple[np.ndarray, RunStats]:
    """:func:`process` for a RawImage, also returning the run's timing."""
    with DEVICE_LOCK:                                # one thread at a time builds and runs on the device
        pipeline = build_pipeline(raw, **options)
        image = pipeline.run(raw.data, tile=tile, backend=backend)
    image = _crop_image(image, output_crop(crop_of(raw), pipeline, raw.shape) if crop else None)
    image = np.ascontiguousarray(orient(image, int(raw.metadata.get("flip", 0) or 0)))
    return image, pipeline.stats


def process(raw: RawImage | str | Path, tile: int | None = None, backend: str = "opencl", crop: bool = True,
            **options: Any) -> np.ndarray:
    """Process a raw image (or a raw file's path) into H x W x 3 float32 sRGB.

    ``options`` are :func:`build_pipeline`'s: preset, demosaic, output ('linear': scene-linear
    sRGB, white 1.0, unclipped; 'srgb': sRGB-encoded in [0, 1]), denoise, wb2.
    ``crop``: keep only the crop the raw declares (:func:`crop_of`, a DNG's DefaultCrop); False
    keeps the whole mosaic. Orientation from camera metadata is applied last. ``half_size=True``:
    half the width and height, one pixel per 2 x 2 block, no demosaic (:func:`build_pipeline`).
    """
    if not isinstance(raw, RawImage):
        raw = read_raw(raw)
    return process_with_stats(raw, tile, backend, crop, **options)[0]


def process_file(raw: RawImage, path: str | Path, tile: int | None = None, budget: int = DEFAULT_BUDGET,
                 backend: str = "opencl", progress: bool = False, compression: str | None = None,
                 explain: dict | None = None, crop: bool = True, resize: int | None = None,
                 **options: Any) -> tuple[tuple[int, int], RunStats]:
    """Process ``raw`` into the image file ``path`` (EXR linear, TIFF/PNG sRGB-encoded), streaming.

    Tile windows are read as needed (from disk for ``read_raw(path, lazy=True)``) and results
    written band by band (imageio.ImageWriter). ``budget`` bounds the peak resident memory of the
    whole process (clisp.engine.memory): what the process holds when planning, plus the tiles' counted
    bytes, plus RSS_MARGIN; ClispError when even the smallest tile does not fit, naming the
    minimum. Raws with a camera rotation are oriented in memory (the whole output counts).
    ``progress``: a progress bar on stderr (when it is a terminal). ``compression``: EXR/TIFF
    compression (default imageio.DEFAULT_COMPRESSION). ``options``: :func:`build_pipeline`'s
    (the output kind follows the extension). ``explain``: a dict that receives the pipeline
    (key 'pipeline'), whose skipper and skip_plan describe the run. ``crop``: write only the crop
    the raw declares (:func:`crop_of`; the whole mosaic is processed, see :func:`cropped_writes`);
    False writes the whole mosaic. ``resize``: the output's long edge in pixels (``--resize``;
    never enlarged, see clisp.modules.resize): the pipeline ends in linear light and the resizer
    low-passes and samples the rows on the device, then applies the output's tone curve. The
    output carries the raw's metadata (clisp.io.exif.output_attributes). Atomic: on failure no file.
    Returns the output's (height, width) and the run's stats.
    """
    from ..io.imageio import DEFAULT_COMPRESSION, ImageWriter, output_kind, write_image   # deferred: 2 ms of start-up
    compression = compression or DEFAULT_COMPRESSION
    attributes = output_attributes(raw)
    kind = output_kind(path)
    encoding = encoded_output(path) if kind == "srgb" else kind
    scale = HALF_SIZE_DOWNSCALE if options.get("half_size") else 1
    region = scaled_crop(crop_of(raw), scale, raw.shape) if crop else None
    upright = output_size(raw, crop, options.get("half_size", False))
    target = upright if resize is None else resized_size(*upright, check_long_edge(resize))
    resized = target != upright
    flip = int(raw.metadata.get("flip", 0) or 0)
    in_memory = bool(flip) or (resized and backend != "opencl")
    with DeviceHold() as hold:        # the device's part; decoding and writing run outside (DEVICE_LOCK)
        pipeline = build_pipeline(raw, output="linear" if resized else encoding, **options)
        notes = []                                                           # what was applied, in the file
        if options.get("wb", "camera") != "camera":
            notes.append(f"white balance {pipeline.wb_source} (clisp)")
        if options.get("exposure") or options.get("auto_exposure"):
            how = ", auto" if options.get("auto_exposure") else ""
            notes.append(f"exposure {pipeline.exposure_ev:+.2f} EV (clisp{how})")
        if resized:                                   # the size it had, in the file (no EXIF size is written)
            notes.append(f"resized from {upright[1]}x{upright[0]} to {target[1]}x{target[0]} "
                         f"(clisp, Lanczos-3 in linear light)")
        if notes:
            attributes["ImageDescription"] = "; ".join(filter(None, [attributes.get("ImageDescription"), *notes]))
        if explain is not None:                       # the caller reads the plan after the run
            explain["pipeline"] = pipeline
        resizer = StreamingResize(get_runtime(), upright, target, encoding, offset=region[:2] if region else (0, 0)) \
            if resized and not in_memory else None
        plan = _whole_process_plan(pipeline, raw, path, tile, budget, backend, in_memory=in_memory,
                                   extra=2 * resizer.window_bytes if resizer else 0)
        if in_memory:               # rotated output rows are input columns: orient the whole result
            image = np.empty(pipeline.output_shape(raw.shape) + (pipeline.out_channels,), dtype=pipeline.out_dtype)
            sink = array_sink(image, get_runtime() if backend == "opencl" else None)
            with closing(window_source(raw.data)) as source, closing(sink):
                pipeline.stream(source, sink, plan, backend)
            oriented = orient(_crop_image(image, region), flip)
            if resized:
                _write_resized(path, oriented, target, encoding, backend, compression, attributes)
            else:
                hold.release()
                write_image(path, oriented, compression=compression, attributes=attributes)
            return target, pipeline.stats
        (height, width), channels = pipeline.output_shape(raw.shape), pipeline.out_channels
        out_h, out_w = target
        bar = progress_bar(plan.tiles, Path(path).name) if progress else nullcontext(None)
        start = time.perf_counter()
        with closing(window_source(raw.data)) as source, closing(resizer) if resizer else nullcontext(), \
                ImageWriter(path, out_w, out_h, channels, compression, attributes) as writer, \
                (ResizeSink(writer.write_rows, plan, width, resizer) if resizer else
                 BandSink(writer.write_rows if region is None else cropped_writes(writer.write_rows, region),
                          plan, width, channels, pipeline.out_dtype, staging=_band_staging(backend))) as sink, \
                bar as update:
            stats = pipeline.stream(source, sink, plan, backend, progress=update)
            if resizer is None:
                hold.release()                  # the bands left to write and the file's close need no device
        return (out_h, out_w), replace(stats, seconds=time.perf_counter() - start)    # the last write included


class DeviceHold:
    """This thread's hold of DEVICE_LOCK, taken on entering; :meth:`release` gives it up early
    (once; leaving the block then does nothing), so that process_file's device work can end before
    its file is written and closed."""

    def __enter__(self) -> "DeviceHold":
        DEVICE_LOCK.acquire()
        self.held = True
        return self

    def release(self) -> None:
        if self.held:
            self.held = False
            DEVICE_LOCK.release()

    def __exit__(self, *exc: object) -> None:
        self.release()


def _band_staging(backend: str) -> Any:
    """Where process_file's output bands come from: the runtime's pinned staging buffers on a
    discrete device (the downloads' destination, reused across files); None (plain arrays) on a
    device sharing host memory, whose last kernel writes into the band itself."""
    if backend != "opencl":
        return None
    rt = get_runtime()
    return None if rt.host_unified else rt.staging


def encoded_output(path: str | Path) -> str:
    """The pipeline output an sRGB-encoded file takes: 8-bit codes for JPEG ('srgb8'), 16-bit codes
    for TIFF and PNG ('srgb16').

    >>> encoded_output("a.JPG"), encoded_output("b.tif")
    ('srgb8', 'srgb16')
    """
    from ..io.imageio import JPEG_EXTENSIONS       # deferred, as in process_file
    return "srgb8" if Path(path).suffix.lower() in JPEG_EXTENSIONS else "srgb16"


def _write_resized(path: str | Path, image: np.ndarray, target: tuple[int, int], encoding: str, backend: str,
                   compression: str, attributes: dict) -> None:
    """Write the linear H x W x 3 ``image`` resized to ``target`` (height, width) in ``encoding``
    ('linear', 'srgb16', 'srgb8'): on the device, band by band into the file; the NumPy reference (and
    ToneCurve's) for ``backend`` 'reference'."""
    from ..io.imageio import ImageWriter, write_image   # deferred, as in process_file
    if backend != "opencl":
        pixels = resize_reference(image, *target)
        if encoding != "linear":
            pixels = tone_curve_for(encoding).reference(pixels, (0, 0))
        write_image(path, pixels, compression=compression, attributes=attributes)
        return
    with ImageWriter(path, target[1], target[0], 3, compression, attributes) as writer:
        resize_image(image, *target, output=encoding, write=writer.write_rows)


def _whole_process_plan(pipeline: Pipeline, raw: RawImage, path: str | Path, tile: int | None, budget: int,
                        backend: str, in_memory: bool, extra: int = 0) -> TilePlan:
    """The plan of :func:`process_file` for a whole-process ``budget`` (see clisp.engine.memory): the
    tiles get what the process does not already hold. ``in_memory``: the whole output is held
    (oriented raws) and counts too; ``extra``: bytes held besides (the resizer's device window).
    ClispError naming the minimum when nothing fits."""
    from ..engine.memory import RSS_MARGIN, format_bytes, resident_bytes   # deferred: 0.6 ms (with resource)
    shape, dtype = raw.shape, raw.data.dtype
    if backend != "opencl":
        return pipeline.plan(shape, dtype, tile, budget, backend)
    limits = device_limits(backend)
    out_h, out_w = pipeline.output_shape(shape)           # the tiles' (the raw's unless --half-size)
    cost = pipeline.tile_cost(dtype, out_w, limits, sink_bands=not in_memory)
    smallest = cost(min(out_h, MIN_TILE), min(out_w, MIN_TILE))   # also builds the programs
    held = resident_bytes() + RSS_MARGIN + extra
    if in_memory:
        held += out_h * out_w * pipeline.out_channels * pipeline.out_dtype.itemsize
    if budget - held < smallest:
        raise ClispError(f"{path}: --mem {format_bytes(budget)} is below the minimum of "
                         f"{format_bytes(held + smallest)} for this {shape[1]}x{shape[0]} raw and these "
                         f"settings ({format_bytes(held)} for the process itself, "
                         f"{format_bytes(smallest)} for the smallest tile)")
    needs = replace(pipeline.needs(dtype), cost=cost)
    try:
        return make_plan(out_h, out_w, needs, tile, budget - held, limits)
    except ClispError as exc:
        raise ClispError(f"{path}: {exc}") from exc
