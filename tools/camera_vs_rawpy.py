"""Camera raws: clisp's linear EXR against rawpy's own linear postprocess (issue 4 check).

For each Bayer raw in DATA/raw, both pipelines run with the camera white balance (LibRaw's
fallback when the file has none), no auto-brightness, linear output (gamma 1), sRGB primaries,
the same orientation and size. rawpy's output is 16-bit and clipped, so the comparison uses pixels
that are unclipped in both. Exposure is matched by one global factor per image: the median over
those pixels of rawpy's luminance divided by ours. Reported: median and mean CIEDE2000 (D65 Lab
of linear sRGB), the exposure factor, and the share of pixels compared.

    python tools/camera_vs_rawpy.py [--data ../shared/data] [--demosaic bilinear] [--rawpy-demosaic LINEAR]

With --demosaic bilinear against LibRaw's LINEAR both sides interpolate alike, so the figure
isolates colour (black, white, WB, matrix, orientation); other pairs add demosaic differences,
which in noisy dark images dominate a per-pixel CIEDE2000. clisp's chroma denoiser is off unless
--denoise: LibRaw has none, and removing chroma noise is not a colour error.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path

import clisp
from clisp.metrics import linear_srgb_to_lab

LUMA = np.array([0.2126, 0.7152, 0.0722])


def rawpy_linear(path: Path, algorithm: str = "LINEAR") -> np.ndarray:
    """rawpy/LibRaw postprocess: camera WB, no auto-bright, linear 16-bit sRGB, as H x W x 3 in [0, 1].
    ``algorithm``: LibRaw's demosaic (rawpy.DemosaicAlgorithm name: LINEAR is bilinear, AHD its default)."""
    import rawpy
    with rawpy.imread(str(path)) as raw:
        rgb = raw.postprocess(use_camera_wb=True, no_auto_bright=True, gamma=(1, 1), output_bps=16,
                              output_color=rawpy.ColorSpace.sRGB, user_flip=None,
                              demosaic_algorithm=getattr(rawpy.DemosaicAlgorithm, algorithm))
    return rgb.astype(np.float64) / 65535.0


def compare(path: Path, demosaic: str | None, algorithm: str, denoise: bool) -> dict[str, float]:
    ours = clisp.process(path, demosaic=demosaic, denoise=None if denoise else False).astype(np.float64)
    theirs = rawpy_linear(path, algorithm)
    if ours.shape != theirs.shape:
        raise SystemExit(f"{path.name}: size differs: clisp {ours.shape} vs rawpy {theirs.shape}")
    y_ours, y_theirs = ours @ LUMA, theirs @ LUMA
    usable = ((theirs.max(axis=2) < 0.98) & (theirs.min(axis=2) > 0.002) & (y_ours > 1e-4))
    exposure = float(np.median(y_theirs[usable] / y_ours[usable]))
    matched = ours * exposure
    usable &= matched.max(axis=2) < 0.98
    lab_ours = linear_srgb_to_lab(np.clip(matched[usable], 0, None)[None])
    lab_theirs = linear_srgb_to_lab(theirs[usable][None])
    import colour
    de = colour.delta_E(lab_ours, lab_theirs, method="CIE 2000").ravel()
    return {"median": float(np.median(de)), "mean": float(de.mean()), "p95": float(np.percentile(de, 95)),
            "exposure": exposure, "share": float(usable.mean())}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    toolkit.add_data_option(parser, "raw/")
    parser.add_argument("--demosaic", default=None, help="clisp Bayer demosaic (default: the preset's)")
    parser.add_argument("--denoise", action="store_true",
                        help="keep clisp's chroma denoiser (LibRaw has none, so per-pixel CIEDE2000 then "
                             "also counts the chroma noise rawpy keeps); default off")
    parser.add_argument("--rawpy-demosaic", default="LINEAR",
                        help="LibRaw demosaic: LINEAR (bilinear, isolates colour from demosaic), AHD, ...")
    args = parser.parse_args(argv)
    files = sorted(p for p in (args.data / "raw").glob("*") if p.is_file())
    if not files:
        raise toolkit.missing_data(args.data / "raw", "raws")
    print(f"{'file':<44}{'median dE00':>12}{'mean':>8}{'p95':>8}{'exposure':>10}{'compared':>10}")
    worst = 0.0
    for path in files:
        r = compare(path, args.demosaic, args.rawpy_demosaic, args.denoise)
        worst = max(worst, r["median"])
        print(f"{path.name:<44}{r['median']:>12.2f}{r['mean']:>8.2f}{r['p95']:>8.2f}{r['exposure']:>10.3f}"
              f"{r['share']:>9.0%}")
    print(f"worst median CIEDE2000: {worst:.2f} (target < 2)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
