"""Tune white balance ``auto``'s constants (clisp.scene.illuminant.Evidence) on scenes made in code (issue 42).

    python tools/tune_wb_auto.py [--work DIR] [--seeds 12] [--subset 3] [--tune]

The cases: tools/wb_scenes.py's kinds, seeds 0..SEEDS-1, each lit by a third of LIGHTS (2500 to
11000 K, on and off the locus; which third turns with the seed, the camera and the gain), simulated
(Airy optics) as Bayer and LMS raws at gains 1 and 16. Each case keeps what the estimate reads (the
raw's clisp.scene.illuminant.BlockStats) and what the metric needs: the mean camera triplet of the cells
whose true colour (the scene under D65, the cell's mean) is a mid-tone (channels 0.03..0.85), and
that true mean. The metric of a case: the angle (degrees) between that camera mean times the
estimate's multipliers through the colour matrix, and the true mean (a cell-level stand-in for
tools/bench_wb_auto.py's whole-process metric, 1000 times cheaper); ``true``: the same with the
light's own multipliers (its floor). The cases are cached in WORK/cases.pkl (delete it after
changing the statistics or the scenes).

Prints mean / worst per kind, light and camera for clisp.scene.illuminant.EVIDENCE; with ``--tune``, a
coordinate descent (each constant times 0.7 and 1.4 in turn, two rounds, kept when mean + 0.3 x
90th percentile drops) over every ``--subset``-th case, and the Evidence it ends with. Kodak and
McMaster are never read here: they judge (tools/bench_wb_auto.py).
"""
from __future__ import annotations

import argparse
import collections
import dataclasses
import pickle
import sys
from pathlib import Path

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path

LIGHTS = ((2500, 0.0), (3200, 0.0), (4200, 0.004), (5000, 0.0), (6504, 0.0), (8000, 0.0), (11000, 0.0),
          (3000, -0.008), (6000, 0.008))
"""(T in K, Duv) of the tuning lights."""
CAMERAS = (("bayer", 1), ("bayer", 16), ("lms", 1), ("lms", 16))
MID = (0.03, 0.85)


def build_cases(seeds: int) -> list[dict]:
    """The cases (module docstring), about 60 per seed."""
    import wb_scenes
    from clisp.scene import illuminant as il
    from clisp.sim.simulate import simulate
    cases = []
    for kind in wb_scenes.KINDS:
        for seed in range(seeds):
            scene = wb_scenes.make_scene(kind, seed).astype(np.float32)
            for cfa, gain in CAMERAS:
                for i, (kelvin, duv) in enumerate(LIGHTS):
                    if (seed * 7 + i * 3 + gain + len(cfa)) % 9 not in (0, 4, 7):
                        continue
                    w = il.light_srgb(np.array(float(kelvin)), duv)
                    w = w / w.max()
                    sim = simulate(scene * w, cfa, gain=gain, optics="airy", seed=seed)
                    raw = sim.raw
                    cells, _, _ = il.cell_means(raw.data, raw.cfa, raw.black_level, raw.white_level, 1 << 30)
                    p = raw.cfa.period
                    truth = sim.truth / w
                    h, wd = cells.shape[0] * p, cells.shape[1] * p
                    ref = truth[:h, :wd].reshape(cells.shape[0], p, cells.shape[1], p, 3).mean(axis=(1, 3))
                    mid = np.all((ref >= MID[0]) & (ref <= MID[1]), axis=-1)
                    if not mid.any():
                        continue
                    cases.append({"kind": kind, "seed": seed, "cfa": cfa, "gain": gain, "light": (kelvin, duv), "w": w,
                                  "stats": il.block_statistics(raw.data, raw.cfa, raw.black_level, raw.white_level),
                                  "camera_mean": cells[mid].mean(axis=0), "true_mean": ref[mid].mean(axis=0),
                                  "matrix": raw.colour_matrix, "daylight": raw.wb, "exposure": raw.exposure})
        print(f"{kind}: {len(cases)} cases", flush=True)
    return cases


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1.0, 1.0))))


def case_error(case: dict, gains: np.ndarray) -> float:
    """The cell-level metric of ``gains`` on ``case``, degrees."""
    out = (case["camera_mean"] * gains * case["exposure"]) @ case["matrix"].T
    return _angle(out, case["true_mean"])


def errors(cases: list[dict], evidence) -> tuple[np.ndarray, np.ndarray]:
    """(estimate's errors, the true light's errors) per case."""
    from clisp.scene import illuminant as il
    est, true = [], []
    for c in cases:
        lights = il.CameraLights(c["matrix"], c["daylight"])
        ref = 0 if c["cfa"] == "lms" else 1
        est.append(case_error(c, il.estimate_light(c["stats"], lights, ref, evidence).gains))
        g = lights.gains(c["w"])
        true.append(case_error(c, g / g[ref]))
    return np.array(est), np.array(true)


def objective(cases: list[dict], evidence) -> float:
    e, _ = errors(cases, evidence)
    return float(e.mean() + 0.3 * np.percentile(e, 90))


def report(cases: list[dict], evidence) -> None:
    est, true = errors(cases, evidence)
    groups = collections.defaultdict(list)
    for i, c in enumerate(cases):
        for key in ("all", c["kind"], f"{c['light'][0]} K, Duv {c['light'][1]:+.3f}", f"{c['cfa']} gain {c['gain']}"):
            groups[key].append(i)
    print(f"{'cases':<24}{'n':>5}  {'auto mean / worst':>18}  {'true light mean / worst':>24}")
    for key, idx in groups.items():
        print(f"{key:<24}{len(idx):>5}  {est[idx].mean():8.2f} / {est[idx].max():5.1f}  "
              f"{true[idx].mean():14.2f} / {true[idx].max():5.1f}")


def tune(cases: list[dict], evidence, rounds: int = 2):
    """Coordinate descent over Evidence's scalar constants (module docstring); returns the best."""
    best = objective(cases, evidence)
    print(f"start {best:.3f}", flush=True)
    names = [f.name for f in dataclasses.fields(evidence) if isinstance(getattr(evidence, f.name), float)]
    for r in range(rounds):
        for name in names:
            for factor in (0.7, 1.4):
                trial = dataclasses.replace(evidence, **{name: getattr(evidence, name) * factor})
                score = objective(cases, trial)
                if score < best - 1e-3:
                    best, evidence = score, trial
                    print(f"  {name} = {getattr(trial, name):.4g}: {score:.3f}", flush=True)
        print(f"round {r}: {evidence}", flush=True)
    return evidence


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    toolkit.add_work_option(parser, "the cached cases (cases.pkl)", Path("/tmp/clisp-tune-wb-auto"))
    parser.add_argument("--seeds", type=int, default=12, help="scenes per kind (default 12)")
    parser.add_argument("--subset", type=int, default=3, help="--tune uses every N-th case (default 3)")
    parser.add_argument("--tune", action="store_true", help="coordinate descent from clisp.scene.illuminant.EVIDENCE")
    args = parser.parse_args(argv)
    from clisp.scene import illuminant as il
    with toolkit.work_folder(args.work, "tune-wb-auto-") as work:
        cache = work / f"cases-{args.seeds}.pkl"
        if cache.is_file():
            cases = pickle.loads(cache.read_bytes())
        else:
            cases = build_cases(args.seeds)
            cache.write_bytes(pickle.dumps(cases))
    evidence = tune(cases[::args.subset], il.EVIDENCE) if args.tune else il.EVIDENCE
    report(cases, evidence)
    return 0


if __name__ == "__main__":
    sys.exit(main())
