"""The paper's Table 1 and Table 2 from clisp, beside the paper's numbers (PAPER_T1, PAPER_T2).

Pipelines (OpenCL): normalise, WB pass 1, demosaic, chroma denoise (clisp.modules.chroma_denoise.stage:
LMS in the paper's Y = (L+M)/2 / R-Y, G-Y, B-Y space, Bayer in BT.601 YUV, noise levels from the
simulation's noise model) -- or, "without denoise", the plain colour matrix. Simulation: docs/model.md
sections 2 and 3 (Airy optics r0 = 1 px, shot + read noise, 10-bit ADC, gains 4..64, or noiseless);
metrics: docs/model.md section 5.

Table 2  gray-panel SNR (dB) of the six ColorChecker neutrals on the demo chart
         (clisp.sim.charts.demo_chart: 64 px patches, central 32 x 32 ROI), LINEAR output, mean over
         R, G, B, mean over --seeds noise seeds; LMS - Bayer lead per panel and averaged.
Table 1  PSNR (dB), tone-mapped (clip, sRGB encode), 10 px border, mean over the images of
         Kodak (24 PNG) and McMaster (18 TIFF, the paper's "IMAX"), cropped to multiples of 4;
         noiseless and gains 4..64; with and without the denoiser; linear-domain PSNR as well.
         "noiseless, estimated": the denoiser driven by the blind noise estimate of the raw
         (clisp.scene.noise), as for camera raws without metadata: what it costs at no noise.
Speed    the chroma-denoise stage alone (kernels on a device-resident 24 MP image, best of
         --repeat) and the whole pipeline with and without it on a 24 MP simulated raw.
Crops    dead-leaves crops at gain 64 (Bayer / LMS, without / with denoise, and the truth),
         tone-mapped 16-bit PNG, into --crops.

Demosaics: --lms-demosaic and --bayer-demosaic take names of clisp.pipeline.DEMOSAICS (several,
comma-separated, for LMS); a name not registered there but known here ('hybrid', 'dlmmse') is
imported from its module with a note. Defaults: for LMS the first registered of 'guided',
'hybrid', 'bilinear'; 'dlmmse' for Bayer when available, else 'bilinear'. Stages are configured for the raw
by clisp.pipeline.make_demosaic when the pipeline has it (noise-aware demosaics get the raw's
noise), else noise-aware stages (a ``noise`` field) get the raw's noise here.

    python tools/paper_tables.py [--data ../shared/data] [--subset N] [--lms-demosaic bilinear,hybrid]
                                 [--seeds 4] [--crops DIR] [--no-table1] [--no-speed]
"""
from __future__ import annotations

import argparse
import dataclasses
import importlib
import resource
import sys
import time
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path
from toolkit import BORDER, KODAK, MCMASTER, load_scene

from clisp.app.batch import map_ordered, worker_cache
from clisp.cfa import CFA
from clisp.sim.charts import demo_chart
from clisp.io.imageio import write_image
from clisp.metrics import gray_panel_snr, psnr
from clisp.sim.noise import ChannelNoise
from clisp.scene.noise import raw_noise
import clisp.pipeline as pipeline_module
from clisp.pipeline import DEMOSAICS, Pipeline
from clisp.io.rawimage import RawImage
from clisp.engine.runtime import get_runtime
from clisp.sim.simulate import simulate
from clisp.engine.stage import Stage
from clisp.modules.chroma_denoise.stage import (ChromaDenoise, ChromaDenoiseParams, NoiseTable, calibrate_noise,
                                                space_for_cfa)
from clisp.modules.colour.stage import ColourMatrix
from clisp.modules.raw_scale.stage import normalize, white_balance1

GAINS = (4, 8, 16, 32, 64)
SETS = {"Kodak": KODAK, "McMaster": MCMASTER}
SPEED_SHAPE = (4000, 6000)

PAPER_T1 = {   # (Bayer, LMS) per noise level; None = no added noise. McMaster is the paper's "IMAX".
    "Kodak": {None: (42.79, 43.15), 4: (37.89, 38.83), 8: (36.57, 37.51), 16: (34.52, 35.78),
              32: (32.57, 33.99), 64: (31.07, 32.50)},
    "McMaster": {None: (37.26, 39.31), 4: (34.96, 36.15), 8: (34.11, 34.86), 16: (32.57, 33.39),
                 32: (31.09, 31.96), 64: (30.00, 30.87)},
}
PAPER_T2 = {   # (Bayer P1..P6, LMS P1..P6)
    4: ((17.08, 21.72, 24.83, 27.34, 29.30, 31.13), (21.50, 25.89, 28.67, 31.62, 33.81, 34.87)),
    8: ((13.90, 18.61, 21.82, 24.32, 26.36, 28.14), (18.44, 22.79, 25.84, 28.82, 30.99, 31.84)),
    16: ((11.81, 16.59, 19.82, 22.34, 24.34, 26.11), (15.98, 20.25, 23.31, 26.14, 28.28, 29.57)),
    32: ((8.59, 13.60, 16.91, 19.45, 21.46, 23.21), (13.07, 17.45, 20.51, 23.34, 25.44, 26.79)),
    64: ((1.47, 7.58, 11.41, 14.02, 16.07, 17.76), (7.04, 12.30, 15.46, 18.33, 20.43, 21.64)),
}
LMS_PREFERENCE = ("guided", "hybrid", "bilinear")
"""Default LMS demosaic: the first of these registered in DEMOSAICS."""
KNOWN = {"hybrid": ("clisp.modules.demosaic_lms.stage", "DemosaicLMSHybrid"),
         "dlmmse": ("clisp.modules.demosaic_dlmmse.stage", "DemosaicDLMMSE")}
"""Demosaics being written beside this tool: used from their modules until registered."""


# ------------------------------------------------------------------------------------------
# pipelines
# ------------------------------------------------------------------------------------------

def demosaic_factory(name: str) -> Callable[[CFA], Stage] | None:
    """DEMOSAICS[name], else the known module's class (with a note), else None."""
    if name in DEMOSAICS:
        return DEMOSAICS[name]
    if name in KNOWN:
        module, cls = KNOWN[name]
        try:
            factory = getattr(importlib.import_module(module), cls)
        except (ImportError, AttributeError):
            return None
        print(f"note: demosaic {name!r} is not registered in clisp.pipeline.DEMOSAICS; using {module}.{cls}")
        return factory
    return None


def make_demosaic(name: str, raw: RawImage, noise: ChannelNoise) -> Stage:
    """The demosaic stage for ``raw``: the pipeline's own ``make_demosaic`` when it has one and
    ``name`` is registered (stages configure themselves from the raw); otherwise the factory, and
    noise-aware stages (a dataclass field ``noise``) get ``noise``."""
    official = getattr(pipeline_module, "make_demosaic", None)
    if official is not None and name in DEMOSAICS:
        return official(name, raw)
    factory = demosaic_factory(name)
    if factory is None:
        raise SystemExit(f"unknown demosaic {name!r}; registered: {', '.join(DEMOSAICS)}")
    stage = factory(raw.cfa)
    if dataclasses.is_dataclass(stage) and "noise" in {f.name for f in dataclasses.fields(stage)} \
            and not noise.is_zero:
        stage = dataclasses.replace(stage, noise=noise)
    return stage


class Runner:
    """Builds and runs pipelines; caches noise tables per (demosaic, CFA, gain)."""

    def __init__(self, params: ChromaDenoiseParams, tile: int | None) -> None:
        self.params = params
        self.tile = tile
        self.tables: dict[tuple, NoiseTable] = {}

    def pipeline(self, raw: RawImage, name: str, denoise: bool, noise: ChannelNoise | None = None) -> Pipeline:
        cfa = raw.cfa
        noise = raw_noise(raw) if noise is None else noise
        demosaic = make_demosaic(name, raw, noise)
        stages = [normalize(cfa, raw.black_level, raw.white_level), white_balance1(cfa, raw.pass1_gains()),
                  demosaic]
        if denoise and not noise.is_zero:
            space = space_for_cfa(cfa, raw.colour_matrix, self.params.luma, raw.pass1_gains(),
                                  self.params.strengths)
            key = (name, cfa.name, raw.metadata.get("gain"), noise)
            if key not in self.tables:
                self.tables[key] = calibrate_noise(demosaic, cfa, space, noise, self.params.levels)
            stages.append(ChromaDenoise(space, self.tables[key], self.params))
        else:
            stages.append(ColourMatrix(raw.colour_matrix))
        return Pipeline(cfa, stages)

    def run(self, raw: RawImage, name: str, denoise: bool, noise: ChannelNoise | None = None) -> np.ndarray:
        return self.pipeline(raw, name, denoise, noise).run(raw.data, tile=self.tile)

    def __reduce__(self) -> tuple:
        """Shipped to a Dask worker (``--scheduler``), a Runner becomes that worker process's own
        Runner with the same settings, so its noise tables are calibrated once per worker."""
        return shared_runner, (self.params, self.tile)


def shared_runner(params: ChromaDenoiseParams, tile: int | None) -> Runner:
    """This process's Runner for (params, tile) (clisp.app.batch.worker_cache)."""
    return worker_cache(("paper_tables.Runner", params, tile), lambda: Runner(params, tile))


def bayer_list(bayer_names: str | Sequence[str]) -> list[str]:
    """One Bayer demosaic name or several as a list; the first is the one set against the paper's
    Bayer (its figures and leads go beside PAPER_T1 / PAPER_T2), the others are extra columns."""
    return [bayer_names] if isinstance(bayer_names, str) else list(bayer_names)


Mapper = Callable[..., list]
"""``mapper(fn, items, *args, progress=label, timeout=s) -> [fn(item, *args) for item in items]``, in order:
clisp.app.batch.map_ordered bound to a Dask client (a sweep on a cluster) or to None (this process)."""


def serial(fn: Callable, items: list, *args, progress: str | None = None, timeout: float | None = None) -> list:
    """The default Mapper: this process, one item after another (``timeout`` is not used)."""
    return map_ordered(None, fn, items, *args, progress=progress)


def chart() -> object:
    """The demo chart, built once per process."""
    return worker_cache("demo_chart", demo_chart)


# ------------------------------------------------------------------------------------------
# Table 2
# ------------------------------------------------------------------------------------------

def table2_item(item: tuple, runner: Runner) -> dict[bool, np.ndarray]:
    """One (gain, kind, demosaic, seed) of Table 2: {denoise: gray-panel SNRs}."""
    gain, kind, name, seed = item
    demo = chart()
    raw = simulate(demo.image, kind, gain=gain, seed=seed).raw
    return {denoise: gray_panel_snr(runner.run(raw, name, denoise), demo.gray_rois) for denoise in (True, False)}


def table2(runner: Runner, lms_names: list[str], bayer_name: str | Sequence[str], seeds: int,
           mapper: Mapper = serial) -> dict:
    """{(gain, kind, demosaic): {denoise: mean gray-panel SNRs}}; ``bayer_name``: one Bayer
    demosaic or several (bayer_list), each one more set of items."""
    bayer_names = bayer_list(bayer_name)
    items = [(gain, kind, name, seed) for gain in GAINS
             for kind, names in (("bayer", bayer_names), ("lms", lms_names)) for name in names
             for seed in range(seeds)]
    snrs = iter(mapper(table2_item, items, runner, progress="Table 2"))
    results: dict = {}
    for gain in GAINS:
        for kind, names in (("bayer", bayer_names), ("lms", lms_names)):
            for name in names:
                snr = {True: [], False: []}
                for seed in range(seeds):
                    one = next(snrs)
                    for denoise in (True, False):
                        snr[denoise].append(one[denoise])
                results[(gain, kind, name)] = {d: np.mean(v, axis=0) for d, v in snr.items()}
    print(f"\nTable 2: gray-panel SNR (dB), linear output, mean of R, G, B; demo chart, {seeds} seed(s); "
          "'ours' with chroma denoise; paper in brackets")
    for name, bayer_name in ((n, b) for n in lms_names for b in bayer_names):
        print(f"\n  LMS demosaic {name!r}, Bayer demosaic {bayer_name!r}")
        print("  gain  " + "".join(f"{'P' + str(k + 1) + ' Bayer/LMS':>22}" for k in range(6))
              + f"{'mean lead':>16}{'darkest lead':>16}")
        for gain in GAINS:
            b, lm = results[(gain, "bayer", bayer_name)][True], results[(gain, "lms", name)][True]
            pb, pl = PAPER_T2[gain]
            cells = "".join(f"{b[k]:6.2f}/{lm[k]:5.2f} ({pb[k]:5.2f}/{pl[k]:5.2f})" for k in range(6))
            lead, plead = lm - b, np.subtract(pl, pb)
            print(f"  {gain:>3}x  {cells}  {lead.mean():+5.2f} ({plead.mean():+.2f})  {lead[0]:+5.2f} ({plead[0]:+.2f})")
        print("  without denoise (colour matrix only), Bayer/LMS:")
        for gain in GAINS:
            b, lm = results[(gain, "bayer", bayer_name)][False], results[(gain, "lms", name)][False]
            print(f"  {gain:>3}x  " + "  ".join(f"{b[k]:6.2f}/{lm[k]:5.2f}" for k in range(6))
                  + f"   mean lead {np.mean(lm - b):+5.2f}")
    return results


# ------------------------------------------------------------------------------------------
# Table 1
# ------------------------------------------------------------------------------------------

def table1_item(item: tuple, runner: Runner) -> list[tuple[tuple, tuple[float, float]]]:
    """One (image path, noise level, columns) of Table 1: [((gain, kind, name, run), (PSNR
    tone-mapped, PSNR linear))] in the order of the serial loop."""
    path, gain, columns = item
    scene = load_scene(path)
    out = []
    for kind, name in columns:
        sim = simulate(scene, kind, gain=gain, seed=0)
        runs = {"with": runner.run(sim.raw, name, True), "without": runner.run(sim.raw, name, False)}
        if gain is None:
            est = raw_noise(sim.raw, estimate=True)
            runs["estimated"] = runner.run(sim.raw, name, True, noise=est)
        for key, image in runs.items():
            out.append(((gain, kind, name, key), (psnr(image, sim.truth, border=BORDER),
                                                   psnr(image, sim.truth, border=BORDER, tone_mapped=False))))
    return out


def table1(runner: Runner, data: Path, subset: int | None, lms_names: list[str], bayer_name: str | Sequence[str],
           mapper: Mapper = serial) -> dict:
    """{(set, gain, kind, demosaic, run): mean (PSNR tone-mapped, PSNR linear)}; ``bayer_name``:
    one Bayer demosaic or several (bayer_list), each one more column of every item."""
    bayer_names = bayer_list(bayer_name)
    levels = [None] + list(GAINS)
    columns = [("bayer", b) for b in bayer_names] + [("lms", n) for n in lms_names]
    results: dict = {}
    for set_name, image_set in SETS.items():
        paths = toolkit.image_files(data, image_set, subset)     # the first ``subset`` by file name
        t0 = time.perf_counter()
        items = [(path, gain, columns) for path in paths for gain in levels]
        for scores in mapper(table1_item, items, runner, progress=f"Table 1 {set_name}"):
            for (gain, kind, name, key), value in scores:
                results.setdefault((set_name, gain, kind, name, key), []).append(value)
        print(f"\n[{set_name}: {len(paths)} images in {time.perf_counter() - t0:.0f} s]")
    mean = {k: np.mean(v, axis=0) for k, v in results.items()}
    for set_name in SETS:
        n = len(results[(set_name, None, "bayer", bayer_names[0], "with")])
        print(f"\nTable 1: PSNR (dB), tone-mapped, {BORDER} px border, {set_name} ({n} images); "
              "Bayer/LMS with chroma denoise; paper in brackets")
        for name, bayer_name in ((n, b) for n in lms_names for b in bayer_names):
            print(f"  LMS {name!r} vs Bayer {bayer_name!r}")
            print(f"  {'noise':>10}  {'ours Bayer/LMS':>16}  {'LMS-Bayer':>9}  {'paper':>13}  {'paper LMS-Bayer':>15}"
                  f"  {'linear Bayer/LMS':>16}")
            for gain in levels:
                b = mean[(set_name, gain, "bayer", bayer_name, "with")]
                lm = mean[(set_name, gain, "lms", name, "with")]
                pb, pl = PAPER_T1[set_name][gain]
                label = "noiseless" if gain is None else f"{gain}x"
                print(f"  {label:>10}  {b[0]:7.2f}/{lm[0]:7.2f}  {lm[0] - b[0]:+9.2f}  {pb:6.2f}/{pl:6.2f}"
                      f"  {pl - pb:+15.2f}  {b[1]:7.2f}/{lm[1]:7.2f}")
        print("  denoiser effect, PSNR with - without (tone-mapped dB); 'with/without' values:")
        for kind, name in columns:
            cells = []
            for gain in levels:
                w = mean[(set_name, gain, kind, name, "with")][0]
                wo = mean[(set_name, gain, kind, name, "without")][0]
                cells.append(f"{'0' if gain is None else gain:>2}: {w - wo:+.3f} ({w:.2f}/{wo:.2f})")
            est = mean[(set_name, None, kind, name, "estimated")][0] - mean[(set_name, None, kind, name, "without")][0]
            print(f"    {kind:5} {name:9} " + "  ".join(cells) + f"  | noiseless, estimated noise: {est:+.3f}")
    return mean


# ------------------------------------------------------------------------------------------
# speed and crops
# ------------------------------------------------------------------------------------------

def cpu_seconds() -> float:
    """User + system CPU time of this process (all threads) in seconds."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def speed(runner: Runner, lms_names: list[str], bayer_name: str, repeat: int) -> None:
    rt = get_runtime()
    h, w = SPEED_SHAPE
    print(f"\nSpeed on {rt.describe()}, {h * w / 1e6:.0f} MP (best of {repeat}):")
    rng = np.random.default_rng(0)
    scene = np.clip(0.3 + 0.1 * rng.standard_normal((h // 8, w // 8, 3)), 0, 1).repeat(8, 0).repeat(8, 1)
    for kind, names in (("lms", lms_names), ("bayer", [bayer_name])):
        raw = simulate(scene, kind, gain=16, optics="none", seed=0).raw
        for name in names:
            pipe = runner.pipeline(raw, name, True)
            stage = pipe.stages[-1]
            pad = stage.halo
            src = rt.upload(np.full((3, h + 2 * pad, w + 2 * pad), 0.3, np.float32)
                            + rng.standard_normal((3, h + 2 * pad, w + 2 * pad)).astype(np.float32) * 0.03)
            best, best_cpu = np.inf, np.inf
            for _ in range(repeat + 1):                           # first run builds the kernels
                t, c = time.perf_counter(), cpu_seconds()
                out = stage.enqueue(rt, src, (-pad, -pad))
                rt.queue.finish()
                best, best_cpu = min(best, time.perf_counter() - t), min(best_cpu, cpu_seconds() - c)
                rt.release(out)
            rt.release(src)
            times = {}
            for denoise in (True, False):
                p = runner.pipeline(raw, name, denoise)
                p.run(raw.data, tile=runner.tile)                 # warm-up
                wall, cpu = [], []
                for _ in range(repeat):
                    c = cpu_seconds()
                    p.run(raw.data, tile=runner.tile)
                    wall.append(p.stats.seconds)
                    cpu.append(cpu_seconds() - c)
                times[denoise] = (min(wall), min(cpu))
            mp = h * w / 1e6
            print(f"  {kind:5} {name:9} chroma denoise stage {mp / best:5.2f} MP/s ({best:.2f} s wall,"
                  f" {best_cpu:.2f} CPU-s); whole pipeline with it {mp / times[True][0]:5.2f} MP/s"
                  f" ({times[True][0]:.2f} s, {times[True][1]:.2f} CPU-s), without {mp / times[False][0]:5.2f} MP/s"
                  f" ({times[False][0]:.2f} s, {times[False][1]:.2f} CPU-s)")
    print("  (CPU-s: process user + system time, PoCL's worker threads included; wall time depends on"
          " what else runs on the machine)")


def crops(runner: Runner, folder: Path, lms_names: list[str], bayer_name: str) -> None:
    chart = demo_chart()
    y0, y1, x0, x1 = chart.regions["dead_leaves"]
    folder.mkdir(parents=True, exist_ok=True)
    truth = None
    for kind, name in [("bayer", bayer_name)] + [("lms", n) for n in lms_names]:
        sim = simulate(chart.image, kind, gain=64, seed=0)
        truth = sim.truth
        for denoise in (False, True):
            out = runner.run(sim.raw, name, denoise)[y0:y1, x0:x1]
            path = folder / f"dead_leaves_g64_{kind}_{name}_{'denoised' if denoise else 'raw_chroma'}.png"
            write_image(path, out, encoded=False)
            print(f"  wrote {path}  (PSNR {psnr(out, truth[y0:y1, x0:x1], border=0):.2f} dB)")
    write_image(folder / "dead_leaves_truth.png", truth[y0:y1, x0:x1], encoded=False)


# ------------------------------------------------------------------------------------------

def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    toolkit.add_data_option(ap)
    ap.add_argument("--subset", type=int, default=None, help="only the first N images of each set")
    default_lms = next(n for n in LMS_PREFERENCE if n in DEMOSAICS)
    ap.add_argument("--lms-demosaic", default=default_lms, help=f"comma-separated (default {default_lms})")
    ap.add_argument("--bayer-demosaic", default=None, help="default dlmmse when available, else bilinear")
    ap.add_argument("--seeds", type=int, default=4, help="noise seeds averaged in Table 2 (default 4)")
    ap.add_argument("--tile", type=int, default=None, help="tile side; 0 = whole image (default: the planner's tiles)")
    ap.add_argument("--crops", type=Path, default=None, help="folder for the gain-64 dead-leaves crops")
    toolkit.add_repeat_option(ap, 3, "timing repeats, best kept")
    ap.add_argument("--no-table1", action="store_true")
    ap.add_argument("--no-table2", action="store_true")
    ap.add_argument("--no-speed", action="store_true")
    args = ap.parse_args(argv)
    lms_names = [n.strip() for n in args.lms_demosaic.split(",") if n.strip()]
    bayer_name = args.bayer_demosaic or ("dlmmse" if demosaic_factory("dlmmse") is not None else "bilinear")
    runner = Runner(ChromaDenoiseParams(), args.tile)
    print(f"clisp paper tables: LMS demosaic(s) {lms_names}, Bayer demosaic {bayer_name!r}, "
          f"chroma denoise {ChromaDenoiseParams()}")
    if not args.no_table2:
        table2(runner, lms_names, bayer_name, args.seeds)
    if not args.no_table1:
        table1(runner, args.data, args.subset, lms_names, bayer_name)
    if args.crops is not None:
        print("\nDead-leaves crops, gain 64:")
        crops(runner, args.crops, lms_names, bayer_name)
    if not args.no_speed:
        speed(runner, lms_names, bayer_name, args.repeat)
    return 0


if __name__ == "__main__":
    sys.exit(main())
