"""Crops of the join between the flat and detail paths inside a mixed tile (issue 30, item 2).

    python tools/skip_crops.py [--out docs/figures/skip_join.png]

Scene: a 1024 x 1024 piece of tools/calibrate_skip.py's striped sky (the smooth gradient with one
textured strip), simulated LMS at gains 1 and 16 (seed 1). Per gain one row of crops around the
lower edge of the detail path's rectangle (the strip, the ramp and the flat sky below): the truth,
``--no-skip``, the default (a mixed tile) and |default - no-skip| x 8; sRGB-encoded, clipped, 2x
(nearest). Prints where the rectangle and the crop lie, and the PSNR of both runs on the crop.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path

from calibrate_skip import striped_sky
from clisp.metrics import psnr, tone_map
from clisp.pipeline import build_pipeline
from clisp.sim.simulate import simulate

ZOOM = 2
AMPLIFY = 8.0


def row(gain: float) -> tuple[np.ndarray, str]:
    scene = striped_sky(1024, 1024)
    sim = simulate(scene, cfa="lms", gain=gain, seed=1)
    pipe = build_pipeline(sim.raw, skip=True, output="linear")
    out = pipe.run(sim.raw.data, tile=0)
    choice = pipe.skip_plan.choices[0]
    if choice.path != "mixed":
        raise SystemExit(f"gain {gain:g}: the tile took {choice.path}, not mixed: {pipe.skip_plan.explain()}")
    pipe.skipper.enabled = False
    full = pipe.run(sim.raw.data, tile=0)
    rect = choice.rects[0]
    y1 = rect.y0 + rect.h
    crop = (slice(y1 - 96, y1 + 64), slice(448, 608))
    panels = [tone_map(sim.truth[crop]), tone_map(full[crop]), tone_map(out[crop]),
              np.clip(AMPLIFY * np.abs(tone_map(out[crop]) - tone_map(full[crop])), 0, 1)]
    region = (crop[0].start, crop[0].stop, crop[1].start, crop[1].stop)
    note = (f"gain {gain:g}: rectangle rows {rect.y0}-{y1}, crop rows {region[0]}-{region[1]}, columns "
            f"{region[2]}-{region[3]}; PSNR on the crop: --no-skip {psnr(full, sim.truth, region=region):.2f} dB, "
            f"default {psnr(out, sim.truth, region=region):.2f} dB")
    gap = np.ones((panels[0].shape[0], 4, 3))
    image = panels[0]
    for p in panels[1:]:
        image = np.concatenate([image, gap, p], axis=1)
    return image, note


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=toolkit.REPO / "docs" / "figures" / "skip_join.png")
    args = ap.parse_args(argv)
    from PIL import Image
    rows = []
    for gain in (1.0, 16.0):
        image, note = row(gain)
        print(note, flush=True)
        rows.append(image)
        rows.append(np.ones((4, image.shape[1], 3)))
    image = np.concatenate(rows[:-1], axis=0).repeat(ZOOM, 0).repeat(ZOOM, 1)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray((255 * image + 0.5).astype(np.uint8)).save(args.out)
    print(f"{args.out}: truth | --no-skip | default (mixed tile) | |default - no-skip| x {AMPLIFY:g}; "
          f"gain 1 above, 16 below")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
