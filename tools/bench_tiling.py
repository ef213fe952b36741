"""Throughput of tiled against whole-image processing, in the same run (issue 6 acceptance).

    python tools/bench_tiling.py [--size 5760x4320] [--cfa lms] [--repeat 3] [--sweep] [--file]

For every preset: the whole image as one tile (``tile=0``) and the automatic plan (``tile=None``,
1 GiB budget) on the same in-memory raw, warm, best of ``--repeat`` runs each, interleaved so
drift hits both alike (array API: each run allocates its output); prints MP/s and the ratio. ``--sweep`` adds full-width bands of several
sizes (the figures behind tiling.TARGET_TILE_PIXELS); ``--file`` adds the streamed
``process_file`` run (DNG on disk -> zip EXR) for the default preset.
The raw is the demo chart simulated at gain 8, its mosaic repeated to the size.
"""
from __future__ import annotations

import argparse
import os
import platform
import tempfile
from functools import partial
from pathlib import Path

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path
from toolkit import best_times

from clisp.sim.charts import demo_chart
from clisp.pipeline import DEFAULT_PRESET, PRESETS, build_pipeline, process_file
from clisp.io.rawfile import read_raw, write_raw
from clisp.io.rawimage import RawImage
from clisp.engine.runtime import get_runtime
from clisp.sim.simulate import simulate
from clisp.engine.streaming import ArraySink, ArrayWindows
from clisp.engine.tiling import TilePlan, even_split, grid

SWEEP_MP = (0.5, 1, 2, 4, 8, 16)
"""Band sizes of --sweep, in megapixels."""


def machine() -> str:
    """CPU model, cores and memory of this machine."""
    model = toolkit.cpu_model(lambda: platform.processor() or platform.machine())
    return f"{model}, {os.cpu_count()} cores, {toolkit.total_memory_gib():.0f} GiB, {platform.system()} {platform.release()}"


def big_raw(cfa: str, width: int, height: int) -> RawImage:
    """The demo chart simulated at gain 8, its mosaic repeated to height x width."""
    raw = simulate(demo_chart().image, cfa=cfa, gain=8, seed=1).raw
    raw.data = np.ascontiguousarray(toolkit.repeat_to(raw.data, height, width))
    return raw


def compare(raw: RawImage, preset: str, repeat: int) -> None:
    """Whole image against the automatic plan for one preset, through the array API (each run
    allocates its output, as a caller's would)."""
    pipeline = build_pipeline(raw, preset=preset)
    mp = raw.data.size / 1e6
    plan = pipeline.plan(raw.shape, raw.data.dtype)
    best = best_times({"whole": lambda: pipeline.run(raw.data, tile=0),
                        "tiled": lambda: pipeline.run(raw.data)}, repeat)
    w, t = mp / best["whole"], mp / best["tiled"]
    print(f"{preset:<12} whole {w:7.1f} MP/s   tiled {t:7.1f} MP/s "
          f"({len(plan.tiles)} tiles of {plan.tile_w}x{plan.tile_h})   tiled/whole {t / w:6.1%}")


def sweep(raw: RawImage, repeat: int) -> None:
    """Full-width bands of about SWEEP_MP megapixels (split evenly, as the planner does) against
    the whole image (default preset), into one preallocated output (so page faults of a fresh
    output do not hide the tiling cost)."""
    pipeline = build_pipeline(raw)
    height, width = raw.shape
    source, out = ArrayWindows(raw.data), np.empty(raw.shape + (3,), np.float32)
    runs = {}
    for band_mp in SWEEP_MP + (None,):
        rows = height if band_mp is None else even_split(height, int(band_mp * 1e6 / width), pipeline.align)
        plan = TilePlan(grid(height, width, rows, width), rows, width, pipeline.halo)
        label = "whole" if band_mp is None else f"{band_mp:g} MP"
        runs[f"bands of {label:>6} ({len(plan.tiles):3d} x {rows:5d} rows)"] = partial(
            pipeline.stream, source, ArraySink(out), plan)
    for name, seconds in best_times(runs, repeat).items():
        print(f"  {name}: {raw.data.size / 1e6 / seconds:7.1f} MP/s")


def file_run(raw: RawImage) -> None:
    """The streamed CLI path: DNG on disk -> zip-compressed EXR, default preset."""
    with tempfile.TemporaryDirectory(dir=os.environ.get("TMPDIR", "/tmp")) as tmp:
        path, out = Path(tmp) / "bench.dng", Path(tmp) / "bench.exr"
        write_raw(path, raw)
        shape, stats = process_file(read_raw(path, lazy=True), out)
        print(f"  file -> EXR: {stats.megapixels / stats.seconds:7.1f} MP/s "
              f"({stats.tiles} tiles of {stats.tile_shape[1]}x{stats.tile_shape[0]}, {stats.seconds:.1f} s)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--size", type=toolkit.parse_size, default=(5760, 4320), metavar="WxH",
                        help="WxH of the raw (default 5760x4320, 25 MP)")
    parser.add_argument("--cfa", default="lms", help="lms or bayer (presets that cannot use it are skipped)")
    toolkit.add_repeat_option(parser, 3, "timed runs of each variant, best counts")
    parser.add_argument("--sweep", action="store_true", help="also time full-width bands of several sizes")
    parser.add_argument("--file", action="store_true", help="also time the streamed DNG -> EXR path")
    args = parser.parse_args()
    width, height = args.size
    print(f"machine: {machine()}")
    print(f"device:  {get_runtime().describe()}")
    raw = big_raw(args.cfa, width, height)
    print(f"raw:     {width}x{height} {raw.cfa.name} uint16, {raw.data.size / 1e6:.1f} MP")
    for preset in PRESETS:
        try:
            compare(raw, preset, args.repeat)
        except Exception as exc:  # noqa: BLE001 - a preset for the other CFA kind
            print(f"{preset:<12} skipped: {exc}")
    if args.sweep:
        print(f"sweep ({DEFAULT_PRESET}):")
        sweep(raw, args.repeat)
    if args.file:
        file_run(raw)


if __name__ == "__main__":
    main()
