"""The CFA kinds through the whole pipeline (issue 32, item 1): PSNR of LMS, Bayer and LMS on the Bayer layout.

    python tools/bench_cfa_kinds.py [--data DIR] [--subset N] [--gains 1,16] [--cfas lms,bayer,lms-bayer]

``--gains none`` simulates without noise (``clisp simulate --noiseless``); ``--cfas`` takes any CFA
name, e.g. ``ML/LS`` (L doubled on the Bayer layout, issue 45). Each CFA's demosaic under each preset
is printed first (what ``clisp process`` runs for it).

Each Kodak image is simulated with each CFA (``clisp.simulate``, Airy optics, seed 1) at each gain
and processed with the fast and the default (quality) preset; printed: the mean PSNR (dB,
sRGB-encoded, toolkit.BORDER px border) per gain, preset and CFA. The CFAs share everything but
what tells them apart: lms and lms-bayer share the LMS filters (camera constants, colour matrix,
chroma space), bayer and lms-bayer the layout (the Bayer demosaics).
"""
from __future__ import annotations

import argparse
import time

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path

import clisp
from clisp.metrics import psnr
from clisp.sim.simulate import simulate

PRESETS = ("fast", "quality")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    toolkit.add_data_option(parser, "kodak/")
    parser.add_argument("--subset", type=int, default=None, help="the first N Kodak images (default all 24)")
    parser.add_argument("--gains", default="1,16", help="analog gains, comma-separated (default 1,16)")
    parser.add_argument("--cfas", default="lms,bayer,lms-bayer", help="CFA names (default lms,bayer,lms-bayer)")
    args = parser.parse_args(argv)
    gains = [None if g.strip().lower() in ("none", "noiseless") else float(g) for g in args.gains.split(",")]
    cfas = args.cfas.split(",")
    scenes = toolkit.kodak(args.data, args.subset)
    from clisp.pipeline import build_pipeline
    for cfa in cfas:
        raw = simulate(scenes[0].image[:64, :64], cfa, gain=4, seed=1).raw
        names = {p: next(type(s).__name__ for s in build_pipeline(raw, preset=p).stages if s.name.startswith("demosaic"))
                 for p in PRESETS}
        print(f"{cfa} ({raw.cfa.kind}, layout {raw.cfa.layout}): " + ", ".join(f"{p} {n}" for p, n in names.items()))
    scores: dict[tuple[float | None, str, str], list[float]] = {}
    start = time.perf_counter()
    for scene in scenes:
        for gain in gains:
            for cfa in cfas:
                sim = simulate(scene.image, cfa, gain=gain, seed=1)
                for preset in PRESETS:
                    out = clisp.process(sim.raw, preset=preset)
                    scores.setdefault((gain, cfa, preset), []).append(psnr(out, sim.truth, border=toolkit.BORDER))
    print(f"{len(scenes)} Kodak images, {time.perf_counter() - start:.0f} s; mean PSNR (dB, sRGB-encoded, "
          f"border {toolkit.BORDER})")
    print("| gain | preset | " + " | ".join(cfas) + " |")
    print("|---|---|" + "---|" * len(cfas))
    for gain in gains:
        for preset in PRESETS:
            level = "noiseless" if gain is None else f"{gain:g}"
            print(f"| {level} | {preset} | " + " | ".join(f"{np.mean(scores[(gain, c, preset)]):.2f}" for c in cfas) + " |")


if __name__ == "__main__":
    main()
