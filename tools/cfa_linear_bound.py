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

With noise (``--gains none,4,16,64``; issue 45) each CFA and gain gets its own bank, trained on the
training charts simulated with the sensor's noise at that gain (seed = the chart's index) against
the clean truth: the least-squares filters are then the best *linear* joint demosaic, colour
conversion and denoise for that noise (a per-phase LMMSE estimator with the noise statistics of the
sensor and the signal statistics of dead leaves), the floor any non-linear pipeline should clear.
``--cfas`` takes any CFA names (``bayer``, ``lms``, ``lms-bayer``, ``ML/LS``, pattern strings); the
period of each bank is its CFA's.

    python tools/cfa_linear_bound.py [--data ../shared/data] [--sets kodak,mcmaster,deadleaves]
        [--subset N] [--dead-leaves 8] [--train 12] [--support 13] [--cfas bayer,lms]
        [--gains none] [--csv FILE]
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


BAND = 64
"""Rows of patches built at once (a multiple of every CFA period): 64 x 512 x 122 float64 is 32 MB,
where a whole Kodak image's patches would take 380 MB."""


def bands(height: int, border: int = 0) -> list[tuple[int, int]]:
    """(y0, y1) row bands of BAND rows covering border..height - border."""
    return [(y, min(y + BAND, height - border)) for y in range(border, height - border, BAND)]


class LinearBank:
    """Per-phase least-squares filters of one CFA kind (normal equations accumulated per image)."""

    def __init__(self, kind: str, period: int, support: int) -> None:
        self.kind, self.period, self.support = kind, period, support
        n = support * support + 1
        self.xtx = np.zeros((period, period, n, n))
        self.xty = np.zeros((period, period, n, 3))
        self.weights: np.ndarray | None = None

    def band_patches(self, mosaic: np.ndarray, y0: int, y1: int) -> np.ndarray:
        """patches() of rows y0..y1 only (mirror padding of the whole mosaic)."""
        r = self.support // 2
        return patches(np.pad(mosaic, r, mode="reflect")[y0:y1 + 2 * r], self.support)[r:-r, r:-r]

    def add(self, mosaic: np.ndarray, truth: np.ndarray) -> None:
        b, p = TRAIN_BORDER, self.period
        w = mosaic.shape[1]
        for y0, y1 in bands(mosaic.shape[0], b):
            x = self.band_patches(mosaic, y0, y1)
            for py in range(p):
                for px in range(p):
                    ry = (py - y0) % p                      # first row of phase py in the band
                    x0 = b + (px - b) % p
                    xs = x[ry::p, x0:w - b:p].reshape(-1, x.shape[-1])
                    ts = truth[y0 + ry:y1:p, x0:w - b:p].reshape(-1, 3).astype(np.float64)
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
        out = np.empty(mosaic.shape + (3,))
        p = self.period
        for y0, y1 in bands(mosaic.shape[0]):
            x = self.band_patches(mosaic, y0, y1)
            for py in range(p):
                ry = (py - y0) % p
                for px in range(p):
                    out[y0 + ry:y1:p, px::p] = x[ry::p, px::p] @ self.weights[py, px]
        return out


def parse_gains(text: str) -> list[float | None]:
    """'none,4,16' -> [None, 4.0, 16.0] (None: noiseless)."""
    return [None if g.strip().lower() in ("none", "noiseless", "0") else float(g) for g in text.split(",")]


def gain_name(gain: float | None) -> str:
    return "noiseless" if gain is None else f"{gain:g}"


def train_banks(cfas: list[str], gains: list[float | None], train: int, support: int
                ) -> dict[tuple[str, float | None], LinearBank]:
    """{(CFA name, gain): bank} trained on ``train`` dead-leaves charts (seeds TRAIN_SEED0..), each
    simulated with Airy optics and, at a gain, the sensor's noise (seed = chart index)."""
    from clisp.cfa import cfa_from_name
    banks = {(name, g): LinearBank(name, cfa_from_name(name).period, support) for name in cfas for g in gains}
    for i in range(train):
        scene = dead_leaves(512, seed=TRAIN_SEED0 + i)
        for (name, g), bank in banks.items():
            sim = simulate(scene, name, gain=g, optics="airy", seed=i)
            bank.add(normalised_mosaic(sim.raw).astype(np.float64), sim.truth)
    for bank in banks.values():
        bank.solve()
    return banks


def score_banks(banks: dict[tuple[str, float | None], LinearBank], scenes: dict[str, list]
                ) -> dict[tuple[str, str, float | None], float]:
    """{(set, CFA name, gain): mean PSNR} of each bank on the held-out scenes, simulated with its CFA
    and gain (noise seed 0), PSNR tone-mapped with toolkit.BORDER."""
    out = {}
    for set_name, items in scenes.items():
        for (name, g), bank in banks.items():
            scores = []
            for _, scene in items:
                sim = simulate(scene, name, gain=g, optics="airy", seed=0)
                scores.append(psnr(bank.apply(normalised_mosaic(sim.raw).astype(np.float64)), sim.truth,
                                   border=BORDER))
            out[(set_name, name, g)] = float(np.mean(scores))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    toolkit.add_data_option(parser)
    toolkit.add_scene_set_options(parser)
    parser.add_argument("--train", type=int, default=12, help="dead-leaves training charts (512 px)")
    parser.add_argument("--support", type=int, default=13, help="filter side K (odd)")
    parser.add_argument("--cfas", default="bayer,lms", help="CFA names, comma-separated (any clisp --cfa)")
    parser.add_argument("--gains", default="none", help="noise levels: none (noiseless) and gains, e.g. none,4,16,64")
    args = parser.parse_args(argv)
    if args.support % 2 == 0 or args.support < 3:
        raise SystemExit("--support must be odd and >= 3")
    start = time.perf_counter()
    cfas, gains = args.cfas.split(","), parse_gains(args.gains)
    banks = train_banks(cfas, gains, args.train, args.support)
    print(f"trained {args.support} x {args.support} per-phase filters on {args.train} dead-leaves charts "
          f"(seeds {TRAIN_SEED0}..{TRAIN_SEED0 + args.train - 1}) in {time.perf_counter() - start:.0f} s")
    scenes = load_scenes(args.data, args.sets.split(","), args.subset, args.dead_leaves, 512)
    scores = score_banks(banks, scenes)
    rows = []
    print(f"{'set':11s} {'images':>6s} {'gain':>9s} " + " ".join(f"{c:>10s}" for c in cfas))
    for set_name, items in scenes.items():
        for g in gains:
            print(f"{set_name:11s} {len(items):6d} {gain_name(g):>9s} "
                  + " ".join(f"{scores[(set_name, c, g)]:10.2f}" for c in cfas), flush=True)
            for c in cfas:
                rows.append({"set": set_name, "cfa": c, "gain": gain_name(g), "support": args.support,
                             "train": args.train, "images": len(items),
                             "psnr_db": round(scores[(set_name, c, g)], 3)})
    if args.csv:
        toolkit.write_csv(rows, args.csv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
