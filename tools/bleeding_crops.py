"""Crops of the bleeding chart at gain 64, before and after issue 17's changes (docs/bleeding/).

    python tools/bleeding_crops.py [--out docs/bleeding] [--gain 64] [--seed 0]

Row 3 of tools/bench_bleeding.py's chart (blue, green, red, yellow, magenta and cyan patches on
mid-grey: rows 248-359, the full 720 px width), simulated at ``--gain`` (seed ``--seed``), preset
quality, written as sRGB 8-bit PNGs (Pillow):

    truth.png              the clean, optics-blurred scene
    bayer_g64_before.png   Bayer as before issue 17: chroma denoiser without the range cap and
                           with a range weight per plane (chroma_range_cap=None, range_joint=0)
    bayer_g64_after.png    Bayer, today's defaults (the cap and the joint range weight)
    lms_g64_before.png     LMS as before issue 17: guided demosaic chroma radius 3, no joint range
                           weight in the denoiser (range_joint=0)
    lms_g64_after.png      LMS, today's defaults (chroma radius 2, the joint range weight)

The "before" settings are passed explicitly, so the crops can be remade from any later checkout.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path

from bench_bleeding import scene
import clisp.pipeline as pipeline_module
from clisp.sim.colorimetry import srgb_encode
from clisp.sim.simulate import simulate
from clisp.modules.chroma_denoise.stage import ChromaDenoiseParams
from clisp.modules.demosaic_lms_guided.stage import DemosaicLMSGuided, LMSGuidedParams

ROWS = slice(248, 360)


class GuidedRadius3:
    """The guided LMS demosaic with its chroma radius before issue 17 (3), for build_pipeline."""

    cfa_kinds = DemosaicLMSGuided.cfa_kinds

    @staticmethod
    def for_raw(raw):
        return DemosaicLMSGuided.for_raw(raw, LMSGuidedParams(chroma_radius=3))


def save_crop(path: Path, image: np.ndarray) -> None:
    """Rows ROWS of a linear sRGB image, sRGB-encoded, as an 8-bit PNG (Pillow)."""
    from PIL import Image
    codes = np.round(srgb_encode(np.clip(image[ROWS], 0.0, 1.0).astype(np.float32)) * 255.0)
    Image.fromarray(codes.astype(np.uint8)).save(path)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    toolkit.add_out_option(ap, "docs/bleeding", "the crops")
    ap.add_argument("--gain", type=float, default=64)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    pipeline_module.DEMOSAICS["guided-r3"] = GuidedRadius3
    image, _, _ = scene()
    tag = f"g{args.gain:g}"
    runs = {
        f"bayer_{tag}_before": ("bayer", {"denoise": ChromaDenoiseParams(chroma_range_cap=None, range_joint=0.0)}),
        f"bayer_{tag}_after": ("bayer", {}),
        f"lms_{tag}_before": ("lms", {"demosaic": "guided-r3", "denoise": ChromaDenoiseParams(range_joint=0.0)}),
        f"lms_{tag}_after": ("lms", {}),
    }
    truth = None
    for name, (cfa, options) in runs.items():
        sim = simulate(image, cfa=cfa, gain=args.gain, seed=args.seed)
        truth = sim.truth
        pipe = pipeline_module.build_pipeline(sim.raw, preset="quality", skip=True, **options)
        save_crop(args.out / f"{name}.png", pipe.run(sim.raw.data))
        print(f"{name}: {pipe.describe()}")
    save_crop(args.out / "truth.png", truth)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
