"""Chroma bleeding: how far colour moves across edges that the luminance does not mark (issue 17).

    python tools/bench_bleeding.py [--gains 1,8,64] [--cfas lms,bayer] [--seeds 2] [--no-denoise]
                                   [--preset quality] [--crops DIR] [--luma paper] [--noise-scale 1]

Scene (made in code): the ColorChecker with 64 px patches and 48 px gaps on mid-grey (linear 0.18:
several patches are close to it in luminance, so nothing in the luminance stops chroma at their
edges), and below it a row of discs (radius 8, 16, 32 px) in the six saturated patch colours on
the same grey. Each is simulated (clisp.sim.simulate: optics, noise at the gain, 10-bit ADC) and
processed with the preset's pipeline (skipping on, as ``clisp process``).

Ring colour shift: for every patch and disc, the mean linear RGB of the ring 3 to 10 px outside
it (Chebyshev distance for patches, Euclidean for discs) in the output and in the clean,
optics-blurred truth, both converted to CIELAB; the shift is the a*b* distance of the two means
(noise averages out in a ring mean, so what remains is colour moved across the edge). Reported:
mean and worst over the 24 patches, and over the 18 discs; averaged over ``--seeds`` noise seeds.
Also the gray-panel SNR (docs/model.md section 5: central 32 x 32 of the six neutral patches,
linear, mean over R, G, B and panels), to show both sides of the trade.

First figures (2026-11-24, 2 shared cores, seed 0, preset quality; ``--gains 8,64 --seeds 1``)::

    cfa    gain  patch mean / worst  disc mean / worst  gray SNR
    lms       8        0.70 / 2.42        0.76 / 1.89     27.60
    lms      64        1.60 / 4.45        2.71 / 5.31     18.04
    bayer     8        0.23 / 0.39        0.44 / 1.11     22.42
    bayer    64        1.44 / 5.71        1.86 / 6.50     12.66
    --no-denoise: lms 8 1.09 / 3.28, lms 64 1.79 / 3.61, bayer 8 0.26 / 0.62, bayer 64 0.97 / 2.06

So for Bayer the shift at gain 64 comes from the chroma denoiser (without it, 0.97 / 2.06), for LMS
mostly from the guided demosaic's chroma (without the denoiser it is larger still). A post-hoc clamp
of the denoised chroma to the 3 x 3 mean of the undenoised chroma +- 1 noise std of that mean
(prototype, not in clisp) brings Bayer 64 to 1.08 / 2.81 at -0.7 dB gray SNR and does not help
LMS (1.73 / 3.46): the fix belongs inside the demosaic's and the denoiser's estimates.

Bayer, with the chroma range cap (ChromaDenoiseParams.chroma_range_cap, CHROMA_RANGE_CAP['yuv']
= 0.027; 2 seeds): gain 4 0.15 / 0.33, gain 8 0.20 / 0.37, gain 64 0.99 / 2.27 (discs 1.17 /
2.43), gray SNR 12.57 dB (12.58 without). PSNR of 7 Kodak + 5 McMaster images: unchanged at gains
4-16, -0.02 dB at 32, -0.05 dB at 64.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import toolkit  # noqa: F401  (before clisp: puts this checkout on sys.path)

from clisp.sim.charts import BACKGROUND, colorchecker, colorchecker_linear, gray_panel_rois
from clisp.metrics import gray_panel_snr, linear_srgb_to_lab
from clisp.pipeline import build_pipeline
from clisp.sim.simulate import simulate

PATCH, GAP = 64, 48
DISC_RADII = (8, 16, 32)
SATURATED = (12, 13, 14, 15, 16, 17)          # blue, green, red, yellow, magenta, cyan
RING = (3, 10)


def scene() -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray]]:
    """(image H x W x 3 linear sRGB, ring masks of the patches, ring masks of the discs)."""
    cc, rois = colorchecker(patch=PATCH, gap=GAP, border=GAP, background=BACKGROUND)
    row_h = 2 * max(DISC_RADII) + 2 * GAP
    h, w = cc.shape[0] + row_h, cc.shape[1]
    image = np.full((h, w, 3), BACKGROUND)
    image[:cc.shape[0]] = cc
    yy, xx = np.mgrid[0:h, 0:w]
    patch_rings = []
    for y0, y1, x0, x1 in rois:
        dy = np.maximum(np.maximum(y0 - yy, yy - (y1 - 1)), 0)
        dx = np.maximum(np.maximum(x0 - xx, xx - (x1 - 1)), 0)
        d = np.maximum(dy, dx)
        patch_rings.append((d >= RING[0]) & (d <= RING[1]))
    colours = colorchecker_linear()
    disc_rings = []
    cy = cc.shape[0] + row_h // 2
    slots = [(r, c) for r in DISC_RADII for c in SATURATED]
    step = w / (len(slots) + 1)
    for k, (radius, colour) in enumerate(slots):
        cx = (k + 1) * step
        d = np.hypot(yy - cy, xx - cx)
        image[d <= radius] = colours[colour]
        disc_rings.append((d > radius + RING[0]) & (d <= radius + RING[1]))
    return image, patch_rings, disc_rings


def ring_shifts(output: np.ndarray, truth: np.ndarray, rings: list[np.ndarray]) -> np.ndarray:
    """a*b* distance of the ring-mean colours of ``output`` and ``truth`` (linear sRGB), per ring."""
    out = []
    for ring in rings:
        a = linear_srgb_to_lab(np.clip(output[ring].mean(axis=0), 0, None)[None, None])[0, 0]
        b = linear_srgb_to_lab(np.clip(truth[ring].mean(axis=0), 0, None)[None, None])[0, 0]
        out.append(float(np.hypot(a[1] - b[1], a[2] - b[2])))
    return np.array(out)


def measure(cfa: str, gain: float, seeds: int, preset: str | None, denoise: "bool | None | ChromaDenoiseParams",
            crops: Path | None = None) -> dict[str, float]:
    image, patch_rings, disc_rings = scene()
    gray = gray_panel_rois(colorchecker(patch=PATCH, gap=GAP, border=GAP)[1])
    patches, discs, snr, seconds = [], [], [], 0.0
    for seed in range(seeds):
        sim = simulate(image, cfa=cfa, gain=gain, seed=seed)
        pipe = build_pipeline(sim.raw, preset=preset, denoise=denoise, skip=True)
        t = time.perf_counter()
        out = pipe.run(sim.raw.data)
        seconds += time.perf_counter() - t
        patches.append(ring_shifts(out, sim.truth, patch_rings))
        discs.append(ring_shifts(out, sim.truth, disc_rings))
        snr.append(float(np.mean(gray_panel_snr(out, gray))))
        if crops is not None and seed == 0:
            from clisp.io.imageio import write_image
            crops.mkdir(parents=True, exist_ok=True)
            write_image(crops / f"bleeding_{cfa}_g{gain:g}.png", np.clip(out[:400, :560], 0, 1), encoded=False)
    p, d = np.mean(patches, axis=0), np.mean(discs, axis=0)
    return {"patch_mean": float(p.mean()), "patch_worst": float(p.max()), "disc_mean": float(d.mean()),
            "disc_worst": float(d.max()), "gray_snr": float(np.mean(snr)), "seconds": seconds / seeds}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--gains", default="1,8,64")
    ap.add_argument("--cfas", default="lms,bayer")
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--preset", default=None)
    ap.add_argument("--no-denoise", action="store_true")
    ap.add_argument("--crops", type=Path, default=None, help="write the chart crops (first seed) here")
    ap.add_argument("--luma", default=None, help="the chroma denoiser's luminance (ChromaDenoiseParams.luma; "
                    "default: the preset's)")
    ap.add_argument("--noise-scale", type=float, default=None, help="the chroma denoiser's noise_scale")
    args = ap.parse_args()
    denoise = False if args.no_denoise else None
    if not args.no_denoise and (args.luma is not None or args.noise_scale is not None):
        from dataclasses import replace
        from clisp.pipeline import PRESETS, denoise_params
        levels = PRESETS[args.preset or "quality"]["denoise_levels"]
        base = denoise_params(None, levels)
        denoise = replace(base, **{k: v for k, v in (("luma", args.luma), ("noise_scale", args.noise_scale))
                                   if v is not None})
    print(f"{'cfa':<6}{'gain':>5}{'patch mean':>12}{'worst':>8}{'disc mean':>11}{'worst':>8}{'gray SNR':>10}{'s':>7}")
    for cfa in args.cfas.split(","):
        for gain in (float(g) for g in args.gains.split(",")):
            r = measure(cfa, gain, args.seeds, args.preset, denoise, args.crops)
            print(f"{cfa:<6}{gain:>5g}{r['patch_mean']:>12.2f}{r['patch_worst']:>8.2f}{r['disc_mean']:>11.2f}"
                  f"{r['disc_worst']:>8.2f}{r['gray_snr']:>10.2f}{r['seconds']:>7.2f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
