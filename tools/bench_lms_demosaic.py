"""Device speed of the LMS demosaics (guided, hybrid, bilinear), in the same run (issue 28).

    python tools/bench_lms_demosaic.py [--shape 4000x6000] [--repeat 2] [--methods guided,hybrid,bilinear]
                                       [--gain 16] [--profile]

A synthetic white-balanced LMS mosaic (the paper's 4 x 4 CFA, float32, smooth colour fields with
random 64 px tiles and noise sigma 0.01) of --shape is processed by a one-stage Pipeline (the
demosaic alone) through clisp's tiler at the default memory budget (planner tiles, host padding,
upload, kernels, download), warm (one small run first builds the programs), best of --repeat: MP/s
of output. Each stage is configured by its ``for_raw`` for a small LMS raw simulated at --gain
(0: noiseless), so noise-adaptive stages run their noisy kernels as in the pipeline. --profile adds
one run with OpenCL event profiling and prints the device time per kernel (clisp.engine.profile).
Bayer counterparts: tools/bench_ari.py (same method and synthetic content).
"""
from __future__ import annotations

import argparse
import os
import platform
import sys

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path

from clisp.cfa import lms_cfa
from clisp.engine.runtime import get_runtime
from clisp.pipeline import DEMOSAICS
from clisp.sim.simulate import simulate

LMS_METHODS = ("guided", "hybrid", "bilinear")


def synthetic_lms_mosaic(height: int, width: int, seed: int = 0) -> np.ndarray:
    """LMS mosaic (paper CFA, phase (0, 0)) in [0, 1]: low-frequency colour fields, 64 px tiles of
    random colour, noise sigma 0.01; H x W float32."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    planes = [0.4 + 0.3 * np.sin(xx / (50 + 30 * c) + c) * np.cos(yy / (70 + 20 * c)) for c in range(3)]
    small = rng.random((height // 64 + 1, width // 64 + 1, 3)).astype(np.float32)
    tiles = np.kron(small, np.ones((64, 64, 1), dtype=np.float32))[:height, :width]
    channel = lms_cfa().channel_map(height, width)
    mos = np.empty((height, width), dtype=np.float32)
    for c in range(3):
        sel = channel == c
        mos[sel] = (0.6 * planes[c] + 0.4 * tiles[..., c])[sel]
    mos += rng.normal(0, 0.01, mos.shape).astype(np.float32)
    return mos


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shape", default="4000x6000", help="H x W of the mosaic (default 24 MP)")
    toolkit.add_repeat_option(ap, 2)
    ap.add_argument("--methods", default=",".join(LMS_METHODS), help="of " + ", ".join(LMS_METHODS))
    ap.add_argument("--gain", type=float, default=16.0, help="gain of the raw the stages are configured for (0: noiseless)")
    ap.add_argument("--profile", action="store_true", help="one more run with event profiling, per kernel")
    args = ap.parse_args(argv)
    h, w = toolkit.parse_shape(args.shape)
    methods = [m for m in args.methods.split(",") if m]
    unknown = [m for m in methods if m not in LMS_METHODS]
    if unknown:
        raise SystemExit(f"unknown --methods {unknown}; choose from {', '.join(LMS_METHODS)}")
    rt = get_runtime(profiling=args.profile)
    print(f"device: {rt.describe()}; host: {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} CPUs visible; stages configured for gain {args.gain:g}")
    small = np.full((64, 64, 3), 0.3, dtype=np.float32)
    raw = simulate(small, "lms", gain=args.gain or None, seed=0).raw
    cfa = lms_cfa()
    mos = synthetic_lms_mosaic(h, w)
    for name in methods:
        toolkit.time_demosaic(DEMOSAICS[name].for_raw(raw), cfa, mos, args.repeat, 20, args.profile)
    return 0


if __name__ == "__main__":
    sys.exit(main())
