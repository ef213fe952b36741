"""What each CFA allows a linear demosaic: per-phase least-squares filters, trained the same way for
the LMS and the Bayer camera (issue 28, the structural part of "The LMS camera against the
strongest Bayer").

For a CFA of period P, the output (linear sRGB, after the camera's colour matrix) at a pixel of
phase (y mod P, x mod P) is a linear function of the K x K white-balanced mosaic around it (plus a
constant): 3 P^2 filters, fitted by least squares (ridge 1e-8 x trace / n) on noiseless simulated
raws (clisp.sim.simulate, Airy optics) of dead-leaves charts of seeds 1000.. (never those the
benchmarks judge, 0..7), every pixel of every phase but a 16 px border. The filters then demosaic
and colour-convert held-out scenes in one step; no chroma denoiser (noiseless). Scores: PSNR (dB)
tone-mapped, 10 px border, against the simulation's truth, as tools/bench_demosaic_quality.py.

The same estimator class, training data and support for both CFAs: the difference of the two
columns is what the CFA's sampling and its colour matrix cost a linear estimator (Condat's and
Alleysson's frequency analyses in one number), not an algorithm's quality. Adaptive demosaics
beat these bounds (their point is to be non-linear), so they bound nothing; they measure how hard
each CFA's problem is.

    python tools/cfa_linear_bound.py [--data ../shared/data] [--sets kodak,mcmaster,deadleaves]
        [--subset N] [--dead-leaves 8] [--train 12] [--support 13] [--csv FILE]
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path
from toolkit import BORDER
from bench import normalised_mosaic
from bench_demosaic_quality import load_scenes
from clisp.metrics import psnr
from clisp.sim.charts import dead_leaves
from clisp.sim.simulate import simulate

TRAIN_SEED0 = 1000
"""First dead-leaves seed of the training charts (the benchmarks judge seeds 0..7)."""
TRAIN_BORDER = 16
RIDGE = 1e-8


def patches(mosaic: np.ndarray, k: int) -> np.ndarray:
    """H x W x (k^2 + 1): the k x k neighbourhood of every pixel (mirror-padded), then 1."""
    r = k // 2
    padded = np.pad(mosaic, r, mode="reflect")
    h, w = mosaic.shape
    win = np.lib.stride_tricks.sliding_window_view(padded, (k, k)).reshape(h, w, k * k)
    return np.concatenate([win, np.ones((h, w, 1))], axis=-1)


class LinearBank:
    """Per-phase least-squares filters of one CFA kind (normal equations accumulated per image)."""

    def __init__(self, kind: str, period: int, support: int) -> None:
        self.kind, self.period, self.support = kind, period, support
        n = support * support + 1
        self.xtx = np.zeros((period, period, n, n))
        self.xty = np.zeros((period, period, n, 3))
        self.weights: np.ndarray | None = None

    def add(self, mosaic: np.ndarray, truth: np.ndarray) -> None:
        x = patches(mosaic, self.support)
        b = TRAIN_BORDER
        for py in range(self.period):
            for px in range(self.period):
                y0 = b + (py - b) % self.period
                x0 = b + (px - b) % self.period
                xs = x[y0:-b:self.period, x0:-b:self.period].reshape(-1, x.shape[-1])
                ts = truth[y0:-b:self.period, x0:-b:self.period].reshape(-1, 3).astype(np.float64)
                self.xtx[py, px] += xs.T @ xs
                self.xty[py, px] += xs.T @ ts

    def solve(self) -> None:
        n = self.xtx.shape[-1]
        self.weights = np.empty_like(self.xty)
        for py in range(self.period):
            for px in range(self.period):
                a = self.xtx[py, px]
                ridge = RIDGE * np.trace(a) / n
                self.weights[py, px] = np.linalg.solve(a + ridge * np.eye(n), self.xty[py, px])

    def apply(self, mosaic: np.ndarray) -> np.ndarray:
        """H x W x 3 linear sRGB of a mosaic whose pixel (0, 0) has phase (0, 0)."""
        x = patches(mosaic, self.support)
        out = np.empty(mosaic.shape + (3,))
        for py in range(self.period):
            for px in range(self.period):
                out[py::self.period, px::self.period] = x[py::self.period, px::self.period] @ self.weights[py, px]
        return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    toolkit.add_data_option(parser)
    toolkit.add_scene_set_options(parser)
    parser.add_argument("--train", type=int, default=12, help="dead-leaves training charts (512 px)")
    parser.add_argument("--support", type=int, default=13, help="filter side K (odd)")
    args = parser.parse_args(argv)
    if args.support % 2 == 0 or args.support < 3:
        raise SystemExit("--support must be odd and >= 3")
    start = time.perf_counter()
    banks = {"bayer": LinearBank("bayer", 2, args.support), "lms": LinearBank("lms", 4, args.support)}
    for i in range(args.train):
        scene = dead_leaves(512, seed=TRAIN_SEED0 + i)
        for kind, bank in banks.items():
            sim = simulate(scene, kind, gain=None, optics="airy", seed=0)
            bank.add(normalised_mosaic(sim.raw).astype(np.float64), sim.truth)
    for bank in banks.values():
        bank.solve()
    print(f"trained {args.support} x {args.support} per-phase filters on {args.train} dead-leaves charts "
          f"(seeds {TRAIN_SEED0}..{TRAIN_SEED0 + args.train - 1}) in {time.perf_counter() - start:.0f} s")
    scenes = load_scenes(args.data, args.sets.split(","), args.subset, args.dead_leaves, 512)
    rows = []
    print(f"{'set':11s} {'images':>6s} {'Bayer':>7s} {'LMS':>7s} {'LMS - Bayer':>12s}")
    for set_name, items in scenes.items():
        scores: dict[str, list[float]] = {k: [] for k in banks}
        for _, scene in items:
            for kind, bank in banks.items():
                sim = simulate(scene, kind, gain=None, optics="airy", seed=0)
                out = bank.apply(normalised_mosaic(sim.raw).astype(np.float64))
                scores[kind].append(psnr(out, sim.truth, border=BORDER))
        means = {k: float(np.mean(v)) for k, v in scores.items()}
        print(f"{set_name:11s} {len(items):6d} {means['bayer']:7.2f} {means['lms']:7.2f} "
              f"{means['lms'] - means['bayer']:+12.2f}", flush=True)
        for kind in banks:
            rows.append({"set": set_name, "cfa": kind, "support": args.support, "train": args.train,
                         "images": len(items), "psnr_db": round(means[kind], 3)})
    if args.csv:
        toolkit.write_csv(rows, args.csv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
