"""Where the LMS camera's error comes from: oracles that hand the pipeline one true component
(issue 28, "The LMS camera against the strongest Bayer").

For every scene and setting an LMS raw and a Bayer raw are simulated (clisp.sim.simulate, seed 0)
and demosaicked by the default pipelines' demosaics (LMS ``guided``, Bayer ``ri``) on the device.
Their white-balanced camera images are then split into a luminance and two chroma components and
one or more components are replaced by the truth (the scene through the optics, mapped to the
camera's white-balanced channels by the simulator's own matrix) before the same after-stages
(colour matrix, chroma denoiser with the default demosaic's noise table) finish them:

  LMS   Y = (L + M) / 2, C = (L - M) / 2, S        (R = 0.86 Y + 8.6 C + 0.14 S, paper eq. (1))
  Bayer G, R - G, B - G

  variant          LMS                          Bayer
  default          the demosaic's output        the demosaic's output
  true chroma      true C (Y, S estimated)      true R - G and B - G (G estimated)
  true S           true S (Y, C estimated)      -
  true luminance   true Y (C, S estimated)      true G (chroma differences estimated)
  only luminance   true C and S (Y estimated)   = true chroma

Scores: PSNR (dB) tone-mapped, 10 px border, as tools/bench_demosaic_quality.py. With noise the
true component is also noiseless, so the gain of an oracle there mixes demosaic error and noise;
the noiseless rows are the demosaic alone. Also printed: the camera-space RMS error of each
component (8-bit codes of the white-balanced camera signal) and the colour matrices' gains, which
say how much of a camera-space error reaches the output.

    python tools/lms_oracle.py [--data ../shared/data] [--sets kodak,mcmaster,deadleaves]
        [--subset N] [--dead-leaves 8] [--settings noiseless,4,16,64] [--csv FILE]
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path
from toolkit import BORDER
from bench_demosaic_quality import SETTINGS, clisp_camera_rgb, load_scenes, run_on_rgb, split_at_demosaic
from clisp.engine.runtime import get_runtime
from clisp.metrics import psnr
from clisp.pipeline import build_pipeline
from clisp.sim.simulate import inverse_isp_matrix, simulate



def true_camera(truth: np.ndarray, kind: str, gains: np.ndarray) -> np.ndarray:
    """White-balanced camera image (H x W x 3, the demosaic's units) of the optics-blurred linear
    sRGB truth: the simulator's sRGB -> raw matrix, then the raw's pass-1 gains."""
    a, _ = inverse_isp_matrix(kind)
    return np.einsum("ij,hwj->hwi", a, truth.astype(np.float64)) * np.asarray(gains, np.float64)


def lms_split(x: np.ndarray) -> dict[str, np.ndarray]:
    """Y = (L + M) / 2, C = (L - M) / 2, S of an H x W x 3 LMS image."""
    return {"Y": (x[..., 0] + x[..., 1]) / 2, "C": (x[..., 0] - x[..., 1]) / 2, "S": x[..., 2]}


def lms_join(y: np.ndarray, c: np.ndarray, s: np.ndarray) -> np.ndarray:
    return np.stack([y + c, y - c, s], axis=-1)


def lms_variants(est: np.ndarray, true: np.ndarray) -> dict[str, np.ndarray]:
    """The LMS oracles of the module doc."""
    e, t = lms_split(est), lms_split(true)
    return {"default": est,
            "true chroma": lms_join(e["Y"], t["C"], e["S"]),
            "true S": lms_join(e["Y"], e["C"], t["S"]),
            "true luminance": lms_join(t["Y"], e["C"], e["S"]),
            "only luminance": lms_join(e["Y"], t["C"], t["S"])}


def bayer_variants(est: np.ndarray, true: np.ndarray) -> dict[str, np.ndarray]:
    """The Bayer oracles of the module doc (G the luminance, R - G and B - G the chroma)."""
    g_e, g_t = est[..., 1:2], true[..., 1:2]
    return {"default": est,
            "true chroma": g_e + (true - g_t),
            "true luminance": g_t + (est - g_e)}


def component_rms(est: np.ndarray, true: np.ndarray, kind: str) -> dict[str, float]:
    """Camera-space RMS error (8-bit codes, 10 px border) of each component."""
    b = BORDER
    if kind == "lms":
        e, t = lms_split(est[b:-b, b:-b]), lms_split(true[b:-b, b:-b])
        return {k: 255.0 * float(np.sqrt(np.mean((e[k] - t[k]) ** 2))) for k in ("Y", "C", "S")}
    d = est[b:-b, b:-b] - true[b:-b, b:-b]
    return {"G": 255.0 * float(np.sqrt(np.mean(d[..., 1] ** 2))),
            "R-G": 255.0 * float(np.sqrt(np.mean((d[..., 0] - d[..., 1]) ** 2))),
            "B-G": 255.0 * float(np.sqrt(np.mean((d[..., 2] - d[..., 1]) ** 2)))}


def run_scene(scene: np.ndarray, setting: str, kind: str) -> tuple[dict[str, float], dict[str, float]]:
    """({variant: PSNR}, {component: camera RMS}) of one scene and setting for CFA kind."""
    gain, optics = SETTINGS[setting]
    sim = simulate(scene, kind, gain=gain, optics=optics, seed=0)
    before, demosaic, after = split_at_demosaic(build_pipeline(sim.raw, output="linear"))
    est = clisp_camera_rgb(sim.raw, before, demosaic).astype(np.float64)
    true = true_camera(sim.truth, kind, sim.raw.pass1_gains())
    variants = lms_variants(est, true) if kind == "lms" else bayer_variants(est, true)
    scores = {name: psnr(run_on_rgb(after, v.astype(np.float32)), sim.truth, border=BORDER)
              for name, v in variants.items()}
    return scores, component_rms(est, true, kind)


def matrix_gains() -> None:
    """Print, per CFA kind, the output (linear sRGB) change per unit change of each camera component."""
    from clisp.sim.colorimetry import camera_constants
    for kind, comps in (("lms", {"Y": (1, 1, 0), "C": (1, -1, 0), "S": (0, 0, 1)}),
                        ("bayer", {"G": (1, 1, 1), "R-G": (1, 0, 0), "B-G": (0, 0, 1)})):
        matrix, _ = camera_constants(kind)
        cells = []
        for name, v in comps.items():
            out = np.asarray(matrix, np.float64) @ np.asarray(v, np.float64)
            cells.append(f"{name} -> RGB ({', '.join(f'{x:+.2f}' for x in out)})")
        print(f"colour matrix gains, {kind}: " + "; ".join(cells))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    toolkit.add_data_option(parser)
    toolkit.add_scene_set_options(parser)
    parser.add_argument("--settings", default="noiseless,4,16,64")
    args = parser.parse_args(argv)
    settings = args.settings.split(",")
    for s in settings:
        if s not in SETTINGS:
            raise SystemExit(f"unknown setting {s!r}; choose from {', '.join(SETTINGS)}")
    scenes = load_scenes(args.data, args.sets.split(","), args.subset, args.dead_leaves, 512)
    print(f"device: {get_runtime().describe()}")
    matrix_gains()
    rows = []
    for set_name, items in scenes.items():
        for setting in settings:
            start = time.perf_counter()
            acc: dict[tuple[str, str], list[float]] = {}
            rms: dict[tuple[str, str], list[float]] = {}
            for _, scene in items:
                for kind in ("lms", "bayer"):
                    scores, comps = run_scene(scene, setting, kind)
                    for k, v in scores.items():
                        acc.setdefault((kind, k), []).append(v)
                    for k, v in comps.items():
                        rms.setdefault((kind, k), []).append(v)
            means = {k: float(np.mean(v)) for k, v in acc.items()}
            base_l, base_b = means[("lms", "default")], means[("bayer", "default")]
            print(f"\n{set_name} ({len(items)}), {setting} [{time.perf_counter() - start:.0f} s]: "
                  f"LMS default {base_l:.2f}, Bayer RI {base_b:.2f} (LMS - RI {base_l - base_b:+.2f})")
            for (kind, name), value in means.items():
                gap = value - base_b if kind == "lms" else value - base_l
                vs = "RI" if kind == "lms" else "LMS default"
                print(f"  {kind:5s} {name:15s} {value:7.2f}  ({value - means[(kind, 'default')]:+.2f} over its default, "
                      f"{gap:+.2f} against {vs})")
                rows.append({"set": set_name, "setting": setting, "cfa": kind, "variant": name,
                             "images": len(items), "psnr_db": round(value, 3)})
            print("  camera RMS error (8-bit codes): " + ", ".join(
                f"{kind} {comp} {np.mean(v):.2f}" for (kind, comp), v in rms.items()))
            for (kind, comp), v in rms.items():
                rows.append({"set": set_name, "setting": setting, "cfa": kind, "variant": f"rms {comp}",
                             "images": len(items), "psnr_db": round(float(np.mean(v)), 3)})
    if args.csv:
        toolkit.write_csv(rows, args.csv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
