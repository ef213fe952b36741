"""The classic demosaic-only protocol for clisp's Bayer demosaics, beside colour-demosaicing's.

For every image of Kodak (24 PNG) and McMaster (18 TIFF): the sRGB-ENCODED 8-bit image, as float in
[0, 1] (no linearisation), is mosaicked as RGGB (no optics, no noise, no colour matrix) and
demosaicked by

    clisp bilinear / Malvar / DLMMSE / RI / ARI
                                       our OpenCL kernels, through a Pipeline holding only the
                                       demosaic stage (the pipeline pads the borders with the
                                       CFA-preserving mirror), whole image as one tile
    cd Malvar2004 / cd Menon2007       colour_demosaicing.demosaicing_CFA_Bayer_Malvar2004 /
                                       demosaicing_CFA_Bayer_Menon2007 on the same mosaic

and scored by CPSNR = 10 log10(1 / MSE), MSE over the 3 channels in [0, 1] scale with a 10 px
border excluded; outputs are clipped to [0, 1] first (clisp.metrics.psnr, tone_mapped=False).
Printed: the per-set mean of every method.

Speed: megapixels per second of each of our demosaics on the OpenCL device on a 6000 x 4000
mosaic, (a) kernels only (stage.enqueue on a padded window already on the device, best of
--repeat) and (b) end to end (Pipeline.run: host padding, upload, kernels, download), beside
rawpy's AHD (LibRaw) postprocessing a Bayer DNG of the same size simulated by clisp and written
with clisp.io.rawfile.write_raw (demosaic_algorithm=AHD, output_bps=16, no_auto_bright=True; only
postprocess is timed, best of --repeat).

    python tools/bayer_demosaic_protocol.py [--data ../shared/data] [--no-speed] [--per-image]

Tools-only dependency: colour-demosaicing (pip install colour-demosaicing).
"""
from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
from pathlib import Path
from typing import Callable

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path
from toolkit import BORDER, KODAK, MCMASTER, cpsnr, image_files, load_8bit

from clisp.cfa import bayer_cfa
from clisp.io.imageio import read_scene
from clisp.pipeline import Pipeline
from clisp.engine.runtime import get_runtime
from clisp.engine.stage import Stage
from clisp.modules.demosaic_ari.stage import DemosaicARI
from clisp.modules.demosaic_bilinear.stage import DemosaicBilinear
from clisp.modules.demosaic_dlmmse.stage import DemosaicDLMMSE
from clisp.modules.demosaic_malvar.stage import DemosaicMalvar
from clisp.modules.demosaic_ri.stage import DemosaicRI

CFA = bayer_cfa("RGGB")
SETS = {"Kodak": KODAK, "McMaster": MCMASTER}
SPEED_SHAPE = (4000, 6000)

OURS: dict[str, Stage] = {
    "clisp bilinear": DemosaicBilinear(CFA),
    "clisp Malvar": DemosaicMalvar(CFA),
    "clisp DLMMSE": DemosaicDLMMSE(CFA),
    "clisp DLMMSE (window mean)": DemosaicDLMMSE(CFA, local_mean="window"),
    "clisp RI": DemosaicRI(CFA),
    "clisp ARI": DemosaicARI(CFA),
}
SLOW = ("clisp ARI",)
"""Left out of the speed measurement (about a minute per 24 MP run; tools/bench_ari.py times it)."""


def colour_demosaicing_methods() -> dict[str, Callable[[np.ndarray], np.ndarray]]:
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # colour warns that matplotlib is missing
        import colour_demosaicing as cd
    return {
        "cd Malvar2004": lambda mosaic: cd.demosaicing_CFA_Bayer_Malvar2004(mosaic, "RGGB"),
        "cd Menon2007": lambda mosaic: cd.demosaicing_CFA_Bayer_Menon2007(mosaic, "RGGB"),
    }


def mosaic(image: np.ndarray) -> np.ndarray:
    """RGGB mosaic of an H x W x 3 image: the CFA channel's value at every pixel."""
    channel = CFA.channel_map(image.shape[0], image.shape[1])
    return np.take_along_axis(image, channel[..., None].astype(np.intp), axis=2)[..., 0]


def quality(data: Path, per_image: bool) -> dict[str, dict[str, list[float]]]:
    """CPSNR of every method on every image: {set: {method: [dB per image]}}."""
    methods: dict[str, Callable[[np.ndarray], np.ndarray]] = {
        name: (lambda m, st=stage: Pipeline(CFA, [st]).run(m.astype(np.float32)))
        for name, stage in OURS.items()}
    methods.update(colour_demosaicing_methods())
    scores: dict[str, dict[str, list[float]]] = {}
    for set_name, image_set in SETS.items():
        scores[set_name] = {name: [] for name in methods}
        for path in image_files(data, image_set, numeric=True):
            truth = load_8bit(path)
            m = mosaic(truth)
            row = []
            for name, method in methods.items():
                value = cpsnr(method(m), truth)
                scores[set_name][name].append(value)
                row.append(f"{value:6.2f}")
            if per_image:
                print(f"{set_name:9s} {path.name:12s} " + " ".join(row), flush=True)
    return scores


def print_quality(scores: dict[str, dict[str, list[float]]]) -> None:
    sets = list(scores)
    names = list(scores[sets[0]])
    print(f"\nCPSNR (dB), sRGB-encoded 8-bit images mosaicked RGGB, border {BORDER} px, per-set mean")
    print(f"{'method':28s}" + "".join(f"{s + f' ({len(scores[s][names[0]])})':>16s}" for s in sets))
    for name in names:
        print(f"{name:28s}" + "".join(f"{np.mean(scores[s][name]):16.2f}" for s in sets))


# ------------------------------------------------------------------------------------- speed

def bayer_raw(data: Path):
    """A 6000 x 4000 Bayer raw simulated by clisp (noisy, uint16) from a tiled Kodak image."""
    from clisp.sim.simulate import simulate
    scene = toolkit.repeat_to(read_scene(toolkit.kodak_path(data, 23)), *SPEED_SHAPE)
    return simulate(scene, cfa=CFA, gain=1.0, optics="none", seed=0).raw


def kernels_only(stage: Stage, window: np.ndarray) -> Callable[[], None]:
    """stage.enqueue on a padded window already on the device, until the queue is done."""
    rt = get_runtime()
    src = rt.upload(window)

    def once() -> None:
        dst = stage.enqueue(rt, src, (-stage.halo, -stage.halo))
        rt.queue.finish()
        rt.release(dst)
    return once


def rawpy_ahd(raw, folder: Path) -> Callable[[], object]:
    """rawpy (LibRaw) AHD postprocess of ``raw`` written as a DNG by clisp; only postprocess runs."""
    import rawpy

    from clisp.io.rawfile import write_raw
    path = folder / "bayer.dng"
    write_raw(path, raw)
    handle = rawpy.imread(str(path))
    options = dict(demosaic_algorithm=rawpy.DemosaicAlgorithm.AHD, output_bps=16, no_auto_bright=True)
    rgb = handle.postprocess(**options)
    if rgb.shape[:2] != SPEED_SHAPE:
        raise SystemExit(f"rawpy decoded {rgb.shape[:2]}, expected {SPEED_SHAPE}")
    return lambda: handle.postprocess(**options)


def machine() -> str:
    """CPU model, logical CPUs and the OpenCL device."""
    cpu = toolkit.cpu_model(lambda: platform.processor() or platform.machine())
    return f"{cpu}, {os.cpu_count()} logical CPUs; OpenCL: {get_runtime().describe()}"


def speed(data: Path, repeat: int, tile: int | None = None) -> None:
    megapixels = SPEED_SHAPE[0] * SPEED_SHAPE[1] / 1e6
    raw = bayer_raw(data)
    scale = raw.pass1_gains() / (raw.white_level - raw.black_level)
    channel = CFA.channel_map(*SPEED_SHAPE)
    m = ((raw.data - raw.black_level[channel]) * scale[channel]).astype(np.float32)
    stages = {name: stage for name, stage in OURS.items() if "window" not in name and name not in SLOW}
    with tempfile.TemporaryDirectory() as folder:
        runs: dict[str, Callable[[], object]] = {"ahd": rawpy_ahd(raw, Path(folder))}
        for name, stage in stages.items():
            runs[name + "/kernels"] = kernels_only(stage, np.pad(m, stage.halo, mode="reflect"))
            runs[name + "/pipeline"] = (lambda p=Pipeline(CFA, [stage]): p.run(m, tile=tile))
        best = toolkit.best_times(runs, repeat)  # interleaved: the ratios compare runs under the same load
    ahd = best["ahd"]
    print(f"\nSpeed on a {SPEED_SHAPE[1]} x {SPEED_SHAPE[0]} ({megapixels:.0f} MP) Bayer mosaic, "
          f"best of {repeat} interleaved rounds")
    print(f"machine: {machine()}")
    print(f"end to end: Pipeline.run, {'whole image as one tile' if not tile else f'tiles of {tile} px'}")
    print(f"{'method':28s}{'kernels MP/s':>14s}{'x AHD':>8s}{'end-to-end MP/s':>18s}{'x AHD':>8s}")
    for name in stages:
        kernels, end_to_end = best[name + "/kernels"], best[name + "/pipeline"]
        print(f"{name:28s}{megapixels / kernels:14.1f}{ahd / kernels:8.2f}"
              f"{megapixels / end_to_end:18.1f}{ahd / end_to_end:8.2f}")
    print(f"{'rawpy AHD (postprocess)':28s}{'':14s}{'':8s}{megapixels / ahd:18.1f}{1.0:8.2f}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    toolkit.add_data_option(parser)
    parser.add_argument("--per-image", action="store_true", help="also print every image's CPSNR")
    parser.add_argument("--no-quality", action="store_true", help="skip the CPSNR protocol")
    parser.add_argument("--no-speed", action="store_true", help="skip the speed measurement")
    toolkit.add_repeat_option(parser, 5, "timing rounds, best kept")
    parser.add_argument("--tile", type=int, default=None,
                        help="output tile side for the end-to-end timing (default: whole image)")
    args = parser.parse_args(argv)
    if not args.no_quality:
        print_quality(quality(args.data, args.per_image))
    if not args.no_speed:
        speed(args.data, args.repeat, args.tile)
    return 0


if __name__ == "__main__":
    sys.exit(main())
