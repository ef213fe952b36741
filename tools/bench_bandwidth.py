"""How close the per-pixel path comes to this machine's streaming bandwidth (issue 11).

The ``fast`` preset is one fused per-pixel kernel (normalise, WB, bilinear demosaic, colour
matrix, tone curve): its speed limit is moving bytes. This tool measures, in one process:

* the streaming bandwidth through the OpenCL device: a copy kernel over 256 MiB (bytes read +
  bytes written per second), and NumPy's single-threaded copy for reference; the ratio uses the
  best copy-kernel run of those interleaved with the pipeline's runs (on a shared machine a
  bandwidth measured once, before, sees another load than the runs it is compared with);
* the ``fast`` pipeline on a 24 MP mosaic in memory, processing only (no file read or write):
  the tile loop of ``clisp process`` (reader thread, upload, kernels, download into the band
  buffers, a writer that does nothing), for linear float output (EXR) and 16-bit codes (TIFF).
  Bytes counted as the copy kernel's are, every byte read plus every byte written: each upload
  and download (a copy reads and writes its bytes: twice its size) and each kernel's input and
  output window, tallied during the warm-up run; per second of wall time, best of ``--repeat``
  runs after that warm-up. Where the device gathers each window from the mosaic in host memory
  (Runtime.gather_window) that copy is the upload. Where the last kernel writes straight into the host's band buffers
  (a device sharing host memory: Runtime.host_image) there is no download to count.

Usage::

    python tools/bench_bandwidth.py [--size 6000x4000] [--repeat 5] [--raw RAW.dng]

Without ``--raw`` the mosaic is a simulated Bayer raw of the built-in chart, repeated.
"""
from __future__ import annotations

import argparse
import platform
import time
from typing import Callable

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path


def copy_bandwidth(rt, nbytes: int = 256 * 2**20, repeat: int = 5) -> float:
    """Bytes read + written per second by a float copy kernel on the device."""
    cl = rt.cl
    n = nbytes // 4
    a = cl.Buffer(rt.context, cl.mem_flags.READ_WRITE, n * 4)
    b = cl.Buffer(rt.context, cl.mem_flags.READ_WRITE, n * 4)
    kernel = cl.Kernel(cl.Program(rt.context, "__kernel void copy(__global const float *a, __global float *b)"
                                              "{ const int i = get_global_id(0); b[i] = a[i]; }").build(), "copy")

    def once() -> None:
        kernel(rt.queue, (n,), (64,), a, b)
        rt.queue.finish()
    _, best = toolkit.best_of(once, repeat, warmup=True)
    return 2 * n * 4 / best


def numpy_bandwidth(nbytes: int = 256 * 2**20, repeat: int = 5) -> float:
    """Bytes read + written per second by np.copyto on one thread."""
    src, dst = np.ones(nbytes // 4, np.float32), np.zeros(nbytes // 4, np.float32)
    _, best = toolkit.best_of(lambda: np.copyto(dst, src), repeat)
    return 2 * nbytes / best


def test_raw(size: tuple[int, int], path: str | None):
    """A Bayer RawImage of ``size`` (W, H): the file's mosaic tiled, or the chart simulated."""
    from dataclasses import replace
    import clisp
    from clisp.sim.charts import demo_chart
    from clisp.io.rawfile import read_raw
    if path:
        raw = read_raw(path)
    else:
        raw = clisp.simulate(demo_chart().image, cfa="bayer", gain=1, seed=0).raw
    h, w = (s - s % 2 for s in raw.shape)
    from clisp.engine.streaming import aligned_copy           # as clisp's camera reader allocates it
    data = aligned_copy(toolkit.repeat_to(raw.data[:h, :w], size[1], size[0]))
    return replace(raw, data=data, metadata={})


def counted_traffic(pipeline, rt) -> tuple[dict[str, int], object]:
    """A tally of bytes read + written (upload, kernels, download) and a function undoing the
    counting wrappers: rt.upload and rt.download_region count their copies (rt.host_input, where
    the device reads the window in place, the reader's copy into it; rt.gather_window, where the
    device gathers the window from the whole mosaic in host memory, that copy), every stage of the
    pipeline's schedule its input and output windows."""
    tally = {"upload": 0, "kernels": 0, "download": 0}
    upload, host_input, download, schedule = rt.upload, rt.host_input, rt.download_region, pipeline.schedule
    gather = rt.gather_window

    def counted_gather(whole, y0, x0, h, w, period):   # the device copies the window out of the
        image = gather(whole, y0, x0, h, w, period)     # mosaic it reads in place: the upload
        tally["upload"] += 2 * image.nbytes
        return image

    def counted_upload(array):
        tally["upload"] += 2 * array.nbytes
        return upload(array)

    def counted_host_input(array):                  # read in place: the reader's gather into the
        image = host_input(array)                   # window was the copy to the device's memory
        if image is not None:
            tally["upload"] += 2 * array.nbytes
        return image

    def counted_download(image, into, y0, x0, rows, cols):
        tally["download"] += 2 * rows * cols * image.channels * np.dtype(image.dtype).itemsize
        return download(image, into, y0, x0, rows, cols)

    def counted_schedule(fuse=True):
        stages = schedule(fuse)
        for stage in stages:
            def enqueue(rt_, src, origin, *args, _enqueue=stage.enqueue, **kwargs):
                dst = _enqueue(rt_, src, origin, *args, **kwargs)
                tally["kernels"] += src.nbytes + dst.nbytes
                return dst
            stage.enqueue = enqueue
        return stages

    rt.upload, rt.host_input, rt.download_region = counted_upload, counted_host_input, counted_download
    rt.gather_window = counted_gather
    pipeline.schedule = counted_schedule

    def undo() -> None:
        rt.upload, rt.host_input, rt.download_region, rt.gather_window = upload, host_input, download, gather
        del pipeline.schedule
    return tally, undo


def pipeline_bandwidth(raw, output: str, repeat: int, copy: Callable[[], float]
                       ) -> tuple[float, float, dict[str, int], str]:
    """(seconds, copy bandwidth, bytes moved by kind, plan) of the fast pipeline's tile loop: best of
    ``repeat`` runs, each followed by a run of ``copy`` (the device's copy kernel; best taken), so
    that both see the same load on a shared machine."""
    from clisp.pipeline import build_pipeline
    from clisp.engine.runtime import get_runtime
    from clisp.engine.streaming import ArrayWindows, BandSink
    pipeline = build_pipeline(raw, preset="fast", output=output)
    width = raw.shape[1]
    plan = pipeline.plan(raw.shape, raw.data.dtype, sink_bands=True)
    with BandSink(lambda y, rows: None, plan, width, pipeline.out_channels, pipeline.out_dtype) as sink:
        tally, undo = counted_traffic(pipeline, get_runtime())
        try:
            pipeline.stream(ArrayWindows(raw.data), sink, plan)     # warm-up, counted
        finally:
            undo()
        best, bandwidth = np.inf, 0.0
        for _ in range(repeat):
            start = time.perf_counter()
            pipeline.stream(ArrayWindows(raw.data), sink, plan)
            best = min(best, time.perf_counter() - start)
            bandwidth = max(bandwidth, copy())
    return best, bandwidth, tally, f"{len(plan.tiles)} tiles of {plan.tile_w}x{plan.tile_h}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=toolkit.parse_size, default=(6000, 4000), metavar="WxH",
                        help="mosaic W x H (default 6000x4000)")
    toolkit.add_repeat_option(parser, 5, "timed runs, best taken")
    parser.add_argument("--raw", default=None, help="a Bayer raw whose mosaic is tiled (default: simulated chart)")
    args = parser.parse_args()
    from clisp.engine.runtime import get_runtime
    size = args.size
    rt = get_runtime()
    print(f"machine: {platform.processor() or platform.machine()}, device: {rt.describe()}")
    device_bw, host_bw = copy_bandwidth(rt), numpy_bandwidth()
    print(f"streaming bandwidth: device copy kernel {device_bw / 1e9:.1f} GB/s, NumPy copy (1 thread) "
          f"{host_bw / 1e9:.1f} GB/s")
    raw = test_raw(size, args.raw)
    mp = raw.data.size / 1e6
    for output, label in (("linear", "float RGB (EXR)"), ("srgb16", "16-bit codes (TIFF)")):
        seconds, bandwidth, tally, plan = pipeline_bandwidth(raw, output, args.repeat,
                                                             lambda: copy_bandwidth(rt, repeat=1))
        moved = sum(tally.values())
        rate = moved / seconds
        parts = ", ".join(f"{kind} {n / 1e6:.0f}" for kind, n in tally.items())
        print(f"fast -> {label}: {seconds * 1e3:.0f} ms for {mp:.1f} MP ({mp / seconds:.0f} MP/s); moved "
              f"{moved / 1e6:.0f} MB ({parts}), {rate / 1e9:.1f} GB/s = {rate / bandwidth:.2f} x the "
              f"device's streaming bandwidth ({bandwidth / 1e9:.1f} GB/s, copy kernel between runs; {plan})")


if __name__ == "__main__":
    main()
