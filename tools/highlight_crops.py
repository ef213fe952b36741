"""Crops of clipped highlights beside saturated colour (issue 25): truth, clisp's modes, LibRaw's.

    python tools/highlight_crops.py [--out docs/highlights] [--baseline DIR] [--kodak [--data DIR]]

Scenes: two of tools/bench_highlights.py's own photos (glossy spheres, flowers), issue 43's
specular ring (clisp.sim.highlight_scenes: a white highlight on a saturated red sphere) and, with
``--kodak``, Kodak 23 (the parrots, issue 25's case; from ``--data``/kodak, kept out of docs/ since
the data set is not ours), simulated at gain 8, seed 1, LMS and Bayer. Per scene and CFA one
PNG: a row of crops, left to right the truth, clisp ``off``, ``clip``, ``reconstruct`` (the
default), and for Bayer LibRaw's Blend and ReconstructDefault (AHD, from the DNG clisp writes;
bench_highlights.libraw). ``--baseline DIR``: another clisp source tree whose ``reconstruct``
joins the row as "before" (run in a child process with DIR first on the path). Linear output is
shown through the sRGB curve, clipped at 1, and enlarged 3x (nearest) so pixels stay visible.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path

import clisp
from clisp.pipeline import build_pipeline
from bench_highlights import libraw, own_photos
from clisp.sim.highlight_scenes import specular_ring

CROPS = {"kodim23": (slice(140, 260), slice(220, 340)), "glossy spheres": (slice(40, 160), slice(40, 160)),
         "flowers": (slice(150, 270), slice(0, 120)), "specular ring": (slice(20, 80), slice(14, 74))}
"""Crop (rows, columns) per scene: where a clipped white meets saturated colour."""
ZOOM = 3

CHILD = """
import sys, numpy as np
sys.path.insert(0, sys.argv[1])
import clisp
from clisp.pipeline import build_pipeline
scene = np.load(sys.argv[2])
sim = clisp.simulate(scene, cfa=sys.argv[3], gain=8, seed=1)
np.save(sys.argv[4], build_pipeline(sim.raw, highlights="reconstruct").run(sim.raw.data))
"""


def encode(linear: np.ndarray) -> np.ndarray:
    """sRGB-encoded 8-bit of linear values clipped to [0, 1], enlarged ZOOM times."""
    x = np.clip(linear, 0.0, 1.0)
    v = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    return np.repeat(np.repeat((v * 255 + 0.5).astype(np.uint8), ZOOM, 0), ZOOM, 1)


def baseline_output(root: Path, scene: np.ndarray, cfa: str, folder: Path) -> np.ndarray:
    """The baseline tree's default reconstruct on the same simulation."""
    scene_path, out_path = folder / "scene.npy", folder / "before.npy"
    np.save(scene_path, scene)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    subprocess.run([sys.executable, "-c", CHILD, str(root), str(scene_path), cfa, str(out_path)], check=True, env=env)
    return np.load(out_path)


def row(scene: np.ndarray, cfa: str, crop: tuple[slice, slice], baseline: Path | None,
        folder: Path) -> tuple[np.ndarray, list[str]]:
    """The crops of one scene and CFA side by side (with 4 px gaps) and their labels."""
    sim = clisp.simulate(scene, cfa=cfa, gain=8, seed=1)
    panels = {"truth": sim.truth}
    for mode in ("off", "clip", "reconstruct"):
        panels[mode] = build_pipeline(sim.raw, highlights=mode).run(sim.raw.data)
    if baseline is not None:
        panels["before"] = baseline_output(baseline, scene, cfa, folder)
    if cfa == "bayer":
        mask = np.zeros(sim.truth.shape[:2], bool)
        for mode in ("Blend", "ReconstructDefault"):
            panels[f"LibRaw {mode}"] = libraw(sim.raw, mode, folder, mask, sim.truth)
    tiles = [encode(p[crop]) for p in panels.values()]
    gap = np.full((tiles[0].shape[0], 4, 3), 255, np.uint8)
    out = tiles[0]
    for tile in tiles[1:]:
        out = np.concatenate([out, gap, tile], axis=1)
    return out, list(panels)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    toolkit.add_data_option(ap, "kodak/ (--kodak)")
    toolkit.add_out_option(ap, "docs/highlights", "the crops")
    ap.add_argument("--baseline", type=Path, default=None, help="a clisp source tree for a 'before' column")
    ap.add_argument("--kodak", action="store_true", help="add Kodak 23 (needs --data)")
    args = ap.parse_args(argv)
    from PIL import Image
    scenes = {k: v for k, v in own_photos().items() if k in CROPS}
    scenes["specular ring"] = specular_ring(192)
    kodak = toolkit.kodak_path(args.data, 23)
    if args.kodak:
        from clisp.io.imageio import read_scene
        scenes = {"kodim23": read_scene(kodak), **scenes}
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        for name, scene in scenes.items():
            for cfa in ("lms", "bayer"):
                image, labels = row(scene, cfa, CROPS[name], args.baseline, Path(tmp))
                path = args.out / f"{name.replace(' ', '_')}_{cfa}.png"
                Image.fromarray(image).save(path)
                print(f"{path}: {' | '.join(labels)}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
