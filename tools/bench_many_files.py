"""Many raws through one `clisp process` against one process per raw (issue 29, item 4).

    python tools/bench_many_files.py [--count 100] [--size 1000x1000] [--cfa lms] [--gain 4]
                                     [--format tif] [--preset quality] [--repeat 2] [--work DIR]

--count raws of --size are simulated (clisp.sim.simulate, --gain, seed i for raw i) from a scene
made in code (the demo chart, repeated to the size) and written as our DNGs. Then, whole process
from the command line, the same outputs: ``clisp process RAW -o OUT`` once per raw, one after the
other, and ``clisp process RAW... -o OUTDIR --format F`` once for all of them. The single-process
run is repeated --repeat times, before and after the per-file runs (interleaved, median kept).
Printed: seconds, files/s and the ratio of the throughputs, and the CPU.
"""
from __future__ import annotations

import argparse
import shutil
import statistics
import sys
from pathlib import Path


import toolkit  # before clisp: puts this checkout on sys.path

from clisp.io.rawfile import write_raw
from clisp.sim.charts import demo_chart
from clisp.sim.simulate import simulate


def make_raws(folder: Path, count: int, width: int, height: int, cfa: str, gain: float) -> list[Path]:
    """``count`` DNGs of ``width`` x ``height`` in ``folder`` (seed i for raw i)."""
    scene = toolkit.repeat_to(demo_chart().image, height, width)
    paths = []
    for i in range(count):
        path = folder / f"raw{i:04d}.dng"
        write_raw(path, simulate(scene, cfa, gain=gain, seed=i).raw)
        paths.append(path)
    return paths


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--count", type=int, default=100)
    ap.add_argument("--size", default="1000x1000", help="W x H of each raw")
    ap.add_argument("--cfa", default="lms", choices=("lms", "bayer"))
    ap.add_argument("--gain", type=float, default=4.0)
    ap.add_argument("--format", default="tif", choices=("exr", "tif", "png"))
    ap.add_argument("--preset", default=None)
    toolkit.add_repeat_option(ap, 2, "single-process runs (median kept)")
    toolkit.add_work_option(ap)
    args = ap.parse_args(argv)
    width, height = toolkit.parse_size(args.size)
    preset = ["--preset", args.preset] if args.preset else []
    with toolkit.work_folder(args.work, "clisp-many-") as work:
        raws_dir = work / "raws"
        raws_dir.mkdir(exist_ok=True)
        raws = make_raws(raws_dir, args.count, width, height, args.cfa, args.gain)
        print(f"{args.count} {args.cfa} raws of {width}x{height} at gain {args.gain:g}; CPU: {toolkit.cpu_model()}", flush=True)

        def one_process() -> float:
            out = work / "one"
            shutil.rmtree(out, ignore_errors=True)
            run = toolkit.measure_process(toolkit.clisp_cmd("process", str(raws_dir), "-o", str(out),
                                                            "--format", args.format, *preset))
            written = len(list(out.glob(f"*.{args.format}"))) if out.is_dir() else 0
            if run.code != 0 or written != args.count:
                raise SystemExit(f"one process failed ({run.code}, {written} files): {toolkit.last_line(run.stderr)}")
            return run.wall_s

        def separate() -> float:
            out = work / "each"
            shutil.rmtree(out, ignore_errors=True)
            out.mkdir()
            total = 0.0
            for raw in raws:
                run = toolkit.measure_process(toolkit.clisp_cmd("process", str(raw), "-o",
                                                                str(out / f"{raw.stem}.{args.format}"), *preset))
                if run.code != 0:
                    raise SystemExit(f"{raw}: {toolkit.last_line(run.stderr)}")
                total += run.wall_s
            return total

        singles = [one_process() for _ in range(max(1, args.repeat // 2))]
        each = separate()
        singles += [one_process() for _ in range(max(1, args.repeat - len(singles)))]
        one = statistics.median(singles)
    n = args.count
    print(f"one process per raw : {each:8.1f} s  {n / each:6.2f} files/s")
    print(f"one process for all : {one:8.1f} s  {n / one:6.2f} files/s  (runs: {', '.join(f'{s:.1f}' for s in singles)})")
    print(f"throughput ratio    : {each / one:6.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
