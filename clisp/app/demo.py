"""``clisp demo``: the whole product on a chart built in code, no data files needed.

Builds the demo chart (ColorChecker with its six gray panels, zone plate, Siemens star, dead
leaves), simulates LMS and Bayer raws at analog gains 1, 8 and 64, writes each as a DNG-style raw,
reads it back, processes it on OpenCL, writes the images and prints PSNR, gray-panel SNR and
throughput.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..sim.charts import demo_chart
from ..io.imageio import write_image
from ..metrics import gray_panel_snr, psnr
from ..pipeline import DEFAULT_PRESET, process_with_stats, resolve_options
from ..io.rawfile import read_raw, write_raw
from ..io.rawimage import RawImage
from ..engine.runtime import get_runtime
from ..sim.simulate import simulate

CFAS = ("lms", "bayer")
GAINS = (1, 8, 64)
THROUGHPUT_REPEAT = (4, 5)
"""The chart's mosaic is repeated 4 x 5 (10 MP) to measure throughput at a realistic size."""


@dataclass
class DemoRow:
    cfa: str
    gain: float
    psnr: float
    psnr_linear: float
    psnr_zone_plate: float
    gray_snr: np.ndarray
    mp_per_s: float


def _score(cfa: str, gain: float, raw: RawImage, truth: np.ndarray, regions: dict, gray_rois: list,
           out_dir: Path) -> DemoRow:
    process_with_stats(raw)                               # warm-up: builds and caches the kernels
    image, stats = process_with_stats(raw)
    write_image(out_dir / f"{cfa}_gain{gain:g}.png", image, encoded=False)
    return DemoRow(cfa, gain, psnr(image, truth), psnr(image, truth, tone_mapped=False),
                   psnr(image, truth, region=regions["zone_plate"]), gray_panel_snr(image, gray_rois),
                   stats.mp_per_s)


def _throughput(raw: RawImage) -> float:
    """MP/s of the default pipeline on the raw's mosaic repeated THROUGHPUT_REPEAT times (warm)."""
    big = RawImage(np.tile(raw.data, THROUGHPUT_REPEAT), raw.cfa, raw.black_level, raw.white_level,
                   raw.wb, raw.colour_matrix, raw.exposure, raw.wb2, dict(raw.metadata), raw.source)
    process_with_stats(big)
    best = min(process_with_stats(big)[1].seconds for _ in range(3))
    return big.data.size / 1e6 / best


def _print_table(rows: list[DemoRow]) -> None:
    print(f"{'cfa':<6}{'gain':>5}{'PSNR dB':>9}{'linear':>8}{'zone':>7}   "
          f"gray-panel SNR dB, panels 1..6 (linear)        {'MP/s':>6}")
    for r in rows:
        snr = " ".join(f"{v:6.2f}" for v in r.gray_snr)
        print(f"{r.cfa:<6}{r.gain:>5g}{r.psnr:>9.2f}{r.psnr_linear:>8.2f}{r.psnr_zone_plate:>7.2f}   {snr}   "
              f"{r.mp_per_s:>6.1f}")


def run_demo(out_dir: Path) -> list[DemoRow]:
    """Run the demo, writing raws and images into ``out_dir``; returns the table rows."""
    out_dir.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    chart = demo_chart()
    write_image(out_dir / "scene.png", chart.image, encoded=False)
    h, w = chart.image.shape[:2]
    print(f"clisp demo: {w}x{h} chart (ColorChecker, zone plate, Siemens star, dead leaves) -> {out_dir}/")
    print(f"OpenCL: {get_runtime().describe()}")
    demosaics = ", ".join(f"{kind} {resolve_options(None, None, kind)['demosaic']}" for kind in CFAS)
    levels = resolve_options(None, None, CFAS[0])["denoise_levels"]
    denoise = f"chroma denoise ({levels} levels)" if levels else "no chroma denoise"
    print(f"pipeline (preset {DEFAULT_PRESET}): normalise, WB pass 1, demosaic ({demosaics}), colour matrix + "
          f"{denoise}, WB pass 2; PSNR tone-mapped with a 10 px border, 'zone' = zone-plate PSNR")
    rows, raws = [], {}
    for cfa in CFAS:
        for gain in GAINS:
            sim = simulate(chart.image, cfa=cfa, gain=gain, seed=gain)
            path = out_dir / f"{cfa}_gain{gain:g}.dng"
            write_raw(path, sim.raw)
            raw = read_raw(path)
            raws[cfa] = raw
            rows.append(_score(cfa, gain, raw, sim.truth, chart.regions, chart.gray_rois, out_dir))
    _print_table(rows)
    for cfa, raw in raws.items():
        mp = raw.data.size * np.prod(THROUGHPUT_REPEAT) / 1e6
        print(f"throughput, {cfa} on a {mp:.0f} MP mosaic: {_throughput(raw):.1f} MP/s")
    print(f"done in {time.perf_counter() - start:.1f} s")
    return rows
