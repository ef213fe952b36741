"""Device time of the highlight stage (``reconstruct``) on a 24 MP image, against another tree's.

    python tools/bench_highlight_stage.py [--baseline DIR] [--size 6000x4000] [--lights 60] [--repeat 3]
    python tools/bench_highlight_stage.py --raw RAW [--baseline DIR] [--repeat 3]

``--raw``: the stage's own input instead: the default (quality) pipeline of RAW, planned as
``clisp process`` plans it, each tile's window run through the stages before the highlight stage
on the device once; then rounds of the highlight stage over every window (this tree's, built for
the raw by highlight_stage with the pipeline's noise, interleaved with the baseline tree's, built
by its own highlight_stage), device seconds per kernel from OpenCL events, summed over the
windows: the median and least over rounds of the stage's sum, and each kernel's least (a shared
machine's load only ever adds). The whole pipeline's
device total is what ``clisp process RAW --profile`` reports; this isolates the stage.

The input: white-balanced camera values (planar float32, neutral n = (0.95, 0.96, 1), thresholds
t = (0.9, 1.1, 2.7) in units of n) of uniform noise in 0.1..0.7 of t with ``--lights`` soft
coloured lights (seeded) past the clip point; the script prints the share of 32 px blocks holding
a clipped pixel (60 lights at 24 MP: about a fifth, as on the D30 DNG). The stage runs on the
whole image as one window, after one untimed run; rounds interleave this tree's stage and the
baseline's (``--baseline DIR``: a clisp source tree; its modules/highlights/stage.py and
clisp/modules/highlights/highlights.cl, built in this process), so drift hits both alike. Per kernel: device
seconds from OpenCL events (the last round); per stage: median wall seconds and MP/s.
Choose the device with CLISP_DEVICE (e.g. ``gpu``).
"""
from __future__ import annotations

import argparse
import importlib.util
import sys
import time
from pathlib import Path

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path
from toolkit import parse_size

from clisp.engine import profile
from clisp.engine.runtime import WORK_GROUP, Parameter, _ProfiledKernel, _define_flags, get_runtime, launch_exact
from clisp.modules.highlights import stage as highlights

NEUTRAL = np.array([0.95, 0.96, 1.0])
THRESHOLD = np.array([0.9, 1.1, 2.7])
DISPLAY = np.array([[4.73, -3.87, 0.14], [-0.9, 1.9, 0.0], [0.0, -0.2, 1.2]])
"""An LMS-like display matrix (rows: output R, G, B), so the trust rule's distances matter."""


class BaselineRuntime:
    """The runtime, with ``kernel`` and ``launch_named`` building the baseline tree's <name>.cl
    instead (kernels/ before issue 26's layout, clisp/modules/<name>/ after; its headers from its
    clisp/modules/common)."""

    def __init__(self, rt, root: Path) -> None:
        self._rt, self._root, self._kernels = rt, root, {}

    def __getattr__(self, name: str):
        return getattr(self._rt, name)

    def kernel(self, name: str, kernel_name: str, defines=None, generated: str = ""):
        flags = tuple(_define_flags(defines or {}))
        key = (name, flags, kernel_name)
        if key not in self._kernels:
            source = "\n".join([source_file(self._root, "common.h").read_text(), generated,
                                source_file(self._root, f"{name}.cl").read_text()])
            include = self._root / "clisp" / "modules" / "common"
            options = list(flags) + ["-cl-std=CL1.2", "-cl-kernel-arg-info"] + (["-I", str(include)] if include.is_dir() else [])
            prg = self._rt.cl.Program(self._rt.context, source).build(options=options)
            self._kernels[key] = _ProfiledKernel(self._rt.cl.Kernel(prg, kernel_name), kernel_name)
        return self._kernels[key]

    def launch_named(self, name: str, kernel_name: str, width: int, height: int, args, defines=None,
                     generated: str = "", group=None, x0: int = 0, exact: bool = True) -> None:
        kernel = self.kernel(name, kernel_name, defines, generated)
        cl, k = self._rt.cl, kernel.kernel
        params = [Parameter(k.get_arg_info(i, cl.kernel_arg_info.NAME), k.get_arg_info(i, cl.kernel_arg_info.TYPE_NAME).strip(),
                            "*" in k.get_arg_info(i, cl.kernel_arg_info.TYPE_NAME)) for i in range(k.num_args)]
        values = [p.convert(args[p.name]) for p in params]
        launch_exact(self, kernel, width, height, *values, group=group or WORK_GROUP, x0=x0)


def source_file(root: Path, file_name: str) -> Path:
    """An OpenCL source of the tree at root, in either layout."""
    old = root / "kernels" / file_name
    return old if old.is_file() else next((root / "clisp" / "modules").glob(f"*/{file_name}"))


def baseline_module(root: Path):
    """The baseline tree's highlights stage, imported beside ours."""
    name = "clisp.modules.highlights.baseline"
    path = root / "clisp" / "modules" / "highlights" / "stage.py"
    if not path.is_file():
        raise SystemExit(f"{root}: no clisp/modules/highlights/stage.py (a tree before issue 26's layout?)")
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


def scene(h: int, w: int, lights: int) -> np.ndarray:
    """3 x h x w float32 camera values (see the module docstring)."""
    rng = np.random.default_rng(0)
    y = rng.uniform(0.1, 0.7, size=(h, w, 3)).astype(np.float32)
    for _ in range(lights):
        cy, cx, r = rng.integers(h), rng.integers(w), int(rng.integers(10, 120))
        rows, cols = slice(max(cy - 2 * r, 0), min(cy + 2 * r, h)), slice(max(cx - 2 * r, 0), min(cx + 2 * r, w))
        yy, xx = np.mgrid[rows, cols]
        d = np.hypot(yy - cy, xx - cx)
        y[rows, cols] += (np.clip(2.5 - d / r, 0, None)[..., None] * rng.uniform(0.3, 1.5, 3) * THRESHOLD
                          ).astype(np.float32)
    return np.ascontiguousarray((y * NEUTRAL).transpose(2, 0, 1).astype(np.float32))


def raw_windows(rt, path: Path):
    """(the default pipeline of the raw at ``path``, its highlight stage, [(device image, origin)]
    of the highlight stage's input per tile)."""
    from clisp.io.rawfile import read_raw
    from clisp.pipeline import build_pipeline
    from clisp.engine.executor import Pipeline
    from clisp.engine.stage import Origin, advance
    from clisp.engine.streaming import window_source
    raw = read_raw(path)
    pipe = build_pipeline(raw)
    k = next(i for i, stage in enumerate(pipe.stages) if isinstance(stage, highlights.Highlights))
    head = pipe.stages[:k]
    plan = pipe.plan(raw.data.shape, raw.data.dtype)
    source = window_source(raw.data)
    image = tuple(raw.data.shape)
    windows = []
    for t in plan.tiles:
        y0, x0 = plan.window_origin(t)
        h, w = plan.window_shape
        x = source.read(y0, x0, h, w, pipe.cfa.period, np.empty((h, w), raw.data.dtype))
        src, origin = rt.upload(x), Origin(y0, x0, image)
        for stage in head:
            out = stage.enqueue(rt, src, origin)
            rt.release(src)
            src, origin = out, advance(origin, stage.halo, stage.downscale)
        windows.append((src, origin))
    rt.queue.finish()
    return raw, pipe, pipe.stages[k], windows


def raw_main(args: argparse.Namespace, rt) -> int:
    """--raw: the stage over the raw's own windows, against the baseline tree's."""
    raw, pipe, stage, windows = raw_windows(rt, args.raw)
    w = sum(src.width * src.height for src, _ in windows) / 1e6
    print(f"{args.raw.name}: {len(windows)} windows, {w:.1f} MP of stage input", flush=True)
    stages = {"this tree": (rt, stage)}
    if args.baseline:
        old = baseline_module(args.baseline.resolve())
        from clisp.scene.measure import wb2_gains as _wb2_gains
        gains2 = _wb2_gains(raw, "metadata")
        stages["baseline"] = (BaselineRuntime(rt, args.baseline.resolve()), old.highlight_stage(raw, "reconstruct", gains2))
    sums: dict[str, list[float]] = {k: [] for k in stages}
    best: dict[str, dict[str, float]] = {k: {} for k in stages}
    for rnd in range(args.repeat + 1):
        for name, (runtime, st) in stages.items():
            prof = profile.start()
            for src, origin in windows:
                rt.release(st.enqueue(runtime, src, origin))
            rt.queue.finish()
            kernels = {k[1]: v[0] for k, v in prof.device_seconds().items()}
            if rnd:
                sums[name].append(sum(kernels.values()))
                for k, v in kernels.items():
                    best[name][k] = min(v, best[name].get(k, np.inf))
    for name, ts in sums.items():
        kernels = best[name]
        print(f"{name:9s} device s, median {np.median(ts):.4f}, least {min(ts):.4f} over {args.repeat} rounds; "
              f"least per kernel (sum {sum(kernels.values()):.4f}): " +
              ", ".join(f"{k} {v:.4f}" for k, v in sorted(kernels.items(), key=lambda kv: -kv[1])), flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", type=Path, default=None, help="another clisp source tree")
    ap.add_argument("--raw", type=Path, default=None, help="the stage's input from this raw's pipeline instead")
    ap.add_argument("--size", type=parse_size, default=(6000, 4000), metavar="WxH")
    ap.add_argument("--lights", type=int, default=60)
    toolkit.add_repeat_option(ap, 3, "timed rounds after an untimed one, median kept")
    args = ap.parse_args(argv)
    rt = get_runtime(profiling=True)
    print(f"device: {rt.describe()}", flush=True)
    if args.raw:
        return raw_main(args, rt)
    w, h = args.size
    x = scene(h, w, args.lights)
    bh, bw = h // 32 * 32, w // 32 * 32
    clipped = (x[:, :bh, :bw] / (NEUTRAL * THRESHOLD)[:, None, None] >= 1).any(axis=0)
    print(f"{w}x{h}, blocks of 32 px with a clipped pixel: {clipped.reshape(bh // 32, 32, bw // 32, 32).any(axis=(1, 3)).mean():.2f}",
          flush=True)
    src = rt.upload(x)
    stages = {"this tree": (rt, highlights.Highlights(NEUTRAL, THRESHOLD, 1.0, "reconstruct", display=DISPLAY))}
    if args.baseline:
        old = baseline_module(args.baseline.resolve())
        stages["baseline"] = (BaselineRuntime(rt, args.baseline.resolve()), old.Highlights(NEUTRAL, THRESHOLD, 1.0, "reconstruct"))
    walls: dict[str, list[float]] = {k: [] for k in stages}
    for rnd in range(args.repeat + 1):
        for name, (runtime, stage) in stages.items():
            prof = profile.start()
            rt.queue.finish()
            t0 = time.perf_counter()
            out = stage.enqueue(runtime, src, (0, 0))
            rt.queue.finish()
            if rnd:
                walls[name].append(time.perf_counter() - t0)
            if rnd == args.repeat:
                kernels = {k[1]: v[0] for k, v in prof.device_seconds().items()}
                print(f"{name}: device {sum(kernels.values()):.4f} s = " +
                      ", ".join(f"{k} {v:.4f}" for k, v in kernels.items()), flush=True)
            rt.release(out)
    mp = w * h / 1e6
    for name, ts in walls.items():
        print(f"{name:9s} median wall {np.median(ts):.4f} s ({mp / np.median(ts):.0f} MP/s)", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
