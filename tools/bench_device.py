"""How a call's time divides between the device and the host, in process, warm (issue 41).

    python tools/bench_device.py host [--repeat 9] [--rounds 3] [--baseline DIR]
    python tools/bench_device.py throughput [--size 6000x4000] [--repeat 5] [--rounds 1] [--baseline DIR]
    python tools/bench_device.py profile [--size 6000x4000]    # where one warm call's time goes
    python tools/bench_device.py stats --save OUT.json          # 1 MP outputs' statistics (per device)
    python tools/bench_device.py stats --against A.json B.json  # compared under tests/tolerance.py's rule

``host``: a 0.26 MP raw (416 x 624) and a 12 MP one (3000 x 4000), simulated at gain 4 from the
demo chart (the mosaic of a simulated 416 x 624 raw tiled, so the 12 MP raw costs no simulation),
LMS and Bayer, already in memory: ``clisp.process(raw, preset, output)``, the two sizes
interleaved, ``--repeat`` calls each after a warm-up, median kept. Printed per CFA, preset and
output: both times, the 12 MP call's MP/s and the small call's time over its pixels' share of the
12 MP call (the host's share: 1.0 where a call costs only its pixels). ``warm x``: the same share
from ``--repeat`` calls of one size in a row (each size after its own kind: the small call then
meets its code and data in the caches, where interleaved it follows 75 ms of another call). For the quality preset also
the small call under event profiling (clisp.engine.profile.recording): device busy (the union of
its kernel and copy events over the tile loop) and the host time outside the device's events over
the whole call. ``throughput``: 24 MP raws (``--size``) to 16-bit sRGB ('srgb16', what a TIFF
writer receives) and linear float32, fast and quality: MP/s and device busy, the GPU's acceptance
(``CLISP_DEVICE=gpu``).

``--baseline DIR``: the same measurements with the clisp checkout DIR (the tree before a change), in
child processes alternating with this checkout's, ``--rounds`` times; each child warms up first.
Figures a tree cannot give (the busy share before clisp.engine.profile.recording) print as '-'.
``stats``: every preset on 1 MP raws (Bayer, LMS, and a Bayer raw with clipped lights) to linear
float: per output the mean and a 16 x 16 grid of block means per channel, saved as JSON (small
enough to bring back from a GPU machine); ``--against`` compares two such files with the suite's
rule, |a - b| <= 1e-5 max(1, |b|), and prints the worst difference per output.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path
from toolkit import REPO, cpu_model, git_rev

SMALL = (416, 624)
BIG = (3000, 4000)
PRESETS = ("fast", "balanced", "quality", "best")
TOL = 1e-5
"""tests/tolerance.py's TOL."""


# ------------------------------------------------------------------------------------ raws

def tiled_raw(cfa: str, shape: tuple[int, int], seed: int = 1, clip: bool = False):
    """A RawImage of ``shape``: the mosaic of a simulated 416 x 624 raw of the demo chart (gain 4,
    so it carries its noise model) tiled to ``shape`` (416 and 624 are multiples of every CFA
    period, so the pattern continues). ``clip``: the chart's brightest third pushed past white."""
    from dataclasses import replace
    from clisp.sim.charts import demo_chart
    from clisp.sim.simulate import simulate
    scene = np.ascontiguousarray(toolkit.repeat_to(demo_chart().image, *SMALL))
    if clip:
        scene = scene * np.where(scene.mean(axis=-1, keepdims=True) > 0.5, 3.0, 1.0)
    raw = simulate(scene, cfa=cfa, gain=4, seed=seed).raw
    if shape == SMALL:
        return raw
    reps = (-(-shape[0] // SMALL[0]), -(-shape[1] // SMALL[1]))
    return replace(raw, data=np.ascontiguousarray(np.tile(raw.data, reps)[:shape[0], :shape[1]]))


def median_call(fn, repeat: int) -> float:
    fn()
    times = []
    for _ in range(repeat):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


# ------------------------------------------------------------------------------------ children

def child_host(repeat: int) -> dict:
    """The host figures of this process's clisp (see the module doc)."""
    import clisp
    out: dict = {}
    for cfa in ("bayer", "lms"):
        small, big = tiled_raw(cfa, SMALL), tiled_raw(cfa, BIG)
        for preset, output in (("fast", "srgb16"), ("fast", "linear"), ("quality", "srgb16")):
            calls = {size: (lambda r=raw: clisp.process(r, preset=preset, output=output))
                     for size, raw in (("small", small), ("big", big))}
            for fn in calls.values():
                fn()
            times: dict[str, list[float]] = {"small": [], "big": []}
            for _ in range(repeat):
                for size, fn in calls.items():
                    start = time.perf_counter()
                    fn()
                    times[size].append(time.perf_counter() - start)
            row = {size: statistics.median(t) for size, t in times.items()}
            row["share"] = row["small"] / (row["big"] * small.data.size / big.data.size)
            warm = {size: median_call(fn, repeat) for size, fn in calls.items()}     # one size at a time
            row["warm share"] = warm["small"] / (warm["big"] * small.data.size / big.data.size)
            if preset == "quality":
                row.update(busy_of(lambda: clisp.process(small, preset=preset, output=output), repeat))
            out[f"{cfa} {preset} {output}"] = row
    return out


def profile_calls(shape: tuple[int, int], repeat: int = 5) -> None:
    """``profile``: for a Bayer raw of ``shape`` (H, W) in memory, fast and quality to 'srgb16', the
    warm call's median time and one profiled call's report (clisp.engine.profile: device busy, host
    per launch, bytes moved, device time per stage and kernel, host activities), in this process."""
    import clisp
    from clisp.engine.profile import recording
    raw = tiled_raw("bayer", shape)
    megapixels = shape[0] * shape[1] / 1e6
    for preset in ("fast", "quality"):
        call = partial(clisp.process, raw, preset=preset, output="srgb16")
        print(f"\nbayer {preset} srgb16 {megapixels:.1f} MP: {1e3 * median_call(call, repeat):.1f} ms warm (median of {repeat})")
        with recording() as prof:
            start = time.perf_counter()
            call()
            wall = time.perf_counter() - start
        print(prof.report(megapixels, wall))


def busy_of(call, repeat: int) -> dict:
    """Device busy (of the tile loop) and the host time outside the device's events over the
    call's wall time, medians of ``repeat`` profiled calls; {} where this clisp cannot say."""
    try:
        from clisp.engine.profile import recording
    except ImportError:
        return busy_of_events(call, repeat)
    busy, outside, launches = [], [], []
    with recording():
        call()
    for _ in range(repeat):
        with recording() as prof:
            start = time.perf_counter()
            call()
            wall = time.perf_counter() - start
        f = prof.summary()
        busy.append(f["device_busy"])
        outside.append(1.0 - f["device_busy_s"] / wall)
        launches.append(f["launches_per_tile"])
    return {"busy": statistics.median(busy), "outside": statistics.median(outside),
            "launches": statistics.median(launches)}


def busy_of_events(call, repeat: int) -> dict:
    """busy_of for a clisp without clisp.engine.profile.recording (the tree before issue 41): its
    profiling runtime's events of the whole call, their union over the call's wall time (there is
    no tile loop to tell apart, so 'busy' is over the call and equals 1 - 'outside')."""
    from clisp.engine import profile
    from clisp.engine.runtime import get_runtime
    get_runtime(profiling=True)
    call()
    outside = []
    for _ in range(repeat):
        prof = profile.start()
        start = time.perf_counter()
        call()
        wall = time.perf_counter() - start
        profile._ACTIVE = None
        spans = []
        for _, _, event in prof.events:
            event.wait()
            spans.append((event.profile.start, event.profile.end))
        spans.sort()
        covered, current = 0, None
        for a, b in spans:
            if current is None or a > current[1]:
                covered += 0 if current is None else current[1] - current[0]
                current = [a, b]
            else:
                current[1] = max(current[1], b)
        covered += 0 if current is None else current[1] - current[0]
        outside.append(1.0 - covered * 1e-9 / wall)
    return {"busy": 1.0 - statistics.median(outside), "outside": statistics.median(outside)}


def child_throughput(size: tuple[int, int], repeat: int) -> dict:
    """MP/s (median of ``repeat`` warm calls) and device busy of 24 MP calls in memory."""
    import clisp
    out: dict = {}
    for cfa in ("bayer", "lms"):
        raw = tiled_raw(cfa, size)
        for preset in ("fast", "quality"):
            for output in ("srgb16", "linear"):
                call = lambda: clisp.process(raw, preset=preset, output=output)      # noqa: E731
                seconds = median_call(call, repeat)
                row = {"s": seconds, "mp_s": raw.data.size / 1e6 / seconds}
                row.update(busy_of(call, max(1, repeat // 2)))
                out[f"{cfa} {preset} {output}"] = row
    return out


def child_stats() -> dict:
    """Every preset's linear output of three 1 MP raws: mean and 16 x 16 block means per channel."""
    import clisp
    out: dict = {}
    shape = (832, 1248)
    for name, raw in (("bayer", tiled_raw("bayer", shape)), ("lms", tiled_raw("lms", shape)),
                      ("bayer clipped", tiled_raw("bayer", shape, clip=True))):
        for preset in PRESETS:
            image = clisp.process(raw, preset=preset).astype(np.float64)
            h, w = image.shape[0] // 16 * 16, image.shape[1] // 16 * 16
            blocks = image[:h, :w].reshape(16, h // 16, 16, w // 16, 3).mean(axis=(1, 3))
            out[f"{name} {preset}"] = {"mean": image.mean(axis=(0, 1)).tolist(), "blocks": blocks.tolist()}
    return out


def device_line() -> str:
    from clisp.engine.runtime import get_runtime
    return get_runtime().describe()


def run_child(tree: Path, task: list[str]) -> dict:
    """This tool's ``_child`` subcommand with the clisp of ``tree``; its JSON."""
    return toolkit.tree_child(__file__, tree, task)


# ------------------------------------------------------------------------------------ reports

def merged(rounds: list[dict]) -> dict:
    """Per key and figure, the median over rounds."""
    keys = rounds[0].keys()
    return {k: {f: statistics.median(r[k][f] for r in rounds) for f in rounds[0][k]} for k in keys}


def fmt(value: float | None, spec: str) -> str:
    return "-" if value is None else format(value, spec)


def report_host(trees: dict[str, dict]) -> None:
    print(f"{'tree':<22}{'cfa preset output':<24}{'0.26 MP ms':>11}{'12 MP ms':>10}{'12 MP MP/s':>11}"
          f"{'share x':>9}{'warm x':>8}{'busy %':>8}{'outside %':>10}{'launches':>9}")
    for name, rows in trees.items():
        for key, r in rows.items():
            print(f"{name:<21} {key:<24}{1e3 * r['small']:>11.2f}{1e3 * r['big']:>10.1f}"
                  f"{BIG[0] * BIG[1] / 1e6 / r['big']:>11.1f}{r['share']:>9.2f}"
                  f"{fmt(r.get('warm share'), '.2f'):>8}"
                  f"{fmt(100 * r['busy'] if 'busy' in r else None, '.0f'):>8}"
                  f"{fmt(100 * r['outside'] if 'outside' in r else None, '.1f'):>10}"
                  f"{fmt(r.get('launches'), '.0f'):>9}")


def report_throughput(trees: dict[str, dict]) -> None:
    print(f"{'tree':<22}{'cfa preset output':<24}{'s':>8}{'MP/s':>9}{'busy %':>8}{'launches':>9}")
    for name, rows in trees.items():
        for key, r in rows.items():
            print(f"{name:<21} {key:<24}{r['s']:>8.3f}{r['mp_s']:>9.1f}"
                  f"{fmt(100 * r['busy'] if 'busy' in r else None, '.0f'):>8}{fmt(r.get('launches'), '.0f'):>9}")


def compare_stats(a: dict, b: dict) -> int:
    """Worst difference per output under the suite's rule; 1 when any exceeds it."""
    worst_all, failed = 0.0, 0
    for key in sorted(set(a) & set(b)):
        x = np.array(a[key]["blocks"]), np.array(b[key]["blocks"])
        err = float(np.max(np.abs(x[0] - x[1]) / np.maximum(1.0, np.abs(x[1]))))
        ok = err <= TOL
        failed += not ok
        worst_all = max(worst_all, err)
        print(f"{key:<24} worst block-mean difference {err:.2e} {'ok' if ok else 'OVER ' + str(TOL)}")
    missing = sorted(set(a) ^ set(b))
    if missing:
        print(f"only in one file: {', '.join(missing)}")
    print(f"{len(set(a) & set(b))} outputs, worst {worst_all:.2e}, {failed} over the rule")
    return 1 if failed or missing else 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    for name in ("host", "throughput"):
        p = sub.add_parser(name)
        p.add_argument("--repeat", type=int, default=9 if name == "host" else 5)
        p.add_argument("--rounds", type=int, default=3 if name == "host" else 1)
        p.add_argument("--baseline", type=Path, default=None, help="the clisp checkout to compare with")
        if name == "throughput":
            p.add_argument("--size", type=toolkit.parse_size, default=(6000, 4000), help="W x H")
    p = sub.add_parser("profile")
    p.add_argument("--size", type=toolkit.parse_size, default=(6000, 4000), help="W x H")
    p = sub.add_parser("stats")
    g = p.add_mutually_exclusive_group(required=True)
    g.add_argument("--save", type=Path)
    g.add_argument("--against", type=Path, nargs=2)
    p = sub.add_parser("_child")
    p.add_argument("--tree", type=Path, required=True)
    p.add_argument("task", nargs="+")
    args = ap.parse_args(argv)

    if args.cmd == "_child":
        toolkit.enter_tree(args.tree)
        task = args.task
        if task[0] == "host":
            result = child_host(int(task[1]))
        elif task[0] == "throughput":
            result = child_throughput((int(task[3]), int(task[2])), int(task[1]))
        else:
            result = child_stats()
        print(json.dumps({"device": device_line(), "rows": result}))
        return 0
    if args.cmd == "profile":
        profile_calls((args.size[1], args.size[0]))
        return 0
    if args.cmd == "stats":
        if args.against:
            return compare_stats(*(json.loads(p.read_text())["rows"] for p in args.against))
        result = run_child(REPO, ["stats"])
        args.save.write_text(json.dumps(result))
        print(f"{args.save}: {len(result['rows'])} outputs on {result['device']}")
        return 0

    trees = {f"clisp@{git_rev(REPO, dirty=True)}": REPO}
    if args.baseline is not None:
        trees[f"base@{git_rev(args.baseline)}"] = args.baseline.resolve()
    task = ["host", str(args.repeat)] if args.cmd == "host" else \
        ["throughput", str(args.repeat), str(args.size[0]), str(args.size[1])]
    rounds: dict[str, list[dict]] = {name: [] for name in trees}
    device = ""
    for _ in range(args.rounds):
        for name, tree in trees.items():
            result = run_child(tree, task)
            device = result["device"]
            rounds[name].append(result["rows"])
    print(f"CPU {cpu_model()}; device {device}; medians over {args.rounds} round(s) of {args.repeat} calls")
    (report_host if args.cmd == "host" else report_throughput)({n: merged(r) for n, r in rounds.items()})
    return 0


if __name__ == "__main__":
    sys.exit(main())
