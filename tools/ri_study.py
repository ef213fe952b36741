"""Residual-interpolation demosaics (clisp/stages/bayer_ri.py) in the classic protocol, beside our DLMMSE.

The protocol is tools/bayer_demosaic_protocol.py's (its load_8bit, mosaic and cpsnr are imported):
every Kodak (24 PNG) and McMaster (18 TIFF) image, sRGB-encoded 8-bit as float in [0, 1], is
mosaicked RGGB (no noise) and demosaicked; CPSNR over the 3 channels with a 10 px border, outputs
clipped to [0, 1]. "clisp DLMMSE" runs our OpenCL stage through a Pipeline holding only it, as the
protocol tool does. Printed: per-set mean CPSNR and mean seconds per image of every method (wall
time of the call on this machine; the NumPy methods are single-threaded float64 references).

    python tools/ri_study.py [--data ../shared/data] [--sets Kodak,McMaster] [--methods REGEX]
                             [--limit N] [--per-image] [--csv out.csv] [--halo]

--halo: instead of the protocol, the distance (px) from a tile's edge beyond which a tile's output
equals the whole image's output to 1e-6 ([0, 1] units), per method, on kodim19.
"""
from __future__ import annotations

import argparse
import csv
import re
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bayer_demosaic_protocol import CFA, SETS, cpsnr, load_8bit, mosaic  # noqa: E402

from clisp.stages import bayer_ri  # noqa: E402

Method = Callable[[np.ndarray], np.ndarray]


def dlmmse() -> Method:
    from clisp.pipeline import Pipeline
    from clisp.stages.demosaic_dlmmse import DemosaicDLMMSE
    pipeline = Pipeline(CFA, [DemosaicDLMMSE(CFA)])
    return lambda m: pipeline.run(m.astype(np.float32))


METHODS: dict[str, Callable[[], Method]] = {
    "RI": lambda: bayer_ri.demosaic_ri,
    "MLRI": lambda: bayer_ri.demosaic_mlri,
    "MLRI weighted": lambda: lambda m: bayer_ri.demosaic_mlri(m, weighted=True),
    "ARI": lambda: bayer_ri.demosaic_ari,
    "ARI hybrid": lambda: bayer_ri.demosaic_ari_hybrid,
    "ARI gbtf, mean chroma": lambda: lambda m: bayer_ri.demosaic_ari(m, green_merge="gbtf", chroma="mean"),
    "clisp DLMMSE": dlmmse,
}
"""Name -> factory of the demosaic (mosaic H x W in [0, 1], RGGB -> H x W x 3)."""


def image_files(data: Path, set_name: str, limit: int | None) -> list[Path]:
    folder, pattern = SETS[set_name]
    files = sorted((data / folder).glob(pattern), key=lambda p: (len(p.stem), p.stem))
    if not files:
        raise SystemExit(f"no {pattern} images in {data / folder}; pass --data")
    return files[:limit] if limit else files


def run_protocol(data: Path, sets: list[str], methods: dict[str, Method], limit: int | None,
                 per_image: bool) -> list[dict]:
    """One row per (set, image, method): CPSNR in dB and seconds."""
    rows = []
    for set_name in sets:
        for path in image_files(data, set_name, limit):
            truth = load_8bit(path)
            m = mosaic(truth)
            line = []
            for name, fn in methods.items():
                start = time.perf_counter()
                out = fn(m)
                seconds = time.perf_counter() - start
                value = cpsnr(out, truth)
                rows.append(dict(set=set_name, image=path.name, method=name, cpsnr=value, seconds=seconds))
                line.append(f"{value:6.2f}")
            if per_image:
                print(f"{set_name:9s} {path.name:12s} " + " ".join(line), flush=True)
    return rows


def print_means(rows: list[dict], sets: list[str], names: list[str]) -> None:
    print("\nCPSNR (dB), sRGB-encoded 8-bit images mosaicked RGGB, border 10 px, per-set mean; "
          "s/img: mean seconds per image")
    counts = {s: len({r["image"] for r in rows if r["set"] == s}) for s in sets}
    print(f"{'method':24s}" + "".join(f"{f'{s} ({counts[s]})':>16s}{'s/img':>8s}" for s in sets))
    for name in names:
        cells = []
        for s in sets:
            sel = [r for r in rows if r["set"] == s and r["method"] == name]
            cells.append(f"{np.mean([r['cpsnr'] for r in sel]):16.2f}{np.mean([r['seconds'] for r in sel]):8.2f}")
        print(f"{name:24s}" + "".join(cells))


def halo(data: Path, methods: dict[str, Method], core: int = 64,
         margins: tuple[int, ...] = (8, 12, 16, 20, 24, 32, 48, 64, 96, 128)) -> None:
    """Per method: max |tile - whole| over a core x core block in the middle of kodim19, the tile
    being that block grown by each margin (even: the tile keeps the RGGB phase)."""
    truth = load_8bit(data / "kodak" / "kodim19.png")
    m = mosaic(truth)
    y0, x0 = (m.shape[0] - core) // 2 // 2 * 2, (m.shape[1] - core) // 2 // 2 * 2
    print(f"max |tile - whole image| on a {core} x {core} block of kodim19 ({m.shape[1]} x {m.shape[0]}), "
          f"per margin (px of context around the block)")
    print(f"{'method':24s}" + "".join(f"{k:>10d}" for k in margins))
    for name, fn in methods.items():
        whole = fn(m)[y0:y0 + core, x0:x0 + core]
        cells = []
        for k in margins:
            if y0 - k < 0 or x0 - k < 0:
                cells.append(f"{'-':>10s}")
                continue
            tile = fn(m[y0 - k:y0 + core + k, x0 - k:x0 + core + k])[k:k + core, k:k + core]
            cells.append(f"{np.abs(tile - whole).max():10.1e}")
        print(f"{name:24s}" + "".join(cells), flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    repo = Path(__file__).resolve().parents[1]
    parser.add_argument("--data", default=str(repo.parent / "shared" / "data"),
                        help="folder holding kodak/ and mcmaster/ (default: ../shared/data from the repo root)")
    parser.add_argument("--sets", default=",".join(SETS), help=f"comma-separated, of {','.join(SETS)}")
    parser.add_argument("--methods", default=".", help="regex on the method names: " + ", ".join(METHODS))
    parser.add_argument("--limit", type=int, default=None, help="first N images of every set (quick tuning)")
    parser.add_argument("--per-image", action="store_true", help="also print every image's CPSNR")
    parser.add_argument("--csv", default=None, help="write one row per (set, image, method) here")
    parser.add_argument("--halo", action="store_true", help="measure the effective halo instead")
    args = parser.parse_args(argv)
    data = Path(args.data)
    names = [n for n in METHODS if re.search(args.methods, n)]
    if not names:
        raise SystemExit(f"--methods {args.methods!r} matches none of: {', '.join(METHODS)}")
    sets = [s.strip() for s in args.sets.split(",") if s.strip()]
    unknown = [s for s in sets if s not in SETS]
    if unknown:
        raise SystemExit(f"unknown set(s) {unknown}; choose from {', '.join(SETS)}")
    methods = {n: METHODS[n]() for n in names}
    if args.halo:
        halo(data, {n: f for n, f in methods.items() if n != "clisp DLMMSE"})
        return 0
    if args.per_image:
        print(f"{'set':9s} {'image':12s} " + " ".join(f"{n[:6]:>6s}" for n in names))
    rows = run_protocol(data, sets, methods, args.limit, args.per_image)
    print_means(rows, sets, names)
    if args.csv:
        with open(args.csv, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=["set", "image", "method", "cpsnr", "seconds"])
            writer.writeheader()
            writer.writerows(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
