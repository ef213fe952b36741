"""Demosaic quality inside the full pipeline: clisp's Bayer and LMS defaults against LibRaw's
demosaics, on Kodak, McMaster and dead leaves, noiseless and noisy (issue 12, item 3).

For every scene and setting a Bayer raw and an LMS raw are simulated once (clisp.sim.simulate, seed 0)
and every method of that CFA processes the same raw. Settings: ``noiseless`` (Airy optics),
``noiseless-sharp`` (no optics), and gains ``4``, ``16``, ``64`` (Airy optics, shot + read noise; also
``1`` and ``8`` on request).

Bayer methods share everything but the demosaic. The stages of ``clisp process``'s default
pipeline for the Bayer raw (clisp.pipeline.build_pipeline, linear output) are split at the
demosaic: before it, black/white normalisation and WB pass 1; after it, the chroma denoiser with
the noise table of the default demosaic (or the plain colour matrix where the raw is noiseless).
Each Bayer demosaic turns the same raw into white-balanced camera RGB, and the same after-stages
(OpenCL, whole image, mirror-padded) finish it:

  clisp <name>      our demosaic stage (clisp.pipeline.DEMOSAICS) on the normalised mosaic
  numpy <func>      a NumPy candidate ``func(mosaic, pattern) -> H x W x 3`` (--numpy MODULE:FUNC)
                    on the normalised, white-balanced mosaic (float64), pattern e.g. 'RGGB'
  LibRaw <ALGO>     rawpy postprocess (AHD, DHT, AAHD, VNG, DCB, ...) of the raw written as a
                    DNG by clisp.io.rawfile.write_raw (noiseless raws: DN x 64 rounded to 16 bits),
                    output_color raw, linear, user_wb = our pass-1 gains; its level is calibrated
                    per channel to our normalised mosaic (means at the channel's own sites)

The LMS method is ``clisp process``'s default pipeline for the LMS raw, unchanged. LMS NumPy
candidates (--lms-numpy MODULE:FUNC, ``func(mosaic, cfa) -> H x W x 3``, cfa a clisp.cfa.CFA) get the
normalised, white-balanced LMS mosaic (float64) and replace the demosaic stage of that same pipeline:
its after-stages (colour matrix, or the chroma denoiser with the default LMS demosaic's noise table)
finish their white-balanced L, M, S on the device as for the Bayer candidates. Scores: PSNR
(dB) tone-mapped (clip, sRGB encode), 10 px border, against the simulation's truth (the scene
through the same optics). Printed per set and setting: the mean of every method, ``LibRaw best``
(the best LibRaw demosaic per image, then the mean) and ``Bayer best`` (the best of all Bayer
methods per image), and the leads the issue asks for: Bayer default - LibRaw best, LMS default -
Bayer best.

    python tools/bench_demosaic_quality.py [--data ../shared/data] [--sets kodak,mcmaster,deadleaves]
        [--subset N] [--settings noiseless,noiseless-sharp,4,16,64] [--bayer dlmmse]
        [--libraw AHD,DHT,AAHD,VNG,DCB] [--numpy MODULE:FUNC,...] [--lms-numpy MODULE:FUNC,...]
        [--csv FILE] [--per-image]

Dead leaves: clisp.sim.charts.dead_leaves (512 x 512, seeds 0..--dead-leaves - 1), generated here.
Set ``zoneplate``: clisp.sim.charts.zone_plate(256) (the neutral sRGB-cosine plate), one image.
Tools-only dependency: rawpy.
"""
from __future__ import annotations

import argparse
import importlib
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

import toolkit  # before clisp: puts this checkout (clisp, research/: the demosaic studies) on sys.path
from toolkit import BORDER, Scene

from bench import bayer_pattern, libraw_level, libraw_options, normalised_mosaic
from clisp.cfa import CFA
from clisp.sim.charts import dead_leaves
from clisp.metrics import psnr
from clisp.pipeline import DEMOSAICS, Pipeline, build_pipeline, make_demosaic
from clisp.io.rawimage import RawImage
from clisp.engine.runtime import get_runtime
from clisp.sim.simulate import simulate
from clisp.engine.stage import Stage

SETTINGS = {"noiseless": (None, "airy"), "noiseless-sharp": (None, "none"), "1": (1.0, "airy"),
            "4": (4.0, "airy"), "8": (8.0, "airy"), "16": (16.0, "airy"), "64": (64.0, "airy")}
DEFAULT_SETTINGS = ("noiseless", "noiseless-sharp", "4", "16", "64")
LIBRAW_ALGOS = ("AHD", "DHT", "AAHD", "VNG", "DCB")
NOISELESS_SCALE = 64.0
"""Noiseless raws are float DN; LibRaw reads integers, so its DNG holds DN x 64 (10-bit data in 16
bits: quantisation 1/64 DN, far below any demosaic's error)."""


# ------------------------------------------------------------------------------------- scenes

def load_scenes(data: Path, sets: list[str], subset: int | None, n_dead: int,
                dead_size: int) -> dict[str, list[Scene]]:
    """{set: [(name, H x W x 3 linear sRGB scene)]}: files of Kodak/McMaster (the first ``subset``,
    cropped to multiples of 4), generated dead leaves and zone plate."""
    loaders = {"kodak": lambda: toolkit.kodak(data, subset), "mcmaster": lambda: toolkit.mcmaster(data, subset),
               "deadleaves": lambda: toolkit.dead_leaves_charts(n_dead, dead_size), "zoneplate": toolkit.zone_plates}
    for name in sets:
        if name not in loaders:
            raise SystemExit(f"unknown set {name!r}; choose from {', '.join(loaders)}")
    return {name: loaders[name]() for name in sets}


# ------------------------------------------------------------------------------------- methods

def split_at_demosaic(pipeline: Pipeline) -> tuple[list[Stage], Stage, list[Stage]]:
    """(stages before the demosaic, the demosaic, stages after it) of a default pipeline."""
    names = [s.name for s in pipeline.stages]
    index = next(i for i, n in enumerate(names) if n.startswith("demosaic"))
    return pipeline.stages[:index], pipeline.stages[index], pipeline.stages[index + 1:]


def run_on_rgb(stages: list[Stage], rgb: np.ndarray) -> np.ndarray:
    """``stages`` (RGB in, RGB out) on the OpenCL device over a whole H x W x 3 image, padded by
    the stages' halo (rounded up to their alignment) with a mirror; H x W x 3 float32 out."""
    if not stages:
        return rgb.astype(np.float32)
    rt = get_runtime()
    halo = sum(s.halo for s in stages)
    align = max(s.align for s in stages)
    pad = -(-halo // align) * align
    padded = np.pad(rgb.astype(np.float32), ((pad, pad), (pad, pad), (0, 0)), mode="reflect")
    src = rt.upload(np.ascontiguousarray(np.moveaxis(padded, -1, 0)))
    origin = (-pad, -pad)
    for stage in stages:
        dst = stage.enqueue(rt, src, origin)
        rt.release(src)
        src, origin = dst, (origin[0] + stage.halo, origin[1] + stage.halo)
    out = rt.download(src)
    rt.release(src)
    out = out if src.interleaved else np.moveaxis(out, 0, -1)
    off = pad - halo
    h, w = rgb.shape[:2]
    return np.ascontiguousarray(out[off:off + h, off:off + w])


def clisp_camera_rgb(raw: RawImage, before: list[Stage], demosaic: Stage) -> np.ndarray:
    """White-balanced camera RGB (H x W x 3) of our demosaic, through a Pipeline (mirror borders)."""
    return Pipeline(raw.cfa, before + [demosaic]).run(raw.data)


def libraw_camera_rgb(raw: RawImage, algo: str, folder: Path) -> np.ndarray:
    """White-balanced camera RGB (H x W x 3) of LibRaw's ``algo``, at our normalisation."""
    import rawpy
    from dataclasses import replace

    from clisp.io.rawfile import write_raw
    if raw.data.dtype != np.uint16:                       # noiseless: float DN -> 16-bit integers
        data = np.clip(np.round(raw.data.astype(np.float64) * NOISELESS_SCALE), 0, 65535).astype(np.uint16)
        raw = replace(raw, data=data, black_level=raw.black_level * NOISELESS_SCALE,
                      white_level=min(65535.0, raw.white_level * NOISELESS_SCALE))
    path = folder / "libraw.dng"
    write_raw(path, raw)
    with rawpy.imread(str(path)) as handle:
        rgb = handle.postprocess(**libraw_options(raw, algo)).astype(np.float64)
    if rgb.shape[:2] != raw.shape:
        raise SystemExit(f"LibRaw {algo}: output {rgb.shape[:2]} is not the raw's {raw.shape}")
    return (rgb * libraw_level(raw, rgb)).astype(np.float32)


def numpy_function(spec: str) -> Callable[..., np.ndarray]:
    """The function named by 'module:function'."""
    module, _, name = spec.partition(":")
    try:
        return getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError) as exc:
        raise SystemExit(f"{spec}: {exc}") from None


def lms_default_reference(mosaic: np.ndarray, cfa: CFA) -> np.ndarray:
    """The default LMS demosaic's NumPy reference (noiseless, neutral of P_LMS) as an --lms-numpy
    candidate: it must score as "LMS clisp default" (the check of the --lms-numpy hook)."""
    from research.demosaic.lms_ri import guided_reference
    return guided_reference(mosaic, cfa)


@dataclass
class Scores:
    """PSNR per (set, setting, method): a list over the set's images, in order."""

    values: dict[tuple[str, str, str], list[float]]

    def add(self, set_name: str, setting: str, method: str, value: float) -> None:
        self.values.setdefault((set_name, setting, method), []).append(value)

    def methods(self, set_name: str, setting: str) -> list[str]:
        return [m for (s, g, m) in self.values if s == set_name and g == setting]

    def per_image_best(self, set_name: str, setting: str, prefix: str) -> np.ndarray:
        rows = [self.values[(set_name, setting, m)] for m in self.methods(set_name, setting) if m.startswith(prefix)]
        return np.max(np.array(rows), axis=0)


def score_scene(scores: Scores, set_name: str, setting: str, scene: np.ndarray, bayer: list[str],
                libraw: list[str], numpy_fns: list[str], folder: Path, per_image: str | None,
                lms_fns: list[str] = ()) -> None:
    gain, optics = SETTINGS[setting]
    cells = []

    def record(method: str, out: np.ndarray, truth: np.ndarray) -> None:
        value = psnr(out, truth, border=BORDER)
        scores.add(set_name, setting, method, value)
        cells.append(f"{method} {value:.2f}")

    sim = simulate(scene, "bayer", gain=gain, optics=optics, seed=0)
    # bad_pixels off: the simulated raws have no defects and LibRaw's path has no search, so the
    # demosaics are compared on the same mosaic
    default = build_pipeline(sim.raw, output="linear", bad_pixels="off")
    before, default_demosaic, after = split_at_demosaic(default)
    for name in bayer:
        stage = default_demosaic if name == default_demosaic.name.removeprefix("demosaic_") \
            else make_demosaic(name, sim.raw)
        record(f"Bayer clisp {name}", run_on_rgb(after, clisp_camera_rgb(sim.raw, before, stage)), sim.truth)
    for spec in numpy_fns:
        rgb = numpy_function(spec)(normalised_mosaic(sim.raw), bayer_pattern(sim.raw))
        record(f"Bayer numpy {spec.partition(':')[2]}", run_on_rgb(after, rgb), sim.truth)
    for algo in libraw:
        record(f"Bayer LibRaw {algo}", run_on_rgb(after, libraw_camera_rgb(sim.raw, algo, folder)), sim.truth)
    lms = simulate(scene, "lms", gain=gain, optics=optics, seed=0)
    lms_pipeline = build_pipeline(lms.raw, output="linear", bad_pixels="off")
    record("LMS clisp default", lms_pipeline.run(lms.raw.data), lms.truth)
    if lms_fns:
        lms_after = split_at_demosaic(lms_pipeline)[2]
        lms_mosaic = normalised_mosaic(lms.raw)
        for spec in lms_fns:
            rgb = numpy_function(spec)(lms_mosaic, lms.raw.cfa)
            record(f"LMS numpy {spec.partition(':')[2]}", run_on_rgb(lms_after, rgb), lms.truth)
    if per_image:
        print(f"  {set_name:9s} {setting:15s} {per_image:18s} " + "  ".join(cells), flush=True)


def report(scores: Scores, sets: list[str], settings: list[str], bayer_default: str) -> list[dict[str, object]]:
    """Print the tables; return CSV rows."""
    rows: list[dict[str, object]] = []
    for set_name in sets:
        for setting in settings:
            methods = scores.methods(set_name, setting)
            if not methods:
                continue
            n = len(scores.values[(set_name, setting, methods[0])])
            print(f"\n{set_name} ({n} images), {setting}: PSNR (dB), tone-mapped, {BORDER} px border")
            means = {m: float(np.mean(scores.values[(set_name, setting, m)])) for m in methods}
            extra = {}
            if any(m.startswith("Bayer LibRaw") for m in methods):
                extra["LibRaw best (per image)"] = float(np.mean(scores.per_image_best(set_name, setting, "Bayer LibRaw")))
            extra["Bayer best (per image)"] = float(np.mean(scores.per_image_best(set_name, setting, "Bayer")))
            for method, value in {**means, **extra}.items():
                print(f"  {method:30s} {value:7.2f}")
                rows.append({"set": set_name, "setting": setting, "method": method, "images": n,
                             "psnr_db": round(value, 3)})
            default = means[f"Bayer clisp {bayer_default}"]
            if "LibRaw best (per image)" in extra:
                print(f"  lead: Bayer default - LibRaw best {default - extra['LibRaw best (per image)']:+.2f} dB")
            for method in (m for m in methods if m.startswith("LMS")):
                label = "LMS default" if method == "LMS clisp default" else method
                print(f"  lead: {label} - Bayer best {means[method] - extra['Bayer best (per image)']:+.2f} dB")
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    toolkit.add_data_option(parser)
    parser.add_argument("--sets", default="kodak,mcmaster,deadleaves", help="kodak, mcmaster, deadleaves")
    parser.add_argument("--subset", type=int, default=None, help="first N images of each file set")
    parser.add_argument("--dead-leaves", type=int, default=8, help="dead-leaves charts (default 8)")
    parser.add_argument("--dead-size", type=int, default=512, help="dead-leaves side in px (default 512)")
    parser.add_argument("--settings", default=",".join(DEFAULT_SETTINGS),
                        help=f"of {', '.join(SETTINGS)} (default {','.join(DEFAULT_SETTINGS)})")
    parser.add_argument("--bayer", default=None,
                        help="our Bayer demosaics (default: the default pipeline's, then any others given)")
    parser.add_argument("--libraw", default=",".join(LIBRAW_ALGOS), help="LibRaw demosaics ('' for none)")
    parser.add_argument("--numpy", default="", help="NumPy candidates MODULE:FUNC, comma-separated")
    parser.add_argument("--lms-numpy", default="",
                        help="NumPy LMS demosaics MODULE:FUNC (func(mosaic, cfa) -> H x W x 3), comma-separated")
    parser.add_argument("--csv", type=Path, default=None, help="write one row per set, setting and method")
    parser.add_argument("--per-image", action="store_true", help="print every image's scores")
    args = parser.parse_args(argv)
    sets = [s for s in args.sets.split(",") if s]
    settings = [s for s in args.settings.split(",") if s]
    for setting in settings:
        if setting not in SETTINGS:
            raise SystemExit(f"unknown setting {setting!r}; choose from {', '.join(SETTINGS)}")
    libraw = [a for a in args.libraw.split(",") if a]
    if libraw:
        try:
            import rawpy
        except ImportError:
            print("rawpy is not installed: LibRaw's demosaics are absent from this run", file=sys.stderr)
            libraw = []
        else:
            unknown = [a for a in libraw if not hasattr(rawpy.DemosaicAlgorithm, a)]
            if unknown:
                raise SystemExit(f"unknown LibRaw demosaic(s) {unknown}")
    probe = build_pipeline(simulate(dead_leaves(64), "bayer", gain=None).raw)
    bayer_default = split_at_demosaic(probe)[1].name.removeprefix("demosaic_")
    bayer = [bayer_default] + [b for b in (args.bayer or "").split(",") if b and b != bayer_default]
    for name in bayer:
        if name not in DEMOSAICS:
            raise SystemExit(f"unknown demosaic {name!r}; registered: {', '.join(DEMOSAICS)}")
    numpy_fns = [f for f in args.numpy.split(",") if f]
    lms_fns = [f for f in args.lms_numpy.split(",") if f]
    for spec in numpy_fns + lms_fns:
        numpy_function(spec)
    scenes = load_scenes(args.data, sets, args.subset, args.dead_leaves, args.dead_size)
    print(f"device: {get_runtime().describe()}; Bayer default demosaic: {bayer_default}; "
          f"LibRaw: {', '.join(libraw) or 'none'}")
    scores = Scores({})
    with tempfile.TemporaryDirectory(prefix="clisp-dq-") as tmp:
        for set_name, items in scenes.items():
            start = time.perf_counter()
            for image_name, scene in items:
                for setting in settings:
                    score_scene(scores, set_name, setting, scene, bayer, libraw, numpy_fns, Path(tmp),
                                image_name if args.per_image else None, lms_fns)
            print(f"[{set_name}: {len(items)} scenes x {len(settings)} settings in "
                  f"{time.perf_counter() - start:.0f} s]", flush=True)
    rows = report(scores, list(scenes), settings, bayer_default)
    if args.csv:
        toolkit.write_csv(rows, args.csv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
