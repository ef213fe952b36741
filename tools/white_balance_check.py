"""``--wb`` on camera raws (issue 31, item 2): the 550D chart's grey patches, the D30 beside rawpy.

    python tools/white_balance_check.py [--data DIR] [--preset quality] [--out docs/white_balance]

1. Canon 550D colour chart (DATA/raw/Canon_EOS550D_MagicLantern_colorchart.dng): the five lighter
   grey patches of the ColorChecker's bottom row (white to neutral 3.5; the black patch is left
   out, its chroma is noise), processed from the command line (``clisp process --no-crop`` to a
   16-bit TIFF, decoded to linear sRGB) with each ``--wb``, and by rawpy (camera WB, and its
   default: daylight). Each output is scaled by one factor so that the white patch has Y = 0.9
   (its reflectance), so that every white balance is judged at the same exposure; printed is the
   mean and largest C*ab = sqrt(a*^2 + b*^2) of the patches' mean colours (CIE Lab, D65). The
   patch-fit row is the bound of any global white balance: the multipliers that make the patches'
   own mean raw colour neutral.
   The patch centres were read by eye off the image (mosaic coordinates, 32 x 32 px windows).
2. Canon D30 (DATA/raw/RAW_CANON_D30_SRGB.CRW, no camera white balance): crops of the lighter's
   top (chrome, steel wheel) and of the wood, for rawpy's default (daylight), clisp before this option (gray world,
   given as multipliers), and clisp's ``--wb auto`` (its default for a raw without camera WB),
   saved to OUT/d30_crops.png with the steel wheel's mean C*ab printed (polished steel reflects
   the light: near-neutral when the white balance is right).
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path

from clisp.io.imageio import read_image
from clisp.io.rawfile import read_raw
from clisp.metrics import linear_srgb_to_lab
from clisp.sim.colorimetry import srgb_decode
from clisp.scene.white_balance import gray_world_gains

CHART = "raw/Canon_EOS550D_MagicLantern_colorchart.dng"
D30 = "raw/RAW_CANON_D30_SRGB.CRW"
GREY_PATCHES = [(930, 702), (930, 812), (930, 924), (930, 1036), (930, 1146)]
"""(y, x) centres of the white, neutral 8, 6.5, 5 and 3.5 patches in the 550D's mosaic."""
PATCH = 16
"""Half side of a patch window, px."""
WHITE_Y = 0.9
"""Luminance the white patch is scaled to (its reflectance)."""
D30_CHROME = (slice(130, 380), slice(980, 1300))
"""The lighter's knurled steel wheel in the D30's cropped output, (rows, columns), read by eye."""
D30_CROPS = [(slice(80, 580), slice(360, 1360)), (slice(300, 800), slice(1660, 2160))]
"""Crops shown: the lighter's top (chrome, wheel, red cap) and the wood beside it."""
LUMA = np.array([0.2126, 0.7152, 0.0722])


def clisp_linear(raw: Path, out: Path, preset: str | None, *extra: str) -> np.ndarray:
    """``clisp process RAW -o OUT.tif`` (16-bit sRGB) decoded to linear sRGB."""
    cmd = toolkit.clisp_cmd("process", str(raw), "-o", str(out), *(["--preset", preset] if preset else []), *extra)
    run = subprocess.run(cmd, capture_output=True, text=True)
    if run.returncode != 0:
        raise SystemExit(f"{raw.name}: {run.stderr.strip()}")
    return srgb_decode(read_image(out)[0].astype(np.float64))


def rawpy_linear(raw: Path, camera_wb: bool) -> np.ndarray:
    """rawpy's postprocess, linear 16-bit sRGB, no auto-bright, not rotated: camera WB or its
    default (daylight multipliers)."""
    import rawpy
    with rawpy.imread(str(raw)) as r:
        return r.postprocess(use_camera_wb=camera_wb, no_auto_bright=True, gamma=(1, 1), output_bps=16,
                             user_flip=0).astype(np.float64) / 65535.0


def patch_means(image: np.ndarray, offset: tuple[int, int] = (0, 0)) -> np.ndarray:
    """Mean linear colour of each grey patch window, shape (5, 3)."""
    return np.array([image[y - offset[0] - PATCH:y - offset[0] + PATCH,
                           x - offset[1] - PATCH:x - offset[1] + PATCH].reshape(-1, 3).mean(axis=0)
                     for y, x in GREY_PATCHES])


def chroma(means: np.ndarray) -> np.ndarray:
    """C*ab of each patch colour after scaling the first (white) to Y = WHITE_Y."""
    scaled = means * (WHITE_Y / float(means[0] @ LUMA))
    lab = linear_srgb_to_lab(scaled)
    return np.hypot(lab[:, 1], lab[:, 2])


def patch_fit_chroma(raw_path: Path, preset: str | None, tmp: Path) -> tuple[np.ndarray, np.ndarray]:
    """The bound: multipliers that neutralise the patches' own mean raw colour, their C*ab."""
    raw = read_raw(raw_path)
    p = raw.cfa.period
    channel = raw.cfa.channel_map(*raw.shape)
    sums = np.zeros(3)
    for y, x in GREY_PATCHES[:3]:                # the three lightest: least noise and flare
        window = (slice(y - PATCH, y + PATCH), slice(x - PATCH, x + PATCH))
        for c in range(3):
            sel = channel[window] == c
            sums[c] += float((raw.data[window][sel] - raw.black_level[c]).mean())
    gains = sums[1] / sums
    assert p == 2
    image = clisp_linear(raw_path, tmp / "fit.tif", preset, "--no-crop", "--wb", ",".join(f"{g:.6f}" for g in gains))
    return gains, chroma(patch_means(image))


def chart_table(data: Path, preset: str | None, tmp: Path) -> None:
    path = data / CHART
    print(f"\n550D colour chart, grey patches (white..neutral 3.5), C*ab at white Y = {WHITE_Y} (preset "
          f"{preset or 'default'}):\n")
    print("| white balance | multipliers R,G,B | mean C*ab | largest C*ab |")
    print("|---|---|---:|---:|")
    for wb in ("camera", "auto", "daylight"):
        image = clisp_linear(path, tmp / f"{wb}.tif", preset, "--no-crop", "--wb", wb)
        gains = _gains(path, wb)
        c = chroma(patch_means(image))
        print(f"| clisp --wb {wb} | {gains} | {c.mean():.1f} | {c.max():.1f} |", flush=True)
    for name, camera in (("rawpy, camera WB", True), ("rawpy default (daylight)", False)):
        c = chroma(patch_means(rawpy_linear(path, camera)))
        print(f"| {name} | | {c.mean():.1f} | {c.max():.1f} |", flush=True)
    gains, c = patch_fit_chroma(path, preset, tmp)
    print(f"| patch fit (the bound) | {', '.join(f'{g:.3f}' for g in gains)} | {c.mean():.1f} | {c.max():.1f} |")


def _gains(path: Path, wb: str) -> str:
    from clisp.scene.white_balance import with_white_balance
    raw = with_white_balance(read_raw(path), wb)
    return ", ".join(f"{g:.3f}" for g in raw.wb)


def d30_crops(data: Path, preset: str | None, tmp: Path, out: Path) -> None:
    from PIL import Image
    path = data / D30
    raw = read_raw(path)
    gray = gray_world_gains(raw.data, raw.cfa, raw.black_level, raw.white_level)
    top, left = raw.metadata["crop"][:2]
    before = clisp_linear(path, tmp / "gray.tif", preset, "--wb", ",".join(f"{g:.6f}" for g in gray))
    auto = clisp_linear(path, tmp / "auto.tif", preset, "--wb", "auto")
    daylight = rawpy_linear(path, camera_wb=False)[top:top + before.shape[0], left:left + before.shape[1]]
    rows = [("rawpy default (daylight)", daylight), ("clisp before (gray world)", before),
            ("clisp --wb auto (default)", auto)]
    print(f"\nCanon D30 (no camera white balance), the steel wheel's mean colour (preset {preset or 'default'}):\n")
    print("| rendering | wheel C*ab | wheel R:G:B |")
    print("|---|---:|---|")
    for name, image in rows:
        mean = image[D30_CHROME].reshape(-1, 3).mean(axis=0)
        c = float(chroma(np.stack([mean] * 5))[0])
        print(f"| {name} | {c:.1f} | {', '.join(f'{v / mean[1]:.2f}' for v in mean)} |")
    tiles = []
    for name, image in rows:
        scale = 0.5 / float(np.percentile(image @ LUMA, 99))       # one exposure per rendering: the looks compare
        tiles.append(np.concatenate([np.clip(image[c] * scale, 0, 1) for c in D30_CROPS], axis=1))
    figure = np.concatenate(tiles, axis=0)
    figure = figure.reshape(figure.shape[0] // 2, 2, figure.shape[1] // 2, 2, 3).mean(axis=(1, 3))  # half size: colour, not detail
    encoded = np.where(figure <= 0.0031308, 12.92 * figure, 1.055 * np.power(figure, 1 / 2.4) - 0.055)
    out.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.round(encoded * 255).astype(np.uint8)).save(out / "d30_crops.png")
    print(f"\nrows top to bottom: {'; '.join(name for name, _ in rows)} -> {out / 'd30_crops.png'}")


SIM_IMAGES = (1, 3, 5, 8, 13, 19, 20, 23)
"""The Kodak images of ``--sims``."""


def sims_table(data: Path) -> None:
    from clisp.sim.simulate import simulate
    from clisp.scene.white_balance import grey_pixel_gains

    def angle(gains: np.ndarray, truth: np.ndarray) -> float:
        a, b = 1.0 / gains, 1.0 / truth
        return float(np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1))))
    print("\nIlluminant error (degrees, camera space) on simulated Kodak images "
          f"{', '.join(map(str, SIM_IMAGES))} at 0.8 of white:\n")
    print("| CFA | gain | gray world mean | gray world max | grey pixels mean | grey pixels max |")
    print("|---|---:|---:|---:|---:|---:|")
    scenes = [toolkit.load_scene(toolkit.kodak_path(data, i)) for i in SIM_IMAGES]
    for kind in ("bayer", "lms"):
        for gain in (1, 64):
            errors = []
            for i, scene in zip(SIM_IMAGES, scenes):
                r = simulate(scene * 0.8, kind, gain=gain, optics="none", seed=i).raw
                gw = gray_world_gains(r.data, r.cfa, r.black_level, r.white_level)
                gp = grey_pixel_gains(r.data, r.cfa, r.black_level, r.white_level)[0]
                errors.append((angle(gw, r.wb), angle(gp, r.wb)))
            e = np.array(errors)
            print(f"| {kind} | {gain} | {e[:, 0].mean():.2f} | {e[:, 0].max():.2f} | {e[:, 1].mean():.2f} | "
                  f"{e[:, 1].max():.2f} |", flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    toolkit.add_data_option(ap, "raw/ and kodak/")
    ap.add_argument("--preset", default=None)
    toolkit.add_out_option(ap, "docs/white_balance", "the D30 crops")
    ap.add_argument("--sims", action="store_true", help="also the illuminant error on simulated Kodak images")
    args = ap.parse_args(argv)
    for name in (CHART, D30):
        if not (args.data / name).is_file():
            raise toolkit.missing_data(args.data / name, "camera raw")
    print(f"CPU: {toolkit.cpu_model()}")
    with tempfile.TemporaryDirectory(prefix="clisp-wb-") as tmp:
        chart_table(args.data, args.preset, Path(tmp))
        d30_crops(args.data, args.preset, Path(tmp), Path(args.out))
    if args.sims:
        sims_table(args.data)
    return 0


if __name__ == "__main__":
    sys.exit(main())
