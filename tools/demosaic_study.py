"""Issue 12 study: plain-NumPy Bayer demosaic candidates against our DLMMSE and LibRaw's demosaics,
in the classic protocol of tools/bayer_demosaic_protocol.py.

Protocol (that tool's ``mosaic``; toolkit's ``load_8bit`` and ``cpsnr``): every Kodak (24 PNG) and
McMaster (18 TIFF) image, sRGB-ENCODED 8-bit as float in [0, 1], mosaicked RGGB (no noise),
demosaicked, clipped to [0, 1] and scored by CPSNR with a 10 px border excluded.

Methods:

    RCD, GBTF, RCD-GBTF, ...     research.demosaic.bayer_rcd / bayer_gbtf / bayer_rcd_gbtf and their
                                 variants, NumPy float64, on the mosaic
    RI, MLRI, ARI, ...           clisp.modules.demosaic_ari.reference (residual interpolation) and its variants;
                                 ARI takes about 9 s per Kodak image: select with --methods
    clisp bilinear / DLMMSE      our OpenCL stages, Pipeline(CFA, [stage]).run(mosaic as float32),
                                 exactly as bayer_demosaic_protocol.py runs them
    LibRaw LINEAR/AHD/DHT/...    rawpy (LibRaw) on the same mosaic written as a Bayer DNG by
                                 clisp.io.rawfile.write_raw (uint16 = round(65535 mosaic), black 0,
                                 white 65535, wb 1, identity colour matrix); postprocess with
                                 output_color raw, gamma (1, 1), no_auto_bright, output_bps 16,
                                 user_wb ones, user_flip 0, highlight_mode Ignore (tools/bench.py's
                                 options) and adjust_maximum_thr 0 (LibRaw's default 0.75 takes
                                 the image's own maximum as white when it is above 0.75 white,
                                 which rescales McMaster images such as 3.tif by 1.076);
                                 result / 65535. LINEAR is the harness check: it must
                                 match our bilinear, and every LibRaw output keeps the mosaic's
                                 samples at their own sites (checked on every image, see
                                 ``check_libraw``), so no shift or scale goes unnoticed.

Printed: per-set mean CPSNR of every method and its mean wall time per image (NumPy candidates
single-threaded NumPy, OpenCL on the device the runtime picks, LibRaw including the DNG read and
postprocess, not the write). The machine may be shared: times are indicative.

    python tools/demosaic_study.py [--data ../shared/data] [--sets Kodak,McMaster]
        [--methods REGEX] [--per-image] [--limit N] [--csv out.csv] [--halo]

``--halo`` measures instead, per NumPy candidate, how much context a tile needs: the largest
|tile - whole image| over a 64 x 64 block of kodim19 for tiles grown by 8..128 px.
"""
from __future__ import annotations

import argparse
import hashlib
import re
import sys
import tempfile
import time
from pathlib import Path
from typing import Callable

import numpy as np

import toolkit  # before clisp: puts this checkout (clisp, research/) on sys.path
from toolkit import cpsnr, image_files, load_8bit

from bayer_demosaic_protocol import CFA, SETS, mosaic
from clisp.pipeline import Pipeline
from clisp.modules.demosaic_ari import reference as bayer_ri
from research.demosaic.bayer_gbtf import SLOW_TAPS, demosaic_gbtf
from research.demosaic.bayer_rcd import demosaic_rcd
from research.demosaic.bayer_rcd_gbtf import demosaic_rcd_gbtf
from clisp.modules.demosaic_bilinear.stage import DemosaicBilinear
from clisp.modules.demosaic_dlmmse.stage import DemosaicDLMMSE

Method = Callable[[np.ndarray], np.ndarray]

LIBRAW_ALGOS = ("LINEAR", "AHD", "DHT", "AAHD", "VNG", "DCB")


def candidates() -> dict[str, Method]:
    """The NumPy candidates of this study, by name."""
    return {
        "RCD": lambda m: demosaic_rcd(m, "RGGB"),
        "RCD (no clip)": lambda m: demosaic_rcd(m, "RGGB", clip=False),
        "GBTF": lambda m: demosaic_gbtf(m, "RGGB"),
        "GBTF (mean R/B at G)": lambda m: demosaic_gbtf(m, "RGGB", rb_at_green="mean"),
        "GBTF (slow taps)": lambda m: demosaic_gbtf(m, "RGGB", taps=SLOW_TAPS),
        "RCD-GBTF": lambda m: demosaic_rcd_gbtf(m, "RGGB"),
        "RI": bayer_ri.demosaic_ri,
        "MLRI": bayer_ri.demosaic_mlri,
        "MLRI weighted": lambda m: bayer_ri.demosaic_mlri(m, weighted=True),
        "ARI": bayer_ri.demosaic_ari,
        "ARI hybrid": bayer_ri.demosaic_ari_hybrid,
        "ARI gbtf, mean chroma": lambda m: bayer_ri.demosaic_ari(m, green_merge="gbtf", chroma="mean"),
        "ARI5": lambda m: bayer_ri.demosaic_ari(m, green_iterations=5),
        "ARI5 mean merge": lambda m: bayer_ri.demosaic_ari(m, green_iterations=5, green_merge="mean"),
        "ARI5 hybrid": lambda m: bayer_ri.demosaic_ari(m, green_iterations=5, green_merge="mean", chroma="mean"),
    }


def ours() -> dict[str, Method]:
    def pipeline(stage) -> Method:
        return lambda m: Pipeline(CFA, [stage]).run(m.astype(np.float32))
    return {"clisp bilinear": pipeline(DemosaicBilinear(CFA)), "clisp DLMMSE": pipeline(DemosaicDLMMSE(CFA))}


class LibRaw:
    """LibRaw demosaics through rawpy; the DNG of a mosaic is written once and reused by every
    algorithm (keyed by a hash of the mosaic's bytes)."""

    def __init__(self, folder: Path) -> None:
        self.key: str | None = None
        self.path = folder / "mosaic.dng"

    def dng(self, m: np.ndarray) -> Path:
        from clisp.io.rawfile import write_raw
        from clisp.io.rawimage import RawImage
        key = hashlib.sha1(np.ascontiguousarray(m).tobytes()).hexdigest()
        if self.key != key:
            data = np.round(np.clip(m, 0.0, 1.0) * 65535.0).astype(np.uint16)
            write_raw(self.path, RawImage(data=data, cfa=CFA, black_level=np.zeros(3), white_level=65535.0,
                                          wb=np.ones(3), colour_matrix=np.eye(3), source="demosaic_study"))
            self.key = key
        return self.path

    def method(self, algo: str) -> Method:
        import rawpy
        options = dict(demosaic_algorithm=getattr(rawpy.DemosaicAlgorithm, algo),
                       output_color=rawpy.ColorSpace.raw, gamma=(1, 1), no_auto_bright=True,
                       output_bps=16, user_wb=[1.0, 1.0, 1.0, 1.0], user_flip=0,
                       highlight_mode=rawpy.HighlightMode.Ignore,
                       adjust_maximum_thr=0.0)  # else LibRaw rescales images whose maximum is < white

        def run(m: np.ndarray) -> np.ndarray:
            path = self.dng(m)
            with rawpy.imread(str(path)) as handle:
                rgb = handle.postprocess(**options)
            return rgb.astype(np.float64) / 65535.0
        return run


def check_libraw(name: str, out: np.ndarray, m: np.ndarray) -> None:
    """LibRaw's output must have the mosaic's shape and keep its samples at their own sites
    (all of these LibRaw methods do): catches a shifted, flipped, cropped or rescaled result."""
    if out.shape != m.shape + (3,):
        raise SystemExit(f"{name}: LibRaw returned {out.shape}, expected {m.shape + (3,)}")
    channel = CFA.channel_map(*m.shape)
    sites = np.take_along_axis(out, channel[..., None].astype(np.intp), axis=2)[..., 0]
    inner = (slice(4, -4), slice(4, -4))
    error = np.abs(sites[inner] - np.round(m[inner] * 65535) / 65535).max()
    if error > 1.0 / 65535:
        raise SystemExit(f"{name}: LibRaw's samples differ from the mosaic by {error:.2e} (shift or scale?)")


def study(data: Path, sets: list[str], pattern: str, per_image: bool, limit: int | None,
          folder: Path) -> tuple[dict[str, dict[str, list[float]]], dict[str, list[float]]]:
    """CPSNR {set: {method: [dB per image]}} and wall times {method: [s per image]}."""
    libraw = LibRaw(folder)
    methods: dict[str, Method] = {**candidates(), **ours()}
    methods.update({f"LibRaw {a}": libraw.method(a) for a in LIBRAW_ALGOS})
    methods = {k: v for k, v in methods.items() if re.search(pattern, k)}
    if not methods:
        raise SystemExit(f"no method matches {pattern!r}")
    scores: dict[str, dict[str, list[float]]] = {}
    times: dict[str, list[float]] = {name: [] for name in methods}
    for set_name in sets:
        files = image_files(data, SETS[set_name], limit, numeric=True)
        scores[set_name] = {name: [] for name in methods}
        if per_image:
            print(f"{'set':9s} {'image':12s} " + " ".join(f"{n[:14]:>14s}" for n in methods), flush=True)
        for path in files:
            truth = load_8bit(path)
            m = mosaic(truth)
            row = []
            for name, method in methods.items():
                start = time.perf_counter()
                out = method(m)
                times[name].append(time.perf_counter() - start)
                if name.startswith("LibRaw"):
                    check_libraw(name, out, m)
                value = cpsnr(out, truth)
                scores[set_name][name].append(value)
                row.append(f"{value:14.2f}")
            if per_image:
                print(f"{set_name:9s} {path.name:12s} " + " ".join(row), flush=True)
    return scores, times


def print_table(scores: dict[str, dict[str, list[float]]], times: dict[str, list[float]]) -> None:
    sets = list(scores)
    names = list(times)
    print("\nCPSNR (dB), sRGB-encoded 8-bit images mosaicked RGGB, no noise, border 10 px, per-set mean")
    print(f"{'method':26s}" + "".join(f"{s + f' ({len(scores[s][names[0]])})':>16s}" for s in sets)
          + f"{'s / image':>12s}")
    for name in names:
        print(f"{name:26s}" + "".join(f"{np.mean(scores[s][name]):16.2f}" for s in sets)
              + f"{np.mean(times[name]):12.3f}")


def write_csv(path: Path, scores: dict[str, dict[str, list[float]]], times: dict[str, list[float]]) -> None:
    """One row per method and set: images, mean CPSNR (dB) and mean seconds per image."""
    toolkit.write_csv([dict(method=name, set=set_name, images=len(values), cpsnr_mean_db=f"{np.mean(values):.4f}",
                            seconds_per_image=f"{np.mean(times[name]):.4f}")
                       for set_name, by_method in scores.items() for name, values in by_method.items()], path)


def halo(data: Path, methods: dict[str, Method], core: int = 64,
         margins: tuple[int, ...] = (8, 12, 16, 20, 24, 32, 48, 64, 96, 128)) -> None:
    """Per method: max |tile - whole| over a core x core block in the middle of kodim19, the tile
    being that block grown by each margin (even: the tile keeps the RGGB phase)."""
    m = mosaic(load_8bit(toolkit.kodak_path(data, 19)))
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
    toolkit.add_data_option(parser)
    parser.add_argument("--sets", default="Kodak,McMaster", help="comma-separated subset of Kodak,McMaster")
    parser.add_argument("--methods", default=".", help="regular expression on the method names")
    parser.add_argument("--per-image", action="store_true", help="also print every image's CPSNR")
    parser.add_argument("--limit", type=int, default=None, help="first N images of every set (quick tuning)")
    parser.add_argument("--csv", default=None, help="write the per-set means to this CSV file")
    parser.add_argument("--halo", action="store_true", help="measure the NumPy candidates' effective halo instead")
    args = parser.parse_args(argv)
    if args.halo:
        halo(args.data, {k: v for k, v in candidates().items() if re.search(args.methods, k)})
        return 0
    sets = [s.strip() for s in args.sets.split(",") if s.strip()]
    unknown = [s for s in sets if s not in SETS]
    if unknown:
        raise SystemExit(f"unknown set(s) {unknown}; choose from {list(SETS)}")
    with tempfile.TemporaryDirectory() as folder:
        scores, times = study(args.data, sets, args.methods, args.per_image, args.limit, Path(folder))
    print_table(scores, times)
    if args.csv:
        write_csv(Path(args.csv), scores, times)
    return 0


if __name__ == "__main__":
    sys.exit(main())
