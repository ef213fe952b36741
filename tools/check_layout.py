"""The layout's checks (issue 26), each a subcommand that prints its figure:

    python tools/check_layout.py wheel                    # what `pip install .` ships: no study module
    python tools/check_layout.py startup --baseline DIR   # `import clisp.app.cli`: time and heavy modules, vs DIR
    python tools/check_layout.py launches                 # the most positional arguments of any kernel launch
    python tools/check_layout.py sources                  # #ifndef host-constant defaults; uncommented function-level imports
    python tools/check_layout.py hashes --baseline DIR    # outputs' pixel hashes, every preset, vs DIR's

Child processes run in a neutral folder: `python -m clisp` and `python -c` put the working
directory first on sys.path, where this checkout's clisp would shadow the baseline's.
``hashes`` processes simulated LMS and Bayer raws (from Kodak images), the Canon D30 CRW tiled to
24 MP as a clisp DNG (as tools/bench_peers.py builds it) and the 550D DNG with every preset and a
few options (ARI, Malvar, hybrid, a forced 96 px tile, clipped highlights), once with this checkout
and once with DIR's, and names every run whose EXR pixels differ. ``startup`` times the two trees
in interleaved rounds. Import cycles: tools/import_cycles.py.
"""
from __future__ import annotations

import argparse
import ast
import hashlib
import statistics
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import toolkit
from toolkit import REPO

HEAVY = ("scipy", "colour", "OpenImageIO", "matplotlib", "rawpy", "pyopencl", "dask", "exiv2", "PIL", "tifffile")
"""Modules that cost start-up; `import clisp.app.cli` should load none of the first five."""
STUDY_NAMES = ("research/", "bayer_rcd", "bayer_gbtf", "bayer_numpy", "lms_ri")
MAX_POSITIONAL = 12


def check_wheel() -> int:
    """Build the wheel without dependencies and list its folders; fail on any study module."""
    with tempfile.TemporaryDirectory() as out:
        subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", out, str(REPO)], check=True)
        wheel = next(Path(out).glob("clisp-*.whl"))
        names = zipfile.ZipFile(wheel).namelist()
    studies = [n for n in names if any(s in n for s in STUDY_NAMES)]
    kernels = [n for n in names if n.endswith((".cl", ".h"))]
    folders = sorted({n.rsplit("/", 1)[0] for n in names if n.startswith("clisp/")})
    print(f"wheel {wheel.name}: {len(names)} files; folders: {', '.join(folders)}")
    print(f"OpenCL sources: {len(kernels)}; READMEs: {sum(n.endswith('README.md') for n in names)}; "
          f"study modules: {len(studies)} {studies}")
    return 1 if studies else 0


def cli_module(tree: Path) -> str:
    """The CLI's module in ``tree``: clisp.app.cli since issue 42, clisp.cli before."""
    return "clisp.app.cli" if (tree / "clisp" / "app" / "cli.py").exists() else "clisp.cli"


def check_startup(baseline: Path | None, repeat: int) -> int:
    """Wall time of `python -c "import clisp.app.cli"` (interleaved with the baseline, whose CLI may
    be clisp.cli) and heavy modules loaded."""
    trees = [REPO] + ([baseline.resolve()] if baseline else [])
    times: dict[Path, list[float]] = {t: [] for t in trees}
    for _ in range(repeat):
        for tree in trees:
            start = time.perf_counter()
            subprocess.run([sys.executable, "-c", f"import {cli_module(tree)}"], env=toolkit.repo_env(tree),
                           check=True, cwd=toolkit.NEUTRAL_CWD)
            times[tree].append(time.perf_counter() - start)
    bad = 0
    for tree in trees:
        probe = f"import sys, {cli_module(tree)}; print(' '.join(m for m in {HEAVY!r} if m in sys.modules))"
        loaded = subprocess.run([sys.executable, "-c", probe], env=toolkit.repo_env(tree), check=True,
                                capture_output=True, text=True, cwd=toolkit.NEUTRAL_CWD).stdout.split()
        bad += tree == REPO and any(m in loaded for m in HEAVY[:5])
        t = sorted(times[tree])
        print(f"{toolkit.git_rev(tree)}: import {cli_module(tree)} best {t[0] * 1e3:.0f} ms, median "
              f"{statistics.median(t) * 1e3:.0f} ms ({repeat} runs); heavy modules loaded: {loaded}")
    return 1 if bad else 0


def check_launches() -> int:
    """Run every demosaic and preset on small simulated raws, recording each kernel launch's
    positional argument count (launches by name are counted apart)."""
    import numpy as np
    import clisp
    from clisp.engine import runtime
    from clisp.pipeline import build_pipeline
    seen: dict[tuple[str, bool], int] = {}

    def record(kernel: object, args: tuple, named: bool) -> None:
        name = getattr(kernel, "function_name", None) or getattr(getattr(kernel, "_kernel", None), "function_name", "?")
        seen[(name, named)] = max(seen.get((name, named), 0), len(args))

    exact, launch, launch_named = runtime.launch_exact, runtime.Runtime.launch, runtime.Runtime.launch_named
    inside_named = [False]

    def exact_spy(rt, kernel, w, h, *args, **kw):
        record(kernel, args, inside_named[0])
        return exact(rt, kernel, w, h, *args, **kw)

    def launch_spy(self, kernel, w, h, *args, **kw):
        record(kernel, args, inside_named[0])
        return launch(self, kernel, w, h, *args, **kw)

    def named_spy(self, *args, **kw):
        inside_named[0] = True
        try:
            return launch_named(self, *args, **kw)
        finally:
            inside_named[0] = False

    modules = [m for name, m in sys.modules.items() if name.startswith("clisp") and getattr(m, "launch_exact", None) is exact]
    for m in modules:
        m.launch_exact = exact_spy
    runtime.Runtime.launch, runtime.Runtime.launch_named = launch_spy, named_spy
    rng = np.random.default_rng(0)
    scene = np.clip(0.3 + 0.2 * rng.standard_normal((160, 200, 3)).cumsum(axis=1) / 30, 0, 1.6)   # clips: highlights
    for cfa, demosaics in (("lms", ["bilinear", "hybrid", "guided"]), ("bayer", ["bilinear", "malvar", "dlmmse", "ari"])):
        raw = clisp.simulate(scene, cfa=cfa, gain=8, seed=1).raw
        for demosaic in demosaics:
            for preset in ("fast", "balanced", "quality"):
                for skip in (None, True):
                    build_pipeline(raw, preset=preset, demosaic=demosaic, output="srgb16", skip=skip).run(raw.data, tile=96)
    positional = {k: n for (k, named), n in seen.items() if not named}
    worst = max(positional.items(), key=lambda kv: kv[1])
    print(f"kernels launched: {len({k for k, _ in seen})}; by name: {sum(named for _, named in seen)}; "
          f"most positional arguments: {worst[1]} ({worst[0]}); over {MAX_POSITIONAL}: "
          f"{sorted(k for k, n in positional.items() if n > MAX_POSITIONAL)}")
    return 1 if worst[1] > MAX_POSITIONAL else 0


LOOSE_MODULES = 6
"""Most modules loose in clisp/ beside its packages (issue 42): the public API, __main__, cfa, errors,
metrics, version."""


def check_sources() -> int:
    """#ifndef defaults in the OpenCL sources, function-level imports in clisp/ without a comment, and
    more than LOOSE_MODULES modules loose in clisp/."""
    sources = sorted((REPO / "clisp").rglob("*.cl")) + sorted((REPO / "clisp").rglob("*.h"))
    fallbacks = [f"{p.relative_to(REPO)}:{i}" for p in sources
                 for i, line in enumerate(p.read_text().splitlines(), 1) if line.strip().startswith("#ifndef")]
    total, bare = 0, []
    for path in sorted((REPO / "clisp").rglob("*.py")):
        lines = path.read_text().splitlines()
        found: set[int] = set()
        for fn in ast.walk(ast.parse("\n".join(lines))):
            if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for node in ast.walk(fn):
                    if isinstance(node, (ast.Import, ast.ImportFrom)) and node.lineno not in found:
                        found.add(node.lineno)
                        span = lines[node.lineno - 2:node.end_lineno or node.lineno]
                        if not any("#" in line for line in span):
                            bare.append(f"{path.relative_to(REPO)}:{node.lineno}")
        total += len(found)
    print(f"OpenCL sources: {len(sources)}, #ifndef defaults: {len(fallbacks)} {fallbacks}")
    print(f"function-level imports in clisp/: {total}, without a comment saying why: {len(bare)} {bare}")
    loose = sorted(p.name for p in (REPO / "clisp").glob("*.py"))
    print(f"modules loose in clisp/: {len(loose)} (at most {LOOSE_MODULES}) {loose}")
    return 1 if fallbacks or bare or len(loose) > LOOSE_MODULES else 0


def hash_runs(data: Path, work: Path) -> list[tuple[str, list[str]]]:
    """(raw, options) of the hashed runs; builds the simulated raws in ``work`` (this checkout)."""
    sims = {"bayer.dng": ("kodak/kodim05.png", "bayer", "8", "2"), "lms.dng": ("kodak/kodim23.png", "lms", "8", "1"),
            "lms1.dng": ("kodak/kodim03.png", "lms", "1", "1")}
    for name, (scene, cfa, gain, seed) in sims.items():
        if not (work / name).exists():
            subprocess.run(toolkit.clisp_cmd("simulate", str(data / scene), "-o", str(work / name), "--cfa", cfa,
                                             "--gain", gain, "--seed", seed), check=True, env=toolkit.repo_env(REPO),
                           cwd=toolkit.NEUTRAL_CWD)
    d30 = work / "bayer-RAW_CANON_D30_SRGB-6000x4000.dng"
    if not d30.exists():
        subprocess.run([sys.executable, str(REPO / "tools" / "bench_peers.py"), "--work", str(work), "--only",
                        "clisp fast bayer tif", "--repeat", "1", "--quiet"], check=True, env=toolkit.repo_env(REPO))
    raws = [str(work / n) for n in sims] + [str(d30), str(data / "raw" / "Canon_EOS550D_MagicLantern_colorchart.dng")]
    runs = [(raw, ["--preset", p]) for raw in raws for p in ("fast", "balanced", "quality")]
    bayer, lms = str(work / "bayer.dng"), str(work / "lms.dng")
    return runs + [(bayer, ["--demosaic", "ari"]), (bayer, ["--demosaic", "malvar"]), (lms, ["--demosaic", "hybrid"]),
                   (lms, ["--preset", "quality", "--tile", "96"]), (bayer, ["--preset", "quality", "--highlights", "clip"])]


def output_hash(tree: Path, raw: str, options: list[str], out: Path) -> str:
    """sha256 (16 hex digits) of the EXR pixels of `clisp process raw` with the clisp of ``tree``."""
    from clisp.io.imageio import read_image
    import numpy as np
    subprocess.run(toolkit.clisp_cmd("process", raw, "-o", str(out), *options), check=True, capture_output=True,
                   env=toolkit.repo_env(tree), cwd=toolkit.NEUTRAL_CWD)
    return hashlib.sha256(np.ascontiguousarray(read_image(out)[0]).tobytes()).hexdigest()[:16]


def check_hashes(data: Path, work: Path, baseline: Path) -> int:
    """Every hashed run with this checkout and with ``baseline``; prints both and the runs that differ."""
    differ = []
    runs = hash_runs(data, work)
    for raw, options in runs:
        label = f"{Path(raw).name} {' '.join(options)}"
        ours, theirs = (output_hash(tree, raw, options, work / "out.exr") for tree in (REPO, baseline.resolve()))
        print(f"{label}: {ours} {'=' if ours == theirs else '!='} {theirs}", flush=True)
        if ours != theirs:
            differ.append(label)
    print(f"{len(runs) - len(differ)} of {len(runs)} runs bit-identical to {toolkit.git_rev(baseline)}; differ: {differ}")
    return 1 if differ else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="check", required=True)
    sub.add_parser("wheel", help="what `pip install .` ships")
    startup = sub.add_parser("startup", help="`import clisp.app.cli`: time and heavy modules")
    startup.add_argument("--baseline", type=Path, default=None, metavar="DIR", help="another clisp source tree to time too")
    toolkit.add_repeat_option(startup, 15, "interleaved runs per tree")
    sub.add_parser("launches", help="the most positional arguments of a kernel launch")
    sub.add_parser("sources", help="#ifndef defaults and uncommented function-level imports")
    hashes = sub.add_parser("hashes", help="outputs' pixel hashes against another tree's")
    hashes.add_argument("--baseline", type=Path, required=True, metavar="DIR", help="the clisp source tree to compare with")
    toolkit.add_data_option(hashes, "kodak/ and raw/")
    toolkit.add_work_option(hashes, "the raws and outputs (the 24 MP DNG is kept there for the next run)")
    args = parser.parse_args(argv)
    if args.check == "wheel":
        return check_wheel()
    if args.check == "startup":
        return check_startup(args.baseline, args.repeat)
    if args.check == "launches":
        return check_launches()
    if args.check == "sources":
        return check_sources()
    with toolkit.work_folder(args.work, "check_layout-") as work:
        return check_hashes(args.data, work, args.baseline)


if __name__ == "__main__":
    sys.exit(main())
