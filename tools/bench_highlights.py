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

``--natural``: issue 25's natural scenes instead: every Kodak image of ``--data`` (sRGB PNGs, so
the truth stays at or under 1.0 and clipping is shallow, as in most photos) and four photos of our
own making (:func:`own_photos`: glossy spheres with white specular highlights, a window beside a
red curtain, a sunset with a clipped orange sun, saturated flowers with white petals past the clip
point), and issue 43's three scenes (clisp.sim.highlight_scenes: glossy spheres of saturated colour
with white specular highlights, a white shirt exposed to the right, a lamp past the clip beside
both), at gains 1 and 8, LMS and Bayer, seed 1, modes off, clamp, clip, reconstruct (and LibRaw's
for Bayer). Per mode: gross-error pixels (any channel more than 0.5 linear off the truth), the
worst error, the worst on the specular rim (:func:`specular_rim`) and mean CIEDE2000 over the
clipped region and a 3 px rim around it (output and truth divided by the truth's peak, at least
1); per image, whether reconstruct has more gross pixels than clip or any pixel over 1.0 off
(issue 25's acceptance, Kodak), or, on issue 43's scenes, more gross pixels than clip or a pixel of
the specular rim over 1.0 off. ``--csv`` writes every row. Every per-pixel score leaves out the
image's BORDER px, as every PSNR in the project does.

``--accept``: issue 14's acceptance figures instead, at gain 1, for clip and reconstruct, LMS and
Bayer: the worst 16 px block chroma of a neutral ramp from 0.2 to 4 (48 x 384 px) and of blown white
lamps (a hard-edged disc of radius 30 px and the soft-edged lamp above, 128 px), and the largest fall
of the ramp's column brightness as the scene brightens (the scenes of tests/modules/test_highlights.py);
then issue 43's scenes (192 px) at gains 1, 4, 16 and 64, LMS and Bayer, seed 1: gross pixels and
the worst error of reconstruct and clip, the worst on the specular rim (all without the BORDER
px), PSNR of the default and of ``--highlights off``, and whether the raw got a highlight stage at all (the white shirt should not:
its clipped samples are noise around full scale).

Usage: python tools/bench_highlights.py [--size 192] [--no-libraw] [--accept]
       python tools/bench_highlights.py --natural [--data DIR] [--only kodim23] [--csv PATH] [--no-libraw]
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path

import clisp
from clisp.metrics import ciede2000, psnr
from clisp.pipeline import build_pipeline
from clisp.sim.simulate import inverse_isp_matrix
from clisp.scene.noise import CLIP_FRACTION
from clisp.modules.highlights.stage import Highlights, box_max
from clisp.sim.highlight_scenes import highlight_scenes, specular_rim

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


def clipped_region(truth: np.ndarray, cfa: str, level: float = 1.0) -> np.ndarray:
    """Pixels whose truth, in the simulation's raw channels, reaches ``level`` of the clip point."""
    a, _ = inverse_isp_matrix(cfa)
    raw = truth @ a.T
    return raw.max(-1) >= level


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
    from clisp.io.rawfile import write_raw
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
    print("\nissue 43's scenes (192 px, seed 1): reconstruct / clip gross pixels, worst; worst on the specular "
          "rim; PSNR default / off (dB); stage built")
    fails = []
    for name, scene in highlight_scenes(192).items():
        for cfa in ("lms", "bayer"):
            for gain in (1, 4, 16, 64):
                sim = clisp.simulate(scene, cfa=cfa, gain=gain, seed=1)
                default = build_pipeline(sim.raw)
                stage = any(isinstance(s, Highlights) for s in default.stages)
                outs = {"reconstruct": default.run(sim.raw.data)}
                for mode in ("clip", "off"):
                    outs[mode] = build_pipeline(sim.raw, highlights=mode).run(sim.raw.data)
                rim, truth = inner(specular_rim(sim.truth, cfa)), inner(sim.truth)
                (g_r, w_r), (g_c, w_c) = (gross_errors(inner(outs[m]), truth) for m in ("reconstruct", "clip"))
                rim_worst = float(np.abs(inner(outs["reconstruct"]) - truth).max(-1)[rim].max()) if rim.any() else 0.0
                bad = g_r > g_c or rim_worst > WORST
                if bad:
                    fails.append(f"{name} {cfa} g{gain}")
                print(f"  {name:14s} {cfa:5s} g{gain:<2d} gross {g_r:5d} / {g_c:5d}  worst {w_r:.2f} / {w_c:.2f}  "
                      f"rim {rim_worst:.2f}  PSNR {psnr(outs['reconstruct'], sim.truth):6.2f} / "
                      f"{psnr(outs['off'], sim.truth):6.2f}  stage {'yes' if stage else 'no'}" + ("  FAIL" if bad else ""),
                      flush=True)
    print(f"issue 43's scenes where reconstruct has more gross pixels than clip, or a specular rim pixel over "
          f"{WORST}: " + (", ".join(fails) if fails else "none"))
    return 0


GROSS = 0.5
"""A pixel is a gross error where some channel is more than this off the truth (linear)."""
WORST = 1.0
"""Issue 25's acceptance: no pixel of reconstruct more than this off the truth."""
RIM = 3
"""Pixels within this distance (Chebyshev) of the clipped region join it for CIEDE2000."""
BORDER = 10
"""Pixels this near (px) the image's edge are left out of the gross counts, the worst errors and
CIEDE2000, as out of every PSNR in the project (clisp.metrics.psnr's default): a one-pixel line
whose row holds no sample of a channel is beyond the demosaic, and a scan's edge has such lines
(kodim20's top row is dark under a bright sky; residual interpolation puts the sky's blue there,
about 0.5 off in every mode, off included: all of the image's gross pixels at Bayer gain 8). The
highlight stage is judged where its input can be right."""


def inner(a: np.ndarray) -> np.ndarray:
    """``a`` (H x W [x C]) less BORDER px on every side."""
    return a[BORDER:a.shape[0] - BORDER, BORDER:a.shape[1] - BORDER]


def own_photos(n: int = 384, seed: int = 7) -> dict[str, np.ndarray]:
    """Four linear-sRGB scenes of our own making (n x n) where clipped whites or lights meet
    saturated colour, as in photos; values past 1.0 are past the clip point at gain 1."""
    rng = np.random.default_rng(seed)
    yy, xx = (np.mgrid[:n, :n] + 0.5) / n
    out = {}
    # glossy spheres: Lambert + Blinn-Phong, white specular highlights up to 3x white
    img = np.stack([0.25 + 0.2 * yy, 0.22 + 0.15 * yy, 0.18 + 0.1 * yy], -1)
    light = np.array([-0.4, -0.5, 0.77]) / np.linalg.norm([-0.4, -0.5, 0.77])
    half = (light + [0, 0, 1]) / np.linalg.norm(light + [0, 0, 1])
    for cy, cx, r, col in ((0.3, 0.28, 0.17, (0.8, 0.05, 0.04)), (0.3, 0.72, 0.16, (0.02, 0.55, 0.5)),
                           (0.72, 0.25, 0.15, (0.9, 0.7, 0.02)), (0.7, 0.72, 0.18, (0.05, 0.1, 0.75)),
                           (0.5, 0.5, 0.09, (0.1, 0.6, 0.08))):
        dx, dy = (xx - cx) / r, (yy - cy) / r
        inside = dx ** 2 + dy ** 2 < 1
        nz = np.sqrt(np.clip(1 - dx ** 2 - dy ** 2, 0, 1))
        normal = np.stack([dx, dy, nz], -1)
        diffuse = np.clip(normal @ light, 0, 1)[..., None] * np.array(col) * 1.1 + 0.03
        spec = 3.0 * np.clip(normal @ half, 0, 1)[..., None] ** 60
        img = np.where(inside[..., None], diffuse + spec, img)
    out["glossy spheres"] = img
    # a bright window (sky, 1.6x white) in a dim wall, a red curtain with folds beside it
    img = np.full((n, n, 3), 0.12) * np.array([1.0, 0.95, 0.85])
    window = (np.abs(xx - 0.63) < 0.21) & (np.abs(yy - 0.45) < 0.3)
    img[window] = np.array([1.3, 1.5, 1.8])[None] * (1 + 0.1 * yy[window])[..., None]
    folds = 0.55 + 0.45 * np.sin(2 * np.pi * 9 * xx + 2 * yy) ** 2
    curtain = (xx > 0.2) & (xx < 0.42)
    img[curtain] = (folds[curtain, None] * np.array([0.85, 0.05, 0.08]))
    out["window and curtain"] = img
    # sunset: an orange sky, a clipped sun (coloured light), dark hills
    img = np.stack([0.9 - 0.5 * yy, 0.45 - 0.3 * yy, 0.2 - 0.1 * yy], -1).clip(0.02)
    sun = np.clip((0.09 - np.hypot(yy - 0.42, xx - 0.55)) / 0.05, 0, 1)[..., None]
    img = img * (1 - sun) + sun * np.array([3.0, 1.9, 0.7])
    hills = yy > 0.62 + 0.08 * np.sin(2 * np.pi * 2.3 * xx)
    img[hills] = np.array([0.03, 0.04, 0.02])
    out["sunset"] = img
    # flowers: saturated discs with white petals just past the clip point, on green leaves
    img = np.stack([0.05 + 0.05 * rng.random((n, n)), 0.2 + 0.1 * rng.random((n, n)), 0.04 + 0.03 * rng.random((n, n))], -1)
    colours = np.array([(0.85, 0.05, 0.3), (0.9, 0.75, 0.02), (0.5, 0.05, 0.8), (1.25, 1.22, 1.18), (1.4, 1.38, 1.3)])
    for _ in range(40):
        cy, cx, r = rng.random(), rng.random(), 0.02 + 0.07 * rng.random()
        img[np.hypot(yy - cy, xx - cx) < r] = colours[rng.integers(len(colours))]
    out["flowers"] = img
    return out


ISSUE43 = tuple(highlight_scenes(8))
"""The names of issue 43's scenes (clisp.sim.highlight_scenes)."""


def natural_scenes(data: Path, only: str) -> dict[str, np.ndarray]:
    """Kodak images of ``data``/kodak (linear sRGB, uncropped), :func:`own_photos` and issue 43's
    scenes (384 px), by name."""
    from clisp.io.imageio import read_scene
    scenes_ = {Path(name).stem: image for name, image in toolkit.kodak(data, read=read_scene, required=False)}
    scenes_.update(own_photos())
    scenes_.update(highlight_scenes(384))
    return {k: v for k, v in scenes_.items() if not only or only in k}


def gross_errors(out: np.ndarray, truth: np.ndarray) -> tuple[int, float]:
    """(pixels with a channel more than GROSS off the truth, the largest error)."""
    err = np.abs(out.astype(np.float64) - truth).max(-1)
    return int((err > GROSS).sum()), float(err.max())


def natural(args: argparse.Namespace) -> int:
    """Issue 25's table: gross errors and CIEDE2000 per mode on natural scenes."""
    rows, fails = [], []
    with tempfile.TemporaryDirectory() as tmp:
        for name, scene in natural_scenes(args.data, args.only).items():
            for cfa in ("lms", "bayer"):
                for gain in (1, 8):
                    sim = clisp.simulate(scene, cfa=cfa, gain=gain, seed=1)
                    mask = clipped_region(sim.truth, cfa, CLIP_FRACTION)
                    if mask.any():
                        mask = box_max(box_max(np.pad(mask, RIM).astype(float), RIM, 0), RIM, 1) > 0
                    methods = {f"clisp {mode}": build_pipeline(sim.raw, highlights=mode).run(sim.raw.data)
                               for mode in ("off", "clamp", "clip", "reconstruct")}
                    if cfa == "bayer" and not args.no_libraw:
                        for mode in ("Clip", "Ignore", "Blend", "ReconstructDefault"):
                            methods[f"LibRaw {mode}"] = libraw(sim.raw, mode, Path(tmp), mask, sim.truth)
                    peak = max(float(sim.truth.max()), 1.0)
                    rim, mask, truth = inner(specular_rim(sim.truth, cfa)), inner(mask), inner(sim.truth)
                    cells = {}
                    for method, out in methods.items():
                        out = inner(out)
                        g, w = gross_errors(out, truth)
                        rw = float(np.abs(out - truth).max(-1)[rim].max()) if rim.any() else 0.0
                        de = ciede2000(out[mask][None] / peak, truth[mask][None] / peak) if mask.any() else np.nan
                        rows.append({"scene": name, "cfa": cfa, "gain": gain, "method": method, "gross": g,
                                     "worst": round(w, 3), "rim_worst": round(rw, 3), "de00": round(float(de), 3),
                                     "clipped_px": int(mask.sum())})
                        cells[method] = (g, w, rw)
                    rec, clip = cells["clisp reconstruct"], cells["clisp clip"]
                    kodak, ours = name.startswith("kodim"), name in ISSUE43
                    # issue 25's test on Kodak; issue 43's on its scenes (the rim: the core is past every record)
                    above = rec[0] > clip[0] or (rec[2] if ours else rec[1]) > WORST
                    if above and (kodak or ours):
                        fails.append(f"{name} {cfa} g{gain}")
                    tag = ("  FAIL" if kodak or ours else "  (above clip or 1.0)") if above else ""
                    print(f"{name:20s} {cfa:5s} g{gain:<2d} " + "  ".join(
                        f"{m.split()[-1]} {g}/{w:.2f}/{rw:.2f}" for m, (g, w, rw) in cells.items()) + tag, flush=True)
    if args.csv:
        toolkit.write_csv(rows, Path(args.csv))
    print("\ntotals: gross-error pixels (sum), worst error (max), worst on the specular rim (max), "
          "CIEDE2000 over clipped + rim (mean)")
    for group, pick in (("Kodak", lambda r: r["scene"].startswith("kodim")),
                        ("own photos", lambda r: not r["scene"].startswith("kodim") and r["scene"] not in ISSUE43),
                        ("issue 43", lambda r: r["scene"] in ISSUE43)):
        for cfa in ("lms", "bayer"):
            for gain in (1, 8):
                sel = [r for r in rows if pick(r) and r["cfa"] == cfa and r["gain"] == gain]
                for method in dict.fromkeys(r["method"] for r in sel):
                    m = [r for r in sel if r["method"] == method]
                    if not m:
                        continue
                    de = [r["de00"] for r in m if r["clipped_px"]]
                    print(f"  {group:10s} {cfa:5s} g{gain:<2d} {method:26s} gross {sum(r['gross'] for r in m):6d}  "
                          f"worst {max(r['worst'] for r in m):5.2f}  rim {max(r['rim_worst'] for r in m):5.2f}  "
                          f"dE00 {np.mean(de) if de else float('nan'):6.2f}")
    print(f"\nKodak images where reconstruct has more gross pixels than clip, or a pixel over {WORST}, and issue 43's "
          f"scenes where it has more gross pixels than clip, or a specular rim pixel over {WORST}: "
          + (", ".join(fails) if fails else "none"))
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=192)
    ap.add_argument("--no-libraw", action="store_true")
    ap.add_argument("--accept", action="store_true", help="issue 14's acceptance figures instead")
    ap.add_argument("--natural", action="store_true", help="issue 25's natural scenes instead")
    toolkit.add_data_option(ap, "kodak/ (--natural)")
    ap.add_argument("--only", default="", help="scenes whose name contains this (--natural)")
    ap.add_argument("--csv", default="", help="write every row of --natural here")
    args = ap.parse_args(argv)
    if args.accept:
        return accept()
    if args.natural:
        return natural(args)
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
