"""The first `clisp process` after installing, against the runs after it (issue 29, item 1).

    python tools/bench_first_run.py RAW [--modes cold,warm,demo] [--preset quality] [--runs 3]

For each mode, with empty compile caches (a fresh ``POCL_CACHE_DIR`` and ``CLISP_CACHE_DIR`` in a
temporary folder, so this machine's own caches are left alone): the mode's set-up step, then
``clisp process RAW -o OUT.tif`` --runs times, each a whole process from the command line.

  cold   no set-up step: the first run compiles every kernel it needs
  warm   ``clisp info --device --warm`` first (the default and fast presets' kernels)
  demo   ``clisp demo`` first (the README's set-up command runs it)

Printed per mode: the set-up step's seconds, every run's seconds, and the first run over the
median of the others.
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
from pathlib import Path

import toolkit  # before clisp: puts this checkout on sys.path

MODES = {"cold": None, "warm": ("info", "--device", "--warm"), "demo": ("demo", "--out", "{tmp}/demo")}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("raw", type=Path)
    ap.add_argument("--modes", default="cold,warm,demo", help="of " + ", ".join(MODES))
    ap.add_argument("--preset", default=None)
    ap.add_argument("--runs", type=int, default=3, help="runs of clisp process per mode (the first is the first run)")
    args = ap.parse_args(argv)
    modes = [m for m in args.modes.split(",") if m]
    if any(m not in MODES for m in modes) or args.runs < 2:
        raise SystemExit(f"--modes from {', '.join(MODES)}; --runs at least 2")
    preset = ["--preset", args.preset] if args.preset else []
    print(f"{args.raw.name}; CPU: {toolkit.cpu_model()}")
    for mode in modes:
        with tempfile.TemporaryDirectory(prefix="clisp-first-") as tmp:
            env = dict(os.environ, POCL_CACHE_DIR=f"{tmp}/pocl", CLISP_CACHE_DIR=f"{tmp}/clisp")
            setup = 0.0
            if MODES[mode] is not None:
                run = toolkit.measure_process(toolkit.clisp_cmd(*(a.format(tmp=tmp) for a in MODES[mode])), env=env)
                if run.code != 0:
                    raise SystemExit(f"{mode}: set-up failed: {toolkit.last_line(run.stderr)}")
                setup = run.wall_s
            times = []
            for _ in range(args.runs):
                run = toolkit.measure_process(toolkit.clisp_cmd("process", str(args.raw.resolve()), "-o",
                                                                f"{tmp}/out.tif", *preset), env=env)
                if run.code != 0:
                    raise SystemExit(f"{mode}: {toolkit.last_line(run.stderr)}")
                times.append(run.wall_s)
        warm = statistics.median(times[1:])
        print(f"{mode:5s} set-up {setup:6.1f} s; runs {', '.join(f'{t:.2f}' for t in times)} s; "
              f"first / warm {times[0] / warm:.2f}x", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
