"""The camera-raw noise estimate against the sensor model (issue 42's "each other estimate as good
as before"), this checkout and optionally another tree in the same run:

    python tools/bench_noise_estimate.py [--baseline DIR] [--kodak 1,4,...] [--mcmaster 1,4,...]
                                         [--gains 1,4,16,64] [--cfas bayer,lms] [--work DIR]

Each scene (Kodak and McMaster images, ``--data``) is simulated by this checkout's ``clisp
simulate`` (seed 1, Airy optics) to a DNG that carries its sensor model. Each tree then reads the
DNG, treats it as a camera raw (``raw_noise(raw, estimate=True)``: the model hidden; this tree's
estimate reads the statistics pass's noise strips, as ``measure_scene`` does, a tree without
``clisp.scene`` its own crops) and compares the estimate with the model (``estimate=False``) per
CFA channel at that channel's median white-balanced level L: the error ``|sigma_est(L) /
sigma_model(L) - 1|``. Printed: the error per set, CFA and gain (mean over images and channels)
for every tree, and the mean and median over all. Texture inflates an estimate where the noise is
small (gain 1), so the figure that matters is each tree against the other, not against 0.
"""
from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path
from toolkit import REPO, git_rev, kodak_path, mcmaster_path, repo_env


def simulated(data: Path, work: Path, sets: dict[str, list[int]], cfas: list[str], gains: list[int]) -> list[dict]:
    """The DNGs (made once in ``work``) and their labels."""
    cases = []
    for label, numbers in sets.items():
        for number in numbers:
            scene = kodak_path(data, number) if label == "kodak" else mcmaster_path(data, number)
            for cfa in cfas:
                for gain in gains:
                    dng = work / f"{label}{number}-{cfa}-g{gain}.dng"
                    if not dng.exists():
                        run = subprocess.run(toolkit.clisp_cmd("simulate", str(scene), "-o", str(dng), "--cfa", cfa,
                                                               "--gain", str(gain), "--seed", "1"), check=False,
                                             env=repo_env(REPO), capture_output=True, text=True)
                        if run.returncode != 0:
                            raise SystemExit(f"bench_noise_estimate: {scene}: {toolkit.last_line(run.stderr)}")
                    cases.append({"set": label, "image": number, "cfa": cfa, "gain": gain, "dng": str(dng)})
    return cases


def child_errors(dngs: list[str]) -> list[list[float]]:
    """Per DNG, per CFA channel: |sigma_est / sigma_model - 1| at the channel's median level."""
    from clisp.io.rawfile import read_raw
    try:
        from clisp.scene.noise import raw_noise
        from clisp.scene.statistics import reference_statistics
    except ImportError:                       # a tree before issue 42: crops of the mosaic
        from clisp.noise_estimate import raw_noise  # type: ignore[no-redef]
        reference_statistics = None
    out = []
    for path in dngs:
        raw = read_raw(path)
        model = raw_noise(raw, estimate=False)
        if reference_statistics is not None:
            estimate = raw_noise(raw, estimate=True, statistics=reference_statistics(raw))
        else:
            estimate = raw_noise(raw, estimate=True)
        gains = np.asarray(raw.pass1_gains(), dtype=np.float64)
        black = np.broadcast_to(np.asarray(raw.black_level, dtype=np.float64), gains.shape)
        pattern = raw.cfa.pattern
        ph, pw = pattern.shape
        errors = []
        for c in range(raw.cfa.n_channels):
            samples = [raw.data[i::ph, j::pw] for i in range(ph) for j in range(pw) if pattern[i, j] == c]
            level = float(np.median(np.concatenate([s.ravel() for s in samples])).astype(np.float64))
            level = (level - black[c]) / (float(raw.white_level) - black[c]) * gains[c]
            ratio = np.sqrt(estimate.variance(c, level) / model.variance(c, level))
            errors.append(float(abs(ratio - 1.0)))
        out.append(errors)
    return out


def numbers(text: str) -> list[int]:
    return [int(v) for v in text.split(",") if v]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    if argv is None and len(sys.argv) > 1 and sys.argv[1] == "_child":
        ap.add_argument("cmd")
        ap.add_argument("--tree", type=Path, required=True)
        ap.add_argument("dngs", nargs="+")
        args = ap.parse_args()
        toolkit.enter_tree(args.tree)
        print(json.dumps(child_errors(args.dngs)))
        return 0
    toolkit.add_data_option(ap)
    toolkit.add_work_option(ap, "the simulated DNGs")
    ap.add_argument("--baseline", type=Path, default=None, help="another clisp checkout to measure in the same run")
    ap.add_argument("--kodak", type=numbers, default=numbers("1,4,7,10,13,16,19,22"))
    ap.add_argument("--mcmaster", type=numbers, default=numbers("1,4,7,10,13"))
    ap.add_argument("--cfas", default="bayer,lms")
    ap.add_argument("--gains", type=numbers, default=numbers("1,4,16,64"))
    args = ap.parse_args(argv)

    trees = {f"clisp@{git_rev(REPO, dirty=True)}": REPO}
    if args.baseline is not None:
        trees[f"base@{git_rev(args.baseline)}"] = args.baseline.resolve()
    with toolkit.work_folder(args.work, "clisp-noise-") as work:
        cases = simulated(args.data, work, {"kodak": args.kodak, "mcmaster": args.mcmaster},
                          args.cfas.split(","), args.gains)
        errors = {name: toolkit.tree_child(__file__, tree, [c["dng"] for c in cases]) for name, tree in trees.items()}
    print(f"CPU: {toolkit.cpu_model()}; |sigma_est / sigma_model - 1| at each channel's median level, "
          f"mean over images and channels")
    print("| set | CFA | gain | " + " | ".join(trees) + " |")
    print("|---|---|---:|" + "---:|" * len(trees))
    groups: dict[tuple, list[int]] = {}
    for i, c in enumerate(cases):
        groups.setdefault((c["set"], c["cfa"], c["gain"]), []).append(i)
    for (label, cfa, gain), rows in groups.items():
        cells = [f"{np.mean([errors[t][i] for i in rows]):.3f}" for t in trees]
        print(f"| {label} | {cfa} | {gain} | " + " | ".join(cells) + " |")
    for t in trees:
        flat = [e for per in errors[t] for e in per]
        print(f"{t}: mean {np.mean(flat):.3f}, median {statistics.median(flat):.3f} over {len(flat)} channels")
    return 0


if __name__ == "__main__":
    sys.exit(main())
