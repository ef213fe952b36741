"""Throughput of ``clisp batch`` (clisp.app.batch on a local Dask cluster) against a plain loop.

Simulates COUNT raws of WxH (alternately Bayer and LMS, gain 4, no optics) into WORK, then, in one
run on the same files and settings:

* loop     clisp.app.batch.process_one called file after file (what the batch does per file,
           without Dask) in a fresh process, cold like a Dask worker: the baseline; and again in
           this process once every program is built (kernels are generated per raw, so a
           fresh process loads one set of programs per raw from PoCL's cache);
* dask N   clisp.app.batch.run_batch on a fresh local cluster of N worker processes, for each N in
           --workers; "batch s" is from submitting to the last result, "wall s" adds the cluster's
           start-up (processes, imports, each worker's OpenCL context);
  (clisp.app.batch gives each of N local workers CPUs / N PoCL threads, POCL_CPU_MAX_CU_NUM);
* with --pocl-all, also each N > 1 with POCL_CPU_MAX_CU_NUM = CPUs: every worker a PoCL thread
  per CPU, PoCL's own default.

A first, untimed loop fills PoCL's on-disk program cache; every timed run but the warm loop then
starts cold in its process (programs loaded from that cache on first use).
Per-file overhead of the Dask path = (batch s of 1 worker - loop s) / COUNT; "in-task s" is the
sum of the manifest's per-file seconds, so batch s - in-task s / N is what scheduling, transfer
and the manifest cost.

    python tools/bench_batch.py [--count 20] [--size 1536x1024] [--preset quality] [--workers 1,2]
                                [--pocl-all] [--work DIR]
"""
from __future__ import annotations

import argparse
import multiprocessing
import shutil
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path

from clisp.app.batch import (BatchSettings, host_cpus, local_worker_env, plan_jobs, process_one, read_manifest,
                             run_batch)
from clisp.app.cli import image_size
from clisp.io.rawfile import write_raw
from clisp.sim.simulate import simulate


def make_raws(folder: Path, count: int, width: int, height: int) -> list[Path]:
    """``count`` simulated raws (random 8 px blocks, gain 4, no optics) in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    paths = []
    for i in range(count):
        scene = rng.random((height // 8 + 1, width // 8 + 1, 3)).repeat(8, 0).repeat(8, 1)[:height, :width]
        path = folder / f"raw{i:03d}.dng"
        write_raw(path, simulate(scene, "lms" if i % 2 else "bayer", gain=4, seed=i, optics="none").raw)
        paths.append(path)
    return paths


def loop(paths: list[Path], outdir: Path, settings: BatchSettings) -> tuple[float, float]:
    """(wall seconds, megapixels) of process_one over ``paths`` in this process."""
    outdir.mkdir(parents=True, exist_ok=True)
    jobs = plan_jobs(paths, outdir, settings.format)
    start, mp = time.perf_counter(), 0.0
    for job in jobs:
        record = process_one(job, settings, settings.digest(), "loop")
        if record["status"] != "ok":
            raise SystemExit(record["error"])
        mp += record["width"] * record["height"] / 1e6
    return time.perf_counter() - start, mp


def dask_run(paths: list[Path], outdir: Path, settings: BatchSettings, workers: int,
             env: dict[str, str] | None) -> dict:
    start = time.perf_counter()
    summary = run_batch(paths, outdir, settings, workers=workers, worker_env=env, timeout=3600)
    wall = time.perf_counter() - start
    if summary.errors or summary.ok != len(paths):
        raise SystemExit(f"batch failed: {summary.failed}")
    in_task = sum(r["seconds"] for r in read_manifest(outdir / "manifest.jsonl"))
    return dict(batch=summary.seconds, wall=wall, mp=summary.megapixels, in_task=in_task,
                workers=len(summary.workers))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--count", type=int, default=20, help="raws (default 20)")
    ap.add_argument("--size", type=image_size, default=(1536, 1024), metavar="WxH", help="default 1536x1024")
    ap.add_argument("--preset", default="quality")
    ap.add_argument("--format", default="exr")
    ap.add_argument("--workers", default="1,2", help="comma-separated worker counts (default 1,2)")
    ap.add_argument("--pocl-all", action="store_true",
                    help="also run N > 1 workers with POCL_CPU_MAX_CU_NUM = CPUs (PoCL's default)")
    toolkit.add_work_option(ap)
    args = ap.parse_args(argv)
    with toolkit.work_folder(args.work, "clisp-bench-batch-") as work:
        return bench(args, work)


def bench(args: argparse.Namespace, work: Path) -> int:
    """The loops and Dask runs of ``args`` on raws made in ``work``; prints the table."""
    width, height = args.size
    settings = BatchSettings(preset=args.preset, format=args.format)
    paths = make_raws(work / "raws", args.count, width, height)
    mp_each = width * height / 1e6
    print(f"{args.count} raws of {width}x{height} ({mp_each:.2f} MP), preset {args.preset}, {args.format}; "
          f"{host_cpus()} CPUs; work {work}")
    rows = []
    loop(paths, work / "out-warm-up", settings)     # fills PoCL's program cache on disk for every run
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as fresh:
        seconds, mp = fresh.submit(loop, paths, work / "out-loop", settings).result()
    rows.append(("loop, fresh process (baseline)", seconds, seconds, seconds, mp))
    warm, _ = loop(paths, work / "out-loop-warm", settings)
    rows.append(("loop, warm process (programs in memory)", warm, warm, warm, mp))
    runs = [(n, None) for n in (int(v) for v in args.workers.split(","))]
    if args.pocl_all:
        runs += [(n, {"POCL_CPU_MAX_CU_NUM": str(host_cpus())}) for n, _ in list(runs) if n > 1]
    batch_1 = None
    for n, env in runs:
        outdir = work / f"out-dask{n}{'-pocl-all' if env else ''}"
        shutil.rmtree(outdir, ignore_errors=True)
        r = dask_run(paths, outdir, settings, n, env)
        threads = env["POCL_CPU_MAX_CU_NUM"] if env else local_worker_env(n).get("POCL_CPU_MAX_CU_NUM", "default")
        label = f"dask {n} worker(s), {threads} PoCL thread(s) each"
        rows.append((label, r["batch"], r["wall"], r["in_task"], r["mp"]))
        if n == 1 and env is None:
            batch_1 = r["batch"]
    print(f"\n{'run':<44}{'batch s':>9}{'wall s':>9}{'in-task s':>11}{'files/s':>9}{'MP/s':>8}")
    for label, batch, wall, in_task, mp in rows:
        print(f"{label:<44}{batch:9.2f}{wall:9.2f}{in_task:11.2f}{args.count / batch:9.2f}{mp / batch:8.2f}")
    if batch_1 is not None:
        per_file = (batch_1 - seconds) / args.count
        print(f"\nper-file overhead of the Dask path (1 worker, batch s - loop s) / files: {per_file * 1e3:+.0f} ms "
              f"({per_file / (seconds / args.count) * 100:+.1f} % of the loop's {seconds / args.count * 1e3:.0f} ms/file)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
