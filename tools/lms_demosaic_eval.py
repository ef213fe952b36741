"""LMS demosaic quality and speed beside Bayer: noiseless PSNR on Kodak and McMaster, the zone plate.

Per image: ``clisp.simulate(scene, cfa, gain=None)`` (optics on: Airy r0 = 1 px) -> ``clisp.process(raw,
demosaic=NAME)`` (OpenCL) -> ``clisp.metrics.psnr(out, truth)`` (tone-mapped sRGB, 10 px border; truth =
the optics-blurred clean scene). Scene sizes are cropped to multiples of 4. A set's score is the mean of
its per-image dB. Zone plate: ``clisp.sim.charts.zone_plate(256)`` (the demo's: a cosine in sRGB-encoded
values up to Nyquist) simulated the same way, scored over the full 256 x 256 with border 10; "linear zp"
is the same plate with the cosine in linear values (``encoding="linear"``). LMS demosaics: bilinear,
hybrid and any --demosaic NAME; Bayer (RGGB): bilinear, dlmmse and any --bayer NAME, each only if registered in clisp.pipeline.DEMOSAICS.

    python tools/lms_demosaic_eval.py [--data ../shared/data] [--subset N] [--demosaic NAME ...]
                                      [--bayer NAME ...] [--crops DIR] [--bench]

--crops DIR writes the zone plate (truth and each demosaic) as 16-bit sRGB PNGs plus one side-by-side
strip of its high-frequency quadrant (2x nearest-neighbour). --bench times each LMS demosaic stage on
PoCL/OpenCL over a 6000 x 4000 LMS mosaic (one window, on the device; upload and download excluded)
and gives its ratio to the bilinear kernel measured in the same run.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path
from toolkit import BORDER

import clisp
import clisp.pipeline
from clisp.sim import charts
from clisp.cfa import lms_cfa
from clisp.io.imageio import write_image
from clisp.metrics import psnr, tone_map

SETS = {"kodak": toolkit.KODAK, "mcmaster": toolkit.MCMASTER}
ZONE_SIZE = 256
SPOT = (44, 84)
"""Rows/columns of the zone-plate crop around (64, 64), where the sRGB cosine's 2nd harmonic sits on the
(pi, pi) L-M carrier (local frequency (0.25, 0.25) cycles/px)."""


def score(scene: np.ndarray, cfa: str, names: list[str],
          border: int = BORDER) -> dict[str, tuple[float, np.ndarray]]:
    """PSNR (tone-mapped, ``border``) and output of each demosaic on one noiseless capture."""
    sim = clisp.simulate(scene, cfa, gain=None)
    out = {}
    for name in names:
        image = clisp.process(sim.raw, demosaic=name)
        out[name] = (psnr(image, sim.truth, border=border), image)
    return out


def registered(names: list[str], kind: str) -> list[str]:
    """``names`` registered in clisp.pipeline.DEMOSAICS for CFA ``kind`` (a stage class may declare
    ``cfa_kinds``), in order, without repeats; the others are reported and skipped."""
    kept = []
    for name in names:
        stage = clisp.pipeline.DEMOSAICS.get(name)
        if stage is None:
            print(f"(skipping {name!r}: not a registered demosaic)", file=sys.stderr)
        elif kind not in (stage.cfa_kinds or (kind,)):          # None: any CFA
            print(f"(skipping {name!r}: not a {kind} demosaic)", file=sys.stderr)
        elif name not in kept:
            kept.append(name)
    return kept


def evaluate_sets(data: Path, subset: int | None, methods: list[tuple[str, str]]) -> dict[str, dict]:
    """{set: {(cfa, name): [dB per image]}} for every method (cfa, demosaic name)."""
    results: dict[str, dict] = {}
    for set_name, image_set in SETS.items():
        files = toolkit.image_files(data, image_set, subset, required=False)
        if not files:
            print(f"(no {set_name} images under {data / image_set.folder})", file=sys.stderr)
            continue
        per = {m: [] for m in methods}
        start = time.perf_counter()
        for path in files:
            scene = toolkit.load_scene(path)                  # cropped to multiples of 4 (the LMS CFA period)
            for cfa in dict.fromkeys(c for c, _ in methods):
                scores = score(scene, cfa, [n for c, n in methods if c == cfa])
                for name, (db, _) in scores.items():
                    per[(cfa, name)].append(db)
        print(f"{set_name}: {len(files)} images in {time.perf_counter() - start:.0f} s", file=sys.stderr)
        results[set_name] = per
    return results


def zone_plate(methods: list[tuple[str, str]], encoding: str = "srgb") -> tuple[dict, np.ndarray, dict]:
    """Zone plate dB per method, the truth and the outputs (linear sRGB); ``encoding`` of the cosine
    (charts.zone_plate: "srgb" is the demo's)."""
    scene = charts.zone_plate(ZONE_SIZE, encoding=encoding)
    db, images, truth = {}, {}, None
    for cfa in dict.fromkeys(c for c, _ in methods):
        sim = clisp.simulate(scene, cfa, gain=None)
        truth = sim.truth
        for name, (value, image) in score(scene, cfa, [n for c, n in methods if c == cfa]).items():
            db[(cfa, name)], images[(cfa, name)] = value, image
    return db, truth, images


def save_crops(folder: Path, truth: np.ndarray, images: dict) -> None:
    """Full zone plates as PNG and a strip of the high-frequency quadrant, truth first."""
    folder.mkdir(parents=True, exist_ok=True)
    panels = [("truth", truth)] + [(f"{cfa}-{name}", img) for (cfa, name), img in images.items()]
    strip = []
    for label, image in panels:
        write_image(folder / f"zone_plate_{label}.png", tone_map(image))
        quadrant = tone_map(image)[ZONE_SIZE // 2:, ZONE_SIZE // 2:]
        strip.append(np.repeat(np.repeat(quadrant, 2, axis=0), 2, axis=1))
        strip.append(np.ones((strip[-1].shape[0], 8, 3)))
    write_image(folder / "zone_plate_quadrant_strip.png", np.concatenate(strip[:-1], axis=1))
    spot = []
    for _, image in panels:       # around (64, 64): local frequency (0.25, 0.25) cycles/px, 2nd harmonic at (pi, pi)
        crop = tone_map(image)[SPOT[0]:SPOT[1], SPOT[0]:SPOT[1]]
        spot += [np.repeat(np.repeat(crop, 8, axis=0), 8, axis=1), np.ones((8 * (SPOT[1] - SPOT[0]), 8, 3))]
    write_image(folder / "zone_plate_spot_8x.png", np.concatenate(spot[:-1], axis=1))
    (folder / "zone_plate_quadrant_strip.txt").write_text(
        "left to right: " + ", ".join(label for label, _ in panels) + "\n"
        "bottom-right quadrant (rows/cols 128..255) of the 256 px zone plate, 2x nearest neighbour\n"
        f"zone_plate_spot_8x.png: rows/cols {SPOT[0]}..{SPOT[1] - 1}, 8x nearest neighbour, same order\n")
    print(f"crops written to {folder}", file=sys.stderr)


def bench(names: list[str], height: int = 4000, width: int = 6000, repeats: int = 3) -> dict[str, float]:
    """Megapixels per second of each LMS demosaic stage on the device over one height x width window.

    The mosaic is uniform random in [0, 1] (the kernels have no data-dependent branches, so content does
    not change their speed), padded by the stage's halo; runs alternate between stages and each stage
    keeps its best time, so a busy machine biases no stage.
    """
    from clisp.engine.runtime import get_runtime
    rt = get_runtime()
    cfa = lms_cfa()
    stages = {name: clisp.pipeline.DEMOSAICS[name](cfa) for name in names}
    rng = np.random.default_rng(0)
    halo = max(stage.halo for stage in stages.values())
    mosaic = rng.uniform(0.0, 1.0, (height + 2 * halo, width + 2 * halo)).astype(np.float32)
    windows = {}
    for name, stage in stages.items():
        d = halo - stage.halo
        windows[name] = rt.upload(np.ascontiguousarray(mosaic[d:mosaic.shape[0] - d, d:mosaic.shape[1] - d]))
    best = {name: float("inf") for name in names}
    for run in range(repeats + 1):                     # run 0 builds the kernels and warms the pool
        for name, stage in stages.items():
            rt.queue.finish()
            start = time.perf_counter()
            out = stage.enqueue(rt, windows[name], (-stage.halo, -stage.halo))
            rt.queue.finish()
            if run:
                best[name] = min(best[name], time.perf_counter() - start)
            rt.release(out)
    for image in windows.values():
        rt.release(image)
    print(f"bench device: {rt.describe()}", file=sys.stderr)
    return {name: height * width / 1e6 / t for name, t in best.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    toolkit.add_data_option(parser)
    parser.add_argument("--subset", type=int, default=None, help="only the first N images of each set")
    parser.add_argument("--demosaic", nargs="*", default=[], help="extra LMS demosaic names")
    parser.add_argument("--bayer", nargs="*", default=[], help="extra Bayer demosaic names")
    parser.add_argument("--crops", default=None, help="folder for the zone plate PNGs")
    parser.add_argument("--bench", action="store_true", help="also time the LMS demosaics at 24 MP")
    parser.add_argument("--no-sets", action="store_true",
                        help="skip Kodak/McMaster (zone plate and bench only)")
    args = parser.parse_args(argv)

    lms = registered(["bilinear", "hybrid"] + args.demosaic, "lms")
    bayer = registered(["bilinear", "dlmmse"] + args.bayer, "bayer")
    methods = [("lms", n) for n in lms] + [("bayer", n) for n in bayer]
    results = {} if args.no_sets else evaluate_sets(args.data, args.subset, methods)
    zone_db, truth, images = zone_plate(methods)
    zone_linear_db = zone_plate(methods, "linear")[0]
    speed = bench(lms) if args.bench else {}

    header = f"{'CFA':6} {'demosaic':12}" + "".join(f"{s:>10}" for s in results) + f"{'zone plate':>12}{'linear zp':>11}"
    header += f"{'MP/s':>9}{'x bilinear':>12}" if speed else ""
    print(header)
    for cfa, name in methods:
        row = f"{cfa:6} {name:12}"
        for per in results.values():
            row += f"{np.mean(per[(cfa, name)]):10.2f}"
        row += f"{zone_db[(cfa, name)]:12.2f}{zone_linear_db[(cfa, name)]:11.2f}"
        if speed and cfa == "lms":
            row += f"{speed[name]:9.1f}{speed[name] / speed['bilinear']:12.3f}"
        print(row)
    counts = ", ".join(f"{s} {len(next(iter(per.values())))} images" for s, per in results.items())
    print(f"(noiseless, Airy r0 = 1 px, PSNR tone-mapped, border {BORDER}, set means; {counts or 'no sets'}; "
          "zone plate = the demo's sRGB cosine, linear zp = the same cosine in linear values)")
    if args.crops:
        save_crops(Path(args.crops), truth, images)
    return 0


if __name__ == "__main__":
    sys.exit(main())
