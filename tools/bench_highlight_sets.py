"""What the highlight stage costs or gains on whole photos (issue 43): Kodak and McMaster,
simulated at several gains, LMS and Bayer, the default pipeline against ``--highlights off``.

The simulator puts sRGB white at full scale, so the noise clips part of a white area's samples
(the truth itself never passes the clip on these sets): a stage that leaves noise-clipped whites
alone scores as ``off`` there. Per image and setting: tone-mapped PSNR (dB, 10 px border, the
Table 1 protocol, docs/model.md section 5) of the default (quality preset, ``reconstruct``) and of
the same pipeline without its highlight stage (what ``--highlights off`` builds: the same stages
less that one; the noise calibration is shared), the difference, the share of the mosaic's 16 px
blocks with a clipped sample and of those the stage treats as a true clip (highlights.clip_map). Where the default pipeline holds no highlight stage (no true
clip found) its output is the off pipeline's, computed once. Seed 0 (as tools/lms_oracle.py).

Summary per set, CFA and gain: the set means, default - off, and the worst image's difference;
issue 43's acceptance: mean difference >= -0.05 dB and no image below -0.2 dB.

    python tools/bench_highlight_sets.py [--data DIR] [--sets kodak,mcmaster] [--cfas lms,bayer]
        [--gains 1,4,16,64] [--subset N] [--only REGEX] [--csv PATH]
"""
from __future__ import annotations

import argparse
import re
import time
from pathlib import Path

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path

import clisp
from clisp.metrics import psnr
from clisp.pipeline import build_pipeline
from clisp.engine.executor import Pipeline
from clisp.modules.highlights.stage import Highlights, clip_map
from clisp.scene.noise import raw_noise

MEAN_LIMIT = -0.05
"""Issue 43: a set's mean PSNR with the stage at least off's minus this much (dB)."""
IMAGE_LIMIT = -0.2
"""Issue 43: no image below off's by more than this (dB)."""


def run_one(scene: np.ndarray, cfa: str, gain: float) -> dict[str, object]:
    """PSNR of the default pipeline and of the same without its highlight stage, and the stage's
    block counts, for one scene and setting."""
    sim = clisp.simulate(scene, cfa=cfa, gain=gain, seed=0)
    default = build_pipeline(sim.raw)
    stage = next((s for s in default.stages if isinstance(s, Highlights)), None)
    off = Pipeline(default.cfa, [s for s in default.stages if s is not stage])
    out_off = off.run(sim.raw.data)
    p_off = psnr(out_off, sim.truth)
    p_def = p_off if stage is None else psnr(default.run(sim.raw.data), sim.truth)
    clipped, true = block_shares(sim.raw)
    return {"psnr_default": round(p_def, 4), "psnr_off": round(p_off, 4), "diff": round(p_def - p_off, 4),
            "stage": stage is not None, "clipped_blocks": clipped, "true_blocks": true}


def block_shares(raw) -> tuple[float, float]:
    """(share of the mosaic's highlights.TEST px blocks with a clipped sample, share the noise test
    of highlights.clip_map calls a true clip), with the raw's own noise (its sensor model)."""
    found = clip_map(raw, raw_noise(raw))
    if found is None:
        return 0.0, 0.0
    return round(float(found.clipped.any(-1).mean()), 4), round(float(found.true.any(-1).mean()), 4)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    toolkit.add_data_option(ap)
    ap.add_argument("--sets", default="kodak,mcmaster")
    ap.add_argument("--cfas", default="lms,bayer")
    ap.add_argument("--gains", default="1,4,16,64")
    ap.add_argument("--subset", type=int, default=None, help="the first N images of each set (default all)")
    ap.add_argument("--only", default="", help="images whose name matches this regular expression")
    ap.add_argument("--csv", default="", help="write every row here")
    args = ap.parse_args(argv)
    gains = [float(g) for g in args.gains.split(",")]
    loaders = {"kodak": lambda: toolkit.kodak(args.data, args.subset),
               "mcmaster": lambda: toolkit.mcmaster(args.data, args.subset, numeric=True)}
    rows = []
    t0 = time.perf_counter()
    for set_name in args.sets.split(","):
        scenes = [s for s in loaders[set_name]() if not args.only or re.search(args.only, s.name)]
        for cfa in args.cfas.split(","):
            for gain in gains:
                for scene in scenes:
                    row = {"set": set_name, "image": scene.name, "cfa": cfa, "gain": gain,
                           **run_one(scene.image, cfa, gain)}
                    rows.append(row)
                    print(f"{set_name:8s} {scene.name:12s} {cfa:5s} g{gain:<3g} default {row['psnr_default']:6.2f} "
                          f"off {row['psnr_off']:6.2f} diff {row['diff']:+.3f}  blocks clipped "
                          f"{row['clipped_blocks']:.3f} true {row['true_blocks']:.3f}"
                          + ("" if row["stage"] else "  (no stage)"), flush=True)
    if args.csv:
        toolkit.write_csv(rows, Path(args.csv))
    print(f"\n{time.perf_counter() - t0:.0f} s. Set means (dB): default / off, default - off, worst image")
    failed = []
    for set_name in dict.fromkeys(r["set"] for r in rows):
        for cfa in dict.fromkeys(r["cfa"] for r in rows):
            for gain in gains:
                sel = [r for r in rows if r["set"] == set_name and r["cfa"] == cfa and r["gain"] == gain]
                if not sel:
                    continue
                d = np.mean([r["psnr_default"] for r in sel]), np.mean([r["psnr_off"] for r in sel])
                worst = min(sel, key=lambda r: r["diff"])
                ok = d[0] - d[1] >= MEAN_LIMIT and worst["diff"] >= IMAGE_LIMIT
                if not ok:
                    failed.append(f"{set_name} {cfa} g{gain:g}")
                print(f"  {set_name:8s} {cfa:5s} g{gain:<3g} n={len(sel):2d}  {d[0]:6.2f} / {d[1]:6.2f}  "
                      f"{d[0] - d[1]:+.3f}  worst {worst['diff']:+.3f} ({worst['image']})" + ("" if ok else "  FAIL"))
    print(f"\nissue 43 (mean >= off {MEAN_LIMIT:+g} dB, no image below {IMAGE_LIMIT:+g} dB): "
          + ("met everywhere" if not failed else "not met: " + ", ".join(failed)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
