"""Crops of the Bayer demosaics beside the truth and LibRaw's, to look at (issue 27).

    python tools/demosaic_crops.py [--data DIR] [--out docs/demosaic_crops.png] [--gain G]

Each row is one scene region: the truth, then clisp's DLMMSE, RI (the quality preset's) and ARI (the
best preset's), then LibRaw's DHT and AHD, every one through the same after-stages (the default
Bayer pipeline's colour matrix, chroma denoiser and WB pass 2, as tools/bench_demosaic_quality.py
scores them), tone-mapped (clip, sRGB encode), 2x nearest-neighbour. Regions: the lighthouse fence
of Kodak 19, a saturated detail of McMaster 1, and the zone plate and dead leaves of clisp's demo
chart. Noiseless with the paper's optics unless --gain.
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path

import bench_demosaic_quality as bdq
from clisp.pipeline import build_pipeline, make_demosaic
from clisp.sim.charts import demo_chart
from clisp.sim.simulate import simulate

METHODS = ("dlmmse", "ri", "ari")
LIBRAW = ("DHT", "AHD")
SIDE = 96
"""Crop side (px) before the 2x enlargement."""


def regions(data: Path) -> list[tuple[str, np.ndarray, tuple[int, int]]]:
    """(label, linear RGB scene, (y, x) of the crop's top-left)."""
    out = []
    for path, at, label in ((toolkit.kodak_path(data, 19), (480, 200), "Kodak 19, fence"),
                            (toolkit.mcmaster_path(data, 1), (200, 200), "McMaster 1")):
        if path.exists():
            out.append((label, toolkit.load_scene(path), at))
    chart = demo_chart().image
    out.append(("demo chart, zone plate", chart, (420, 20)))
    out.append(("demo chart, dead leaves", chart, (430, 580)))
    return out


def tone(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return (np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055) * 255).astype(np.uint8)


def row(scene: np.ndarray, at: tuple[int, int], gain: float | None, folder: Path) -> tuple[list[np.ndarray], list[str]]:
    sim = simulate(scene, "bayer", gain=gain, seed=0)
    before, _, after = bdq.split_at_demosaic(build_pipeline(sim.raw, output="linear"))
    images, names = [sim.truth], ["truth"]
    for name in METHODS:
        images.append(bdq.run_on_rgb(after, bdq.clisp_camera_rgb(sim.raw, before, make_demosaic(name, sim.raw))))
        names.append(name.upper() if name != "dlmmse" else "DLMMSE")
    for algo in LIBRAW:
        images.append(bdq.run_on_rgb(after, bdq.libraw_camera_rgb(sim.raw, algo, folder)))
        names.append(f"LibRaw {algo}")
    y, x = at
    return [tone(im[y:y + SIDE, x:x + SIDE]) for im in images], names


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    toolkit.add_data_option(ap, "kodak/ and mcmaster/")
    ap.add_argument("--out", type=Path, default=toolkit.REPO / "docs" / "demosaic_crops.png")
    ap.add_argument("--gain", type=float, default=None, help="analog gain (default: noiseless)")
    args = ap.parse_args()
    from PIL import Image, ImageDraw
    rows, names = [], []
    with tempfile.TemporaryDirectory() as folder:
        for label, scene, at in regions(args.data):
            tiles, names = row(scene, at, args.gain, Path(folder))
            rows.append(np.concatenate([np.pad(t, ((2, 2), (2, 2), (0, 0)), constant_values=255) for t in tiles], axis=1))
            print(f"{label}: done", flush=True)
    grid = np.concatenate(rows, axis=0)
    img = Image.fromarray(grid).resize((grid.shape[1] * 2, grid.shape[0] * 2), Image.NEAREST)
    header = Image.new("RGB", (img.width, 24), "white")
    draw = ImageDraw.Draw(header)
    for i, name in enumerate(names):
        draw.text((i * (SIDE + 4) * 2 + 6, 6), name, fill="black")
    out = Image.new("RGB", (img.width, img.height + 24), "white")
    out.paste(header, (0, 0))
    out.paste(img, (0, 24))
    out.save(args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
