"""Highlight benchmark (issue 14): simulated scenes with known truth past the clip point.

Scenes (linear sRGB, truth up to 4x white): a neutral ramp through the clip point, a blown white
lamp, coloured lights (orange, blue) on grey, and a sky (blue, brightening to a clipped sun).
Each is simulated at gains 1 and 8 for LMS and Bayer and processed by clisp with
``--highlights clip`` and ``reconstruct`` (default preset), and for Bayer by LibRaw through rawpy
(highlight modes Clip, Ignore, Blend, ReconstructDefault; AHD, linear sRGB, user_wb = our pass-1
gains, its level calibrated to ours on the unclipped pixels), from the DNG clisp writes.

Scores, over the clipped region only (pixels whose truth has a channel past the clip point, in
the simulation's raw): CIEDE2000 and tone-mapped PSNR (dB), both after dividing output and truth by
the scene's peak (so values up to the peak are compared, not clipped at 1). ``chroma`` is the
largest (max - min)/max of 16 px block means over the clipped region, for the neutral scenes.

``--accept``: issue 14's acceptance figures instead, at gain 1, for clip and reconstruct, LMS and
Bayer: the worst 16 px block chroma of a neutral ramp from 0.2 to 4 (48 x 384 px) and of blown white
lamps (a hard-edged disc of radius 30 px and the soft-edged lamp above, 128 px), and the largest fall
of the ramp's column brightness as the scene brightens (the scenes of tests/test_highlights.py).

Usage: python tools/bench_highlights.py [--size 192] [--no-libraw] [--accept]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import clisp  # noqa: E402
from clisp.metrics import ciede2000, psnr  # noqa: E402
from clisp.pipeline import build_pipeline  # noqa: E402
from clisp.simulate import inverse_isp_matrix  # noqa: E402

PEAK = 4.0
BLOCK = 16
"""Side of the blocks whose mean colour the chroma figures use (px)."""


def scenes(n: int) -> dict[str, np.ndarray]:
    yy, xx = np.mgrid[:n, :n] / n
    out = {}
    ramp = np.repeat((0.2 + (PEAK - 0.2) * xx)[..., None], 3, -1)
    out["neutral ramp"] = ramp
    grey = np.full((n, n, 3), 0.18)
    r = np.hypot(yy - 0.5, xx - 0.5)
    disc = np.clip((0.25 - r) / 0.03, 0, 1)[..., None]      # soft-edged lamp
    out["white lamp"] = grey * (1 - disc) + PEAK * disc
    out["orange light"] = grey * (1 - disc) + disc * PEAK * np.array([1.0, 0.55, 0.2])
    out["blue light"] = grey * (1 - disc) + disc * PEAK * np.array([0.25, 0.5, 1.0])
    sky = np.stack([0.35 + 0.3 * yy, 0.55 + 0.3 * yy, 0.95 + 0.2 * yy], -1) * 1.1
    sun = np.clip((0.12 - np.hypot(yy - 0.3, xx - 0.7)) / 0.1, 0, 1)[..., None]
    out["sky"] = sky * (1 - sun) + PEAK * np.array([1.0, 0.95, 0.85]) * sun
    return out


def clipped_region(truth: np.ndarray, cfa: str) -> np.ndarray:
    """Pixels whose truth, in the simulation's raw channels, passes the clip point."""
    a, _ = inverse_isp_matrix(cfa)
    raw = truth @ a.T
    return raw.max(-1) >= 1.0


def block_means(image: np.ndarray, b: int = BLOCK) -> np.ndarray:
    """Means of the whole b x b blocks of an H x W x C image: (H // b) x (W // b) x C."""
    h, w = image.shape[0] // b * b, image.shape[1] // b * b
    return image[:h, :w].reshape(h // b, b, w // b, b, image.shape[2]).mean(axis=(1, 3))


def score(out: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> tuple[float, float, float]:
    o, t = out[mask][None] / PEAK, truth[mask][None] / PEAK
    de = ciede2000(o, t)
    p = psnr(o, t, border=0)
    cover = block_means(mask[..., None].astype(np.float64)) > 0
    chroma = block_chroma(out)
    return de, p, float(chroma[cover[..., 0]].max()) if cover.any() else float("nan")


def libraw(raw, mode: str, folder: Path, mask: np.ndarray, reference: np.ndarray) -> np.ndarray:
    import rawpy
    from clisp.rawfile import write_raw
    path = folder / "bench.dng"
    write_raw(path, raw)
    g = raw.pass1_gains()
    with rawpy.imread(str(path)) as handle:
        rgb = handle.postprocess(demosaic_algorithm=rawpy.DemosaicAlgorithm.AHD,
                                 user_wb=[float(g[0]), float(g[1]), float(g[2]), float(g[1])],
                                 output_color=rawpy.ColorSpace.sRGB, gamma=(1, 1), no_auto_bright=True,
                                 output_bps=16, user_flip=0, highlight_mode=getattr(rawpy.HighlightMode, mode),
                                 adjust_maximum_thr=0.0).astype(np.float64) / 65535.0
    ok = ~mask & (reference.max(-1) > 0.05) & (rgb.max(-1) < 0.9)
    level = float(np.median(reference[ok].sum(-1) / np.maximum(rgb[ok].sum(-1), 1e-9))) if ok.any() else 1.0
    return (rgb * level).astype(np.float32)


def block_chroma(image: np.ndarray, b: int = BLOCK) -> np.ndarray:
    """(max - min) / max of the b x b block means of an H x W x 3 image."""
    m = block_means(image, b)
    return (m.max(-1) - m.min(-1)) / np.maximum(m.max(-1), 1e-9)


def accept() -> int:
    """Issue 14's acceptance figures (gain 1): ramp and lamps' worst block chroma, ramp fall."""
    ramp = np.repeat(np.repeat(np.linspace(0.2, PEAK, 384)[None, :, None], 48, 0), 3, 2)
    yy, xx = np.mgrid[:128, :128]
    hard = np.full((128, 128, 3), 0.18)
    hard[np.hypot(yy - 64, xx - 64) < 30] = PEAK
    soft = scenes(128)["white lamp"]
    for cfa in ("lms", "bayer"):
        for mode in ("reconstruct", "clip"):
            sim = clisp.simulate(ramp, cfa=cfa, gain=1, seed=3)
            out = build_pipeline(sim.raw, highlights=mode).run(sim.raw.data)
            lum = block_means(out).mean(axis=(0, 2))
            fall = float(np.max(np.maximum.accumulate(lum) - lum) / lum.max())
            cells = [f"ramp chroma {block_chroma(out).max():.3f}, fall {100 * fall:.1f} %"]
            for name, scene, seed in (("hard lamp", hard, 3), ("soft lamp", soft, 1)):
                sim = clisp.simulate(scene, cfa=cfa, gain=1, seed=seed)
                out = build_pipeline(sim.raw, highlights=mode).run(sim.raw.data)
                bright = block_means(sim.truth).max(-1) > 0.5
                cells.append(f"{name} {block_chroma(out)[bright].max():.4f}")
            print(f"{cfa:5s} {mode:11s} " + " | ".join(cells), flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=192)
    ap.add_argument("--no-libraw", action="store_true")
    ap.add_argument("--accept", action="store_true", help="issue 14's acceptance figures instead")
    args = ap.parse_args(argv)
    if args.accept:
        return accept()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, scene in scenes(args.size).items():
            for cfa in ("lms", "bayer"):
                for gain in (1, 8):
                    sim = clisp.simulate(scene, cfa=cfa, gain=gain, seed=1)
                    mask = clipped_region(sim.truth, cfa)
                    methods = {}
                    for mode in ("off", "clip", "reconstruct"):
                        methods[f"clisp {mode}"] = build_pipeline(sim.raw, highlights=mode).run(sim.raw.data)
                    if cfa == "bayer" and not args.no_libraw:
                        for mode in ("Clip", "Ignore", "Blend", "ReconstructDefault"):
                            methods[f"LibRaw {mode}"] = libraw(sim.raw, mode, Path(tmp), mask, sim.truth)
                    for method, out in methods.items():
                        de, p, chroma = score(out, sim.truth, mask)
                        rows.append((name, cfa, gain, method, de, p, chroma))
                        print(f"{name:13s} {cfa:5s} g{gain:<2d} {method:26s} dE00 {de:6.2f}  PSNR {p:6.2f}  "
                              f"chroma {chroma:.3f}", flush=True)
    print("\nmean over scenes and gains (clipped regions)")
    for cfa in ("lms", "bayer"):
        for method in dict.fromkeys(r[3] for r in rows if r[1] == cfa):
            sel = [r for r in rows if r[1] == cfa and r[3] == method]
            print(f"  {cfa:5s} {method:26s} dE00 {np.mean([r[4] for r in sel]):6.2f}  "
                  f"PSNR {np.mean([r[5] for r in sel]):6.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
