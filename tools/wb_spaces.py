"""Which space a known light is best undone in, with spectral lights (issue 42, the metric's floor).

    python tools/wb_spaces.py [--data DIR] [--subset 3] [--step 4]

Issue 42 judges white balance ``auto`` on scenes lit by multiplying their linear sRGB by the light's
colour: a light that is a diagonal in linear sRGB, which the pipeline's white balance (a diagonal
on the raw, in camera space, before the D65 colour matrix) cannot undo exactly even when it knows
the light (the ``true`` column of ``tools/bench_wb_auto.py``). Real lights are spectra. Here each
Kodak image (every ``--subset``-th, every ``--step``-th pixel) becomes reflectance spectra (Mallett
and Yuksel 2019, clisp.sim.spectral.srgb_to_reflectance), lit by CIE illuminant A (tungsten), CIE
daylight at 4000 K and at 8000 K, and seen by the LMS and the Bayer camera (clisp.sim.spectral; no
mosaic, no noise). The light is known exactly (its white's camera response), and undone three ways:

* ``camera``: the light's own multipliers on the raw, then the camera's D65 matrix (clisp's pass 1);
* ``srgb``: the D65 multipliers and matrix, then a diagonal in linear sRGB that makes the light's
  white grey (what the issue's metric rewards: its lights are such diagonals);
* ``bradford``: the D65 multipliers and matrix, then the Bradford adaptation in XYZ from the
  light's white to D65's.

Each output, scaled to the truth's mean level, is compared with the same reflectances under D65
(CIE 1931, clisp.sim.spectral.true_srgb): mean CIEDE2000 over the pixels and the issue's angle
between the mean colours of the mid-tones (the truth's channels within 0.03..0.85). Mallett's
spectra span three dimensions, so metamerism is understated: a bound on what each space does for
smooth spectra, not a camera test. A benchmark, not a test.
"""
from __future__ import annotations

import argparse
import sys

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path
from colour_natural_spectra import Camera, delta_e00

LIGHTS = ("A", "4000 K", "8000 K")
SPACES = ("camera", "srgb", "bradford")
MID = (0.03, 0.85)
BRADFORD = np.array([[0.8951, 0.2664, -0.1614], [-0.7502, 1.7135, 0.0367], [0.0389, -0.0685, 1.0296]])
"""Bradford's cone response matrix (XYZ -> sharpened RGB)."""


def light_spectrum(name: str) -> np.ndarray:
    """Relative spectral power at clisp.sim.spectral.WAVELENGTHS of CIE A or a CIE daylight ('T K')."""
    from clisp.sim.spectral import _colour, _resample
    colour = _colour()
    if name == "A":
        return _resample(colour.SDS_ILLUMINANTS["A"])
    kelvin = float(name.split()[0]) * 1.4388 / 1.4380          # the daylight formula's old c2 scale
    return _resample(colour.sd_CIE_illuminant_D_series(colour.temperature.CCT_to_xy_CIE_D(kelvin)))


def undone(raw: np.ndarray, white: np.ndarray, camera: Camera) -> dict[str, np.ndarray]:
    """Linear sRGB (N, 3) of camera responses ``raw`` (N, 3) under a light whose white reads
    ``white`` (3,), the light undone in each of SPACES (module docstring)."""
    from clisp.sim.colorimetry import XYZ_TO_SRGB
    srgb_to_xyz = np.linalg.inv(XYZ_TO_SRGB)
    outs = {"camera": (raw * (white[camera.ref] / white)) @ camera.matrix.T}
    base = (raw * camera.wb) @ camera.matrix.T
    w = (white * camera.wb) @ camera.matrix.T
    outs["srgb"] = base / (w / w[1])
    adapt = np.linalg.inv(BRADFORD) @ np.diag((BRADFORD @ (np.ones(3) @ srgb_to_xyz.T)) / (BRADFORD @ (w @ srgb_to_xyz.T))) @ BRADFORD
    outs["bradford"] = base @ (XYZ_TO_SRGB @ adapt @ srgb_to_xyz).T
    return outs


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)), -1.0, 1.0))))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    toolkit.add_data_option(parser, "kodak/")
    parser.add_argument("--subset", type=int, default=3, help="every N-th Kodak image (default 3)")
    parser.add_argument("--step", type=int, default=4, help="every N-th pixel row and column (default 4)")
    args = parser.parse_args(argv)
    from clisp.sim.spectral import WAVELENGTHS, illuminant_d65, srgb_to_reflectance, true_srgb
    cameras = {kind: Camera.of(kind) for kind in ("lms", "bayer")}
    scores: dict[tuple[str, str, str], list[tuple[float, float]]] = {}
    scenes = toolkit.kodak(args.data)[::args.subset]
    for scene in scenes:
        refl = srgb_to_reflectance(scene.image[::args.step, ::args.step].reshape(-1, 3))
        truth = true_srgb(refl)
        mid = np.all((truth >= MID[0]) & (truth <= MID[1]), axis=1)
        for name in LIGHTS:
            power = light_spectrum(name)
            for kind, camera in cameras.items():
                scale = float((illuminant_d65() @ camera.sens).max())
                raw = (refl * power) @ camera.sens / scale
                white = (np.ones(WAVELENGTHS.size) * power) @ camera.sens / scale
                for space, out in undone(raw, white, camera).items():
                    out = out * (truth[mid].mean() / out[mid].mean())
                    scores.setdefault((name, kind, space), []).append(
                        (float(delta_e00(out, truth).mean()), _angle(out[mid].mean(axis=0), truth[mid].mean(axis=0))))
    print(f"Kodak: {len(scenes)} images (--subset {args.subset}), every {args.step}-th pixel row and column; "
          "the light known exactly")
    print("| light | camera | " + " | ".join(f"{s}: dE00 / angle mean / worst" for s in SPACES) + " |")
    print("|---|---|" + "---:|" * len(SPACES))
    for name in LIGHTS:
        for kind in cameras:
            cells = []
            for space in SPACES:
                v = np.array(scores[(name, kind, space)])
                cells.append(f"{v[:, 0].mean():.2f} / {v[:, 1].mean():.2f} / {v[:, 1].max():.2f}")
            print(f"| {name} | {kind} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
