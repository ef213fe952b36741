"""--auto-exposure against rawpy's default postprocess (issue 31, item 1): mean luminance in EV.

    python tools/bench_auto_exposure.py [--data DIR] [--preset quality]

For every camera raw in ``--data``/raw: rawpy's default ``postprocess()`` (the camera's daylight
multipliers, not its as-shot white balance: rawpy's ``use_camera_wb`` is False by default;
LibRaw's auto-bright, BT.709 gamma 2.222/4.5, 8 bits), clisp's default (colorimetric), clisp with
``--auto-exposure``, and with ``--auto-exposure --wb daylight`` (rawpy's white balance), all to
16-bit TIFF from the command line. Each output is decoded with its
own curve to linear, and the mean luminance (Rec. 709 weights) compared: EV = log2(clisp / rawpy).
Printed: one row per raw, the EV clisp applied (from the output's description), and the EV
LibRaw's auto-bright applies to its own image (the same rule on LibRaw's colours: where the two EVs
agree and the luminances do not, the difference is white balance and colour, not exposure).
"""
from __future__ import annotations

import argparse
import math
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path

from clisp.io.imageio import read_image
from clisp.sim.colorimetry import srgb_decode

LUMA = np.array([0.2126, 0.7152, 0.0722])


def bt709_decode(v: np.ndarray) -> np.ndarray:
    """LibRaw's default output curve (gamma 1/2.222 with a linear toe of slope 4.5) undone."""
    return np.where(v < 0.081, v / 4.5, ((v + 0.099) / 1.099) ** (1 / 0.45))


def mean_luminance(linear: np.ndarray) -> float:
    return float((linear.reshape(-1, 3) @ LUMA).mean())


def rawpy_default(path: Path) -> np.ndarray:
    import rawpy
    with rawpy.imread(str(path)) as raw:
        return bt709_decode(raw.postprocess().astype(np.float64) / 255.0)


def libraw_auto_bright_ev(path: Path) -> float:
    """The EV LibRaw's auto-bright applies to its own image: its linear output without auto-bright,
    the level 1 % of the pixels exceed in the brightest channel (at most white), to white."""
    import rawpy
    with rawpy.imread(str(path)) as raw:
        img = raw.postprocess(no_auto_bright=True, gamma=(1, 1), output_bps=16).reshape(-1, 3) / 65535.0
    white = float(np.minimum(np.percentile(img, 99, axis=0), 1.0).max())
    return -math.log2(white) if white > 0 else 0.0


def clisp_tif(path: Path, out: Path, preset: str | None, *extra: str) -> tuple[np.ndarray, str]:
    cmd = [*toolkit.clisp_cmd("process", str(path), "-o", str(out), *(["--preset", preset] if preset else []), *extra)]
    run = subprocess.run(cmd, capture_output=True, text=True)
    if run.returncode != 0:
        raise SystemExit(f"{path.name}: {run.stderr.strip()}")
    import OpenImageIO as oiio
    note = oiio.ImageInput.open(str(out)).spec().getattribute("ImageDescription") or ""
    return srgb_decode(read_image(out)[0].astype(np.float64)), note.split("; ")[-1]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    toolkit.add_data_option(ap, "raw/")
    ap.add_argument("--preset", default=None)
    args = ap.parse_args(argv)
    raws = sorted(p for p in (args.data / "raw").glob("*") if p.is_file() and not p.name.startswith("."))
    if not raws:
        raise SystemExit(f"no camera raws in {args.data / 'raw'}")
    print(f"CPU: {toolkit.cpu_model()}; preset {args.preset or 'default'}")
    print("| raw | rawpy default Y | clisp default (EV vs rawpy) | clisp --auto-exposure (EV vs rawpy) | "
          "applied | --auto-exposure --wb daylight (EV vs rawpy) | applied | LibRaw's auto-bright on its own image |")
    print("|---|---:|---:|---:|---|---:|---|---:|")
    worst = worst_day = 0.0
    with tempfile.TemporaryDirectory(prefix="clisp-ae-") as tmp:
        for path in raws:
            ref = mean_luminance(rawpy_default(path))
            plain, _ = clisp_tif(path, Path(tmp) / "plain.tif", args.preset)
            auto, note = clisp_tif(path, Path(tmp) / "auto.tif", args.preset, "--auto-exposure")
            ev_plain = math.log2(mean_luminance(plain) / ref)
            ev_auto = math.log2(mean_luminance(auto) / ref)
            day, day_note = clisp_tif(path, Path(tmp) / "day.tif", args.preset, "--auto-exposure", "--wb", "daylight")
            ev_day = math.log2(mean_luminance(day) / ref)
            worst = max(worst, abs(ev_auto))
            worst_day = max(worst_day, abs(ev_day))
            print(f"| {path.name} | {ref:.3f} | {ev_plain:+.2f} | {ev_auto:+.2f} | {note} | {ev_day:+.2f} | "
                  f"{day_note} | {libraw_auto_bright_ev(path):+.2f} EV |", flush=True)
    print(f"largest |EV| with --auto-exposure: {worst:.2f}; with --auto-exposure --wb daylight: {worst_day:.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
