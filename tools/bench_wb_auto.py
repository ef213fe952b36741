"""White balance ``auto`` judged on Kodak and McMaster under three lights (issue 42, item 1).

    python tools/bench_wb_auto.py [--data DIR] [--subset N] [--before] [--results docs/RESULTS.md] [--csv FILE]
    python tools/bench_wb_auto.py --scenes [--seeds 12]     # the tuning set (tools/wb_scenes.py)

Each image (linear sRGB, white 1) is lit by D65, a warm light (3200 K, Planck's locus) and a cool one
(8000 K, CIE daylight): the scene times the light's linear sRGB colour (clisp.scene.illuminant.light_srgb,
scaled so its largest channel is 1: no channel brighter than under D65), simulated (clisp.simulate,
Airy optics, seed 1) as a Bayer and an LMS raw at gains 1 and 16, and processed in this process
(clisp.process, default preset, linear sRGB output; the same stages as ``clisp process``) with
each white balance:

``auto``       ``--wb auto`` as this tree has it (clisp.scene.white_balance.with_white_balance);
``grey px``    with ``--before``: the grey-pixel estimate that was ``--wb auto`` before issue 42
               (clisp.scene.white_balance.grey_pixel_gains), given as multipliers;
``gray world`` clisp.scene.white_balance.gray_world_gains, given as multipliers;
``daylight``   ``--wb daylight``: the camera's D65 multipliers (right under D65 by construction);
``true``       the light's own multipliers (clisp.scene.illuminant.CameraLights.gains): the floor the
               metric leaves to any global white balance (clipping, noise, the tone of the light).

The error of an image: the angle (degrees) in linear sRGB between the mean colour of the mid-tones
(pixels whose three channels lie within 0.03..0.85) of the output and that of the same scene lit
by D65, simulated the same way and processed with ``--wb camera`` (its true white balance). Each
image's mid-tones are its own (the issue's definition). Printed and written into RESULTS (section
``bench_wb_auto``): per set, light and camera (CFA, gain) the mean and worst image of each method.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path

LIGHTS = {"D65": None, "3200 K": (3200.0, 0.0), "8000 K": (8000.0, 0.0)}
"""The lights: None is D65 itself (the scene as it is); else (T, Duv) of clisp.scene.illuminant."""
CAMERAS = (("bayer", 1), ("bayer", 16), ("lms", 1), ("lms", 16))
METHODS = ("auto", "gray world", "daylight", "true")
BEFORE = "grey px"
"""With --before: the grey pixels, ``--wb auto`` before issue 42 (a fifth method, 20 % more time)."""
MID = (0.03, 0.85)
"""The mid-tones: every channel within this range (linear sRGB)."""
SECTION = "bench_wb_auto"


def light_colour(light: tuple[float, float] | None) -> np.ndarray:
    """Linear sRGB colour of a light, largest channel 1; D65 (None) is (1, 1, 1)."""
    from clisp.scene.illuminant import light_srgb
    if light is None:
        return np.ones(3)
    w = light_srgb(np.array(light[0]), light[1])
    return w / w.max()


def mid_mean(image: np.ndarray) -> np.ndarray:
    """Mean linear sRGB of the pixels whose channels all lie within MID, shape (3,)."""
    pixels = image.reshape(-1, 3)
    keep = np.all((pixels >= MID[0]) & (pixels <= MID[1]), axis=1)
    return pixels[keep].astype(np.float64).mean(axis=0) if keep.any() else np.full(3, np.nan)


def angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle in degrees between two colours."""
    c = float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))))


def method_gains(raw, method: str, light: np.ndarray) -> str:
    """The ``wb`` option (clisp.process) of ``method`` for ``raw`` lit by ``light``."""
    from clisp.scene.illuminant import CameraLights
    from clisp.scene.white_balance import daylight_gains, gray_world_gains, grey_pixel_gains, reference_channel
    if method == "auto":
        return "auto"
    if method == "daylight":
        return "daylight"
    if method == "grey px":
        gains = grey_pixel_gains(raw.data, raw.cfa, raw.black_level, raw.white_level)[0]
    elif method == "gray world":
        gains = gray_world_gains(raw.data, raw.cfa, raw.black_level, raw.white_level)
    else:
        gains = CameraLights(raw.colour_matrix, daylight_gains(raw)).gains(light)
        gains = gains / gains[reference_channel(raw.cfa)]
    return ",".join(f"{g:.6g}" for g in gains)


def image_errors(scene: np.ndarray, cfa: str, gain: int, methods: tuple[str, ...] = METHODS) -> dict:
    """{light: {method: degrees}} for one scene on one camera; also ``method + SHARED``: the same
    angle over the reference's mid-tone pixels in both images (what white balance alone moves)."""
    import clisp
    image = clisp.process(clisp.simulate(scene, cfa, gain=gain, seed=1).raw, output="linear").reshape(-1, 3)
    reference = mid_mean(image)
    keep = np.all((image >= MID[0]) & (image <= MID[1]), axis=1)
    out: dict = {}
    for name, light in LIGHTS.items():
        w = light_colour(light)
        raw = clisp.simulate(scene * w, cfa, gain=gain, seed=1).raw
        out[name] = {}
        for m in methods:
            result = clisp.process(raw, output="linear", wb=method_gains(raw, m, w)).reshape(-1, 3)
            out[name][m] = angle(mid_mean(result), reference)
            out[name][m + SHARED] = angle(result[keep].astype(np.float64).mean(axis=0), image[keep].mean(axis=0))
    return out


SHARED = " (ref. mid-tones)"


def table(rows: list[dict], methods: tuple[str, ...] = METHODS) -> str:
    """Markdown: per set, light and camera, each method's mean / worst image (degrees)."""
    head = "| set | light | camera | n | " + " | ".join(methods) + " |"
    lines = [head, "|" + "---|" * (4 + len(methods))]
    keys = []
    for r in rows:
        key = (r["set"], r["light"], r["cfa"], r["gain"])
        if key not in keys:
            keys.append(key)
    for light in LIGHTS:
        for s in dict.fromkeys(k[0] for k in keys):
            picked = [r for r in rows if r["set"] == s and r["light"] == light]
            for cfa, gain in CAMERAS:
                these = [r for r in picked if r["cfa"] == cfa and r["gain"] == gain]
                if not these:
                    continue
                cells = []
                for m in methods:
                    v = np.array([r[m] for r in these])
                    cells.append(f"{np.nanmean(v):.2f} / {np.nanmax(v):.1f}")
                lines.append(f"| {s} | {light} | {cfa} gain {gain} | {len(these)} | " + " | ".join(cells) + " |")
            all_ = np.array([r[methods[0]] for r in picked])
            if len(all_):
                lines.append(f"| {s} | {light} | **all** | {len(all_)} | **{np.nanmean(all_):.2f} / {np.nanmax(all_):.1f}** |"
                             + " |" * (len(methods) - 1))
    return "\n".join(lines)


def run_sets(data: Path, subset: int | None, methods: tuple[str, ...] = METHODS) -> list[dict]:
    rows = []
    for set_name, scenes in (("Kodak", toolkit.kodak(data, subset)), ("McMaster", toolkit.mcmaster(data, subset))):
        for scene in scenes:
            t0 = time.perf_counter()
            for cfa, gain in CAMERAS:
                for light, errs in image_errors(scene.image, cfa, gain, methods).items():
                    rows.append({"set": set_name, "image": scene.name, "light": light, "cfa": cfa, "gain": gain, **errs})
            print(f"{set_name} {scene.name}: auto " + ", ".join(
                f"{r['light']} {r['cfa']}/{r['gain']} {r['auto']:.1f}" for r in rows[-12:])
                + f"  ({time.perf_counter() - t0:.1f} s)", flush=True)
    return rows


def run_scenes(seeds: int) -> list[dict]:
    import wb_scenes
    rows = []
    for kind in wb_scenes.KINDS:
        for seed in range(seeds):
            scene = wb_scenes.make_scene(kind, seed)
            for cfa, gain in CAMERAS:
                for light, errs in image_errors(scene, cfa, gain, ("auto", "gray world", "true")).items():
                    rows.append({"set": f"scenes: {kind}", "image": f"{kind}{seed}", "light": light, "cfa": cfa,
                                 "gain": gain, **errs})
        print(f"{kind}: auto mean {np.mean([r['auto'] for r in rows if r['set'].endswith(kind)]):.2f}", flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    toolkit.add_data_option(parser)
    parser.add_argument("--subset", type=int, default=None, help="the first N images of each set (default all)")
    parser.add_argument("--scenes", action="store_true", help="the tuning scenes (tools/wb_scenes.py) instead")
    parser.add_argument("--seeds", type=int, default=6, help="scenes per kind with --scenes (default 6)")
    parser.add_argument("--before", action="store_true", help="also the grey pixels (--wb auto before issue 42)")
    parser.add_argument("--results", type=Path, default=None, help="write the table into this file (docs/RESULTS.md)")
    parser.add_argument("--csv", type=Path, default=None, help="every image's errors as CSV")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    if args.scenes:
        rows, methods = run_scenes(args.seeds), ("auto", "gray world", "true")
    else:
        methods = METHODS[:1] + (BEFORE,) + METHODS[1:] if args.before else METHODS
        rows = run_sets(args.data, args.subset, methods)
    text = table(rows, methods) + "\n\nThe same over the D65 reference's mid-tone pixels in both images (the issue's metric takes " \
        "each image's own; a light that darkens a channel moves pixels across 0.03 and 0.85, which no white balance " \
        "undoes):\n\n" + table(rows, ("auto" + SHARED, "true" + SHARED))
    print(text)
    print(f"({len(rows)} images x lights x cameras, {time.perf_counter() - t0:.0f} s, {toolkit.cpu_model()})")
    if args.csv:
        toolkit.write_csv(rows, args.csv)
    if args.results:
        start, end = toolkit.markers(SECTION)
        body = (f"{start}\n### `--wb auto` on Kodak and McMaster under three lights (issue 42; "
                f"`python tools/bench_wb_auto.py --results docs/RESULTS.md`)\n\n"
                f"Angle (degrees) between the mean mid-tone colour (channels 0.03..0.85) of each white balance's "
                f"output and that of the D65-lit scene processed with `--wb camera`; mean / worst image. "
                f"`grey px` (with --before): `--wb auto` before issue 42; `true`: the light's own multipliers (the metric's floor). "
                f"Tree {toolkit.git_rev(toolkit.REPO, dirty=True)}.\n\n{text}\n{end}")
        toolkit.update_results(args.results, body, SECTION)
    return 0


if __name__ == "__main__":
    sys.exit(main())
