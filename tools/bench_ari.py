"""Speed of the Bayer demosaics on the device (DLMMSE, RI, ARI), in the same run (issues 12, 27).

    python tools/bench_ari.py [--shape 4000x6000] [--repeat 2] [--profile] [--methods dlmmse,ri,ari]
                              [--green 5] [--chroma 2] [--skip-dlmmse] [--no-dht]

A synthetic white-balanced Bayer mosaic (RGGB, float32, smooth colour fields with random discs and
noise) of --shape is processed by a one-stage Pipeline (the demosaic alone) through clisp's tiler at
the default memory budget (Pipeline.run: planner tiles, host padding, upload, kernels, download),
warm (one small run first builds the programs), best of --repeat: MP/s of output. Beside them, when
rawpy is installed (--no-dht: not), LibRaw's DHT on the same mosaic written as a 16-bit Bayer DNG by
clisp.io.rawfile.write_raw: only rawpy's postprocess is timed (DHT plus LibRaw's scaling, colour
conversion and 16-bit output; no file read or write), best of --repeat. --profile adds one
run with OpenCL event profiling and prints the device time per step and kernel (clisp.engine.profile; the
ARI stage labels its steps "demosaic_ari 1 green", "... 2 diagonals", "... 3 G sites").

Measured (commit 7027c40; PoCL 3.0 on 2 shared AMD EPYC cores, two other sessions busy; 24 MP,
default budget: ARI bands of 442 x 6242 windows (200 output rows + 2 x 121 halo, 20 bands),
DLMMSE 332 x 6024):
    DemosaicDLMMSE  0.42 s   57 MP/s
    DemosaicARI   334.9 s    0.07 MP/s   (profiled run: 291.6 s of device time)
Device time of ARI by step: step 1 (G, 4 chains x 5 iterations) 206 s (71%), step 2 (diagonals)
54 s (19%), step 3 (G sites) 31 s (11%). Top kernels: ari_across_coefficients 68 + 11 s (23% + 4%:
four weighted fits with sqrt and divisions per pixel, 12 moment planes read over the across
window), ari_box_apply 37 s, ari_diag_coefficients 28 s, ari_along_moments 25 + 5 s, box_x / box_y
20 + 17 s, criterion kernels (err_terms, gauss_x/y, select) ~36 s. The halo (121 px) costs 2.2x in
window pixels at this band height.

Measured (commit a2ec1fd against c03fc4e, back to back, twice; same PoCL on the same 2 EPYC cores,
shared with other sessions: load average 1.4-1.8 during the runs; under load ~5 an earlier pair ran
~1.7x slower, so compare only back-to-back pairs), --shape 1000x1500 --repeat 2 --skip-dlmmse
--profile (one 742 x 1742 window):
    c03fc4e   6.85 s / 6.25 s   0.22 / 0.24 MP/s   device 6.19 / 5.99 s
    a2ec1fd   3.72 s / 4.01 s   0.40 / 0.37 MP/s   device 2.98 / 3.31 s   (wall 1.6-1.8x, device 1.8-2.1x)
Device time by step (a2ec1fd, first pair): step 1 2.26 s (76%; c03fc4e 4.27 s), step 2 0.35 s
(1.11), step 3 0.37 s (0.81). Top kernels: ari_across_coefficients 0.94 s (step 1: four single-fit
launches per iteration), ari_box_apply 0.27 s, ari_along_moments 0.23 s, ari_select 0.21 s, box_x /
box_y 0.17 + 0.16 s, ari_diag_coefficients 0.12 s; the criterion's err_terms + gauss_x/y 0.28 s in
all three steps. Every ARI kernel now vectorises at width 8 (POCL_VECTORIZER_REMARKS: clisp/modules/demosaic_ari/README.md
says how to check).

Measured (commit f6d34d7 + this tool's DHT column; the machine otherwise idle; 24 MP, --repeat 1):
    DemosaicDLMMSE  0.27 s   89.3 MP/s
    DemosaicARI    53.6 s    0.45 MP/s   (--green 2: 23.7 s, 1.01 MP/s, halo 70)
    rawpy DHT       2.12 s   11.3 MP/s   (postprocess)
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import platform
import tempfile
from typing import Callable

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path

from clisp.cfa import bayer_cfa
from clisp.engine.runtime import get_runtime
from clisp.modules.demosaic_ari.stage import DemosaicARI
from clisp.modules.demosaic_dlmmse.stage import DemosaicDLMMSE
from clisp.modules.demosaic_ri.stage import DemosaicRI


def synthetic_mosaic(height: int, width: int, seed: int = 0) -> np.ndarray:
    """RGGB mosaic in [0, 1]: low-frequency colour fields, discs, noise sigma 0.01."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
    rgb = [0.4 + 0.3 * np.sin(xx / (50 + 30 * c) + c) * np.cos(yy / (70 + 20 * c)) for c in range(3)]
    small = rng.random((height // 64 + 1, width // 64 + 1, 3)).astype(np.float32)
    tiles = np.kron(small, np.ones((64, 64, 1), dtype=np.float32))[:height, :width]
    mos = np.empty((height, width), dtype=np.float32)
    for c, (oy, ox) in ((0, (0, 0)), (1, (0, 1)), (1, (1, 0)), (2, (1, 1))):
        mos[oy::2, ox::2] = (0.6 * rgb[c] + 0.4 * tiles[..., c])[oy::2, ox::2]
    mos += rng.normal(0, 0.01, mos.shape).astype(np.float32)
    return mos


def rawpy_dht(mos: np.ndarray, folder: str) -> Callable[[], object]:
    """rawpy (LibRaw) DHT postprocess of ``mos`` (RGGB, [0, 1]) written as a 16-bit DNG; returns the
    timed call (postprocess only)."""
    import rawpy

    from clisp.sim.colorimetry import B_BAYER
    from clisp.io.rawfile import write_raw
    from clisp.io.rawimage import RawImage
    data = np.round(np.clip(mos, 0.0, 1.0) * 65535.0).astype(np.uint16)
    raw = RawImage(data=data, cfa=bayer_cfa("RGGB"), black_level=np.zeros(3), white_level=65535.0,
                   wb=np.ones(3), colour_matrix=B_BAYER)
    path = os.path.join(folder, "ari-bench.dng")
    write_raw(path, raw)
    handle = rawpy.imread(path)
    options = dict(demosaic_algorithm=rawpy.DemosaicAlgorithm.DHT, output_bps=16, no_auto_bright=True,
                   user_wb=[1.0, 1.0, 1.0, 1.0])
    rgb = handle.postprocess(**options)
    if rgb.shape[:2] != mos.shape:
        raise SystemExit(f"rawpy decoded {rgb.shape[:2]}, expected {mos.shape}")
    return lambda: handle.postprocess(**options)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--shape", default="4000x6000", help="H x W of the mosaic (default 24 MP)")
    toolkit.add_repeat_option(ap, 2)
    ap.add_argument("--green", type=int, default=5, help="ARI green_iterations")
    ap.add_argument("--chroma", type=int, default=2, help="ARI chroma_iterations")
    ap.add_argument("--profile", action="store_true", help="one more run with event profiling, per kernel")
    ap.add_argument("--methods", default="dlmmse,ri,ari",
                    help="device demosaics to time, of dlmmse, ri, ari (comma-separated)")
    ap.add_argument("--skip-dlmmse", action="store_true", help="leave out DLMMSE (same as --methods without it)")
    ap.add_argument("--no-dht", action="store_true", help="leave out rawpy's DHT")
    args = ap.parse_args()
    h, w = toolkit.parse_shape(args.shape)
    cfa = bayer_cfa("RGGB")
    rt = get_runtime(profiling=args.profile)
    print(f"device: {rt.describe()}; host: {platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} CPUs visible")
    mos = synthetic_mosaic(h, w)
    makers = {"dlmmse": lambda: DemosaicDLMMSE(cfa), "ri": lambda: DemosaicRI(cfa),
              "ari": lambda: DemosaicARI(cfa, args.green, args.chroma)}
    methods = [m for m in args.methods.split(",") if m and not (args.skip_dlmmse and m == "dlmmse")]
    unknown = [m for m in methods if m not in makers]
    if unknown:
        raise SystemExit(f"unknown --methods {unknown}; choose from {sorted(makers)}")
    stages = [makers[m]() for m in methods]
    for stage in stages:
        toolkit.time_demosaic(stage, cfa, mos, args.repeat, profiled=args.profile)
    if not args.no_dht:
        if importlib.util.find_spec("rawpy") is None:
            print("rawpy DHT: absent (pip install rawpy)")
            return
        with tempfile.TemporaryDirectory() as folder:
            _, best = toolkit.best_of(rawpy_dht(mos, folder), args.repeat)
        print(f"{'rawpy DHT':16s} {'':18s}{'':24s}{best:7.2f} s  {h * w / 1e6 / best:6.2f} MP/s (postprocess)")


if __name__ == "__main__":
    main()
