"""Colour accuracy on natural spectra (issue 32, item 3): the Kodak images as reflectance spectra,
seen by the LMS camera (Stockman-Sharpe cones) and the Bayer camera (Nikon D100 QE), each through
its colour matrix fitted on the ColorChecker only.

Per Kodak image (all 24, full size):

1. the 8-bit sRGB file decoded to linear sRGB (toolkit.load_scene) and every pixel upsampled to a
   reflectance spectrum by Mallett & Yuksel (2019), "Spectral Primary Decomposition for Rendering
   with sRGB Reflectance", EGSR 2019 (clisp.sim.spectral.srgb_to_reflectance: colour-science's
   RGB_to_sd_Mallett2019 basis). Chosen over Jakob & Hanika (2019) because it is a fixed linear
   combination of three basis spectra (vectorised over all pixels, no optimisation), and
   colour-science ships no precomputed Jakob LUT (generating one at a useful size costs minutes);
2. lit by D65 and integrated with each camera's sensitivities exactly as clisp.sim.spectral does for
   the ColorChecker (photon counting, brightest channel of a perfect white = 1; 400..700 nm, 10 nm);
3. white-balanced on the perfect white and mapped to linear sRGB by the camera's matrix, fitted by
   clisp.sim.spectral.spectral_colorchecker on the 24 ColorChecker patches (never on these images);
4. compared per pixel with the true colour: the same reflectance under D65 through the CIE 1931
   2-degree observer to XYZ, then linear sRGB (clisp.sim.spectral.true_srgb), both to CIE Lab with
   the reference white of clisp.metrics.linear_srgb_to_lab (the XYZ of sRGB (1, 1, 1): D65,
   x, y = 0.3127, 0.3290), after clipping negative values to 0 (as patch_delta_e does), CIEDE2000.

Two paths, both at no noise and at analog gain 8 (clisp.sim.noise.NoiseModel, seed 0):

* direct (demosaic-free): every pixel has all three camera responses; at gain 8 each response goes
  through NoiseModel.sample (Poisson shot noise, 1.5 e- read noise, 10-bit ADC, clipping), exactly as
  simulate_spectral digitises the ColorChecker's mosaic, then back to normalised raw. No optics, no
  mosaic, no denoise: noiseless it is the camera's colorimetric error alone; at gain 8 it is that
  plus the raw noise as each matrix amplifies it, per pixel.
* pipeline (``--pipeline``, on by default): the camera-response image goes through
  clisp.sim.spectral.simulate_responses (Airy optics, CFA mosaic, noise) and the clisp pipeline as
  tools/reproduce_paper.py runs it (the LMS default demosaic / DLMMSE, chroma denoise on, fitted
  colour matrix); scored against the optics-blurred truth, 10 px border dropped. This is the
  ColorChecker figure's path (docs/RESULTS.md, "Spectral ColorChecker colour error").

Per image: mean and 95th percentile of the per-pixel CIEDE2000; overall: the same over the pixels of
all images pooled. A ColorChecker row (the 24 patches through the direct path, the fit's own
residual) comes first for scale. Smooth upsampled spectra understate metamerism (Mallett's spectra
span only three dimensions, so every camera's error is one fixed 3 x 3 map of the input colour).

    python tools/colour_natural_spectra.py --data ../shared/data [--csv docs/colour_natural_spectra.csv]
"""
from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path

from clisp.metrics import linear_srgb_to_lab
from clisp.sim.noise import NoiseModel
from clisp.sim.spectral import (WAVELENGTHS, _colour, fit_colour_matrix, illuminant_d65, reflectances,
                                sensitivities, spectral_colorchecker, srgb_to_reflectance, true_srgb)

KINDS = ("lms", "bayer")
GAIN = 8.0
"""The noisy level of the table (the issue's gain 8)."""
CHUNK = 1 << 16
"""Pixels upsampled at a time (a chunk's spectra: CHUNK x 31 float64, 16 MiB)."""


@dataclass(frozen=True)
class Camera:
    """A camera as clisp.sim.spectral models one: sensitivities per photon at WAVELENGTHS, shape
    (n_lambda, 3), and the channel its white balance holds at 1 (L for LMS, G for Bayer).
    wb and matrix are fitted on the ColorChecker (:meth:`fitted`)."""

    name: str
    sens: np.ndarray
    ref: int
    wb: np.ndarray
    matrix: np.ndarray

    @classmethod
    def fitted(cls, name: str, sens: np.ndarray, ref: int) -> "Camera":
        """White balance from the perfect white and the white-preserving matrix fitted on the 24
        ColorChecker patches (colour-science's N Ohta), as clisp.sim.spectral.spectral_colorchecker."""
        probe = cls(name, sens, ref, np.ones(3), np.eye(3))
        white = probe.responses(np.ones((1, WAVELENGTHS.size)))[0]
        wb = white[ref] / white
        chart = reflectances("colour")
        matrix = fit_colour_matrix(probe.responses(chart) * wb, true_srgb(chart))
        return cls(name, sens, ref, wb, matrix)

    @classmethod
    def of(cls, kind: str) -> "Camera":
        """The LMS or Bayer camera of clisp.sim.spectral."""
        return cls.fitted(kind, sensitivities(kind), 0 if kind == "lms" else 1)

    def responses(self, refl: np.ndarray) -> np.ndarray:
        """Responses (N, 3) of reflectances (N, n_lambda) under D65, brightest white channel = 1
        (clisp.sim.spectral.camera_responses with these sensitivities)."""
        e = illuminant_d65()
        return (refl * e) @ self.sens / (e @ self.sens).max()

    def to_srgb(self, raw: np.ndarray) -> np.ndarray:
        """Normalised raw responses (..., 3) -> linear sRGB: white balance, then the matrix."""
        return (raw * self.wb) @ self.matrix.T


def cie_camera() -> Camera:
    """A camera whose sensitivities are the CIE 1931 observer's (x-bar, y-bar, z-bar, used as they
    are by :meth:`Camera.responses`), so that its responses are XYZ up to a scale: fitted like the
    others, it must score ~0 (the harness's own check). Its white balance holds Z (the brightest
    channel of white) at 1, so that the white-balanced white is (1, 1, 1) as for LMS and Bayer."""
    from clisp.sim.spectral import _resample
    cmfs = _resample(_colour().MSDS_CMFS["CIE 1931 2 Degree Standard Observer"])
    return Camera.fitted("cie1931", cmfs, int(np.argmax(illuminant_d65() @ cmfs)))


def delta_e00(output: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per-pixel CIEDE2000 of linear sRGB (..., 3) against linear sRGB (..., 3), negatives clipped
    to 0 first; Lab white: clisp.metrics.linear_srgb_to_lab's (D65). Shape (...)."""
    lab_out = linear_srgb_to_lab(np.clip(output, 0.0, None))
    lab_truth = linear_srgb_to_lab(np.clip(truth, 0.0, None))
    return np.asarray(_colour().delta_E(lab_out, lab_truth, method="CIE 2000"))


def spectral_image(rgb: np.ndarray, cameras: list[Camera]) -> tuple[list[np.ndarray], np.ndarray]:
    """Upsample linear sRGB (H, W, 3) by Mallett 2019 and return each camera's responses (H, W, 3)
    and the true linear sRGB (H, W, 3) of the spectra under D65 (CIE 1931)."""
    flat = rgb.reshape(-1, 3)
    cams = [np.empty_like(flat, dtype=np.float64) for _ in cameras]
    truth = np.empty_like(flat, dtype=np.float64)
    for start in range(0, flat.shape[0], CHUNK):
        refl = srgb_to_reflectance(flat[start:start + CHUNK])
        truth[start:start + CHUNK] = true_srgb(refl)
        for cam, camera in zip(cams, cameras):
            cam[start:start + CHUNK] = camera.responses(refl)
    return [c.reshape(rgb.shape) for c in cams], truth.reshape(rgb.shape)


def direct(responses: np.ndarray, camera: Camera, gain: float | None, seed: int = 0,
           noise: NoiseModel | None = None) -> np.ndarray:
    """The demosaic-free path: responses (..., 3), noiseless or digitised at ``gain`` by the
    simulator's noise model (every pixel all three channels), to linear sRGB by the camera's fit."""
    if gain is None:
        return camera.to_srgb(responses)
    noise = noise or NoiseModel()
    dn = noise.sample(responses, gain, np.random.default_rng(seed)).astype(np.float64)
    return camera.to_srgb((dn - float(noise.black_level)) / noise.range_dn)


def stats(de: np.ndarray) -> tuple[float, float]:
    """(mean, 95th percentile) of CIEDE2000 values."""
    return float(np.mean(de)), float(np.percentile(de, 95))


class PipelineRunner:
    """The full clisp path (Airy optics, mosaic, noise, demosaic, chroma denoise, fitted matrix), as
    tools/reproduce_paper.py runs it; built only when asked (it needs OpenCL)."""

    def __init__(self) -> None:
        import paper_tables as pt
        from clisp.modules.chroma_denoise.stage import ChromaDenoiseParams
        self.runner = pt.Runner(ChromaDenoiseParams(), None)
        bayer = "dlmmse" if pt.demosaic_factory("dlmmse") is not None else "bilinear"
        lms = next(n for n in pt.LMS_PREFERENCE if n in pt.DEMOSAICS)   # as tools/reproduce_paper.py
        self.demosaic = {"lms": lms, "bayer": bayer}

    def __call__(self, responses: np.ndarray, truth: np.ndarray, kind: str, gain: float | None) -> np.ndarray:
        """Per-pixel CIEDE2000 (H - 2 BORDER, W - 2 BORDER) of the pipeline's output."""
        from clisp.sim.spectral import simulate_responses
        chart = spectral_colorchecker(kind)
        sim = simulate_responses(responses, truth, kind, chart.wb, chart.matrix, gain=gain, seed=0,
                                 scene="Kodak, Mallett 2019 spectra (D65)")
        out = self.runner.run(sim.raw, self.demosaic[kind], True)
        b = toolkit.BORDER
        return delta_e00(out[b:-b, b:-b], sim.truth[b:-b, b:-b])


def chart_row(cameras: dict[str, Camera]) -> dict[str, object]:
    """The 24 ColorChecker patches through the direct path, noiseless: each fit's own residual."""
    refl = reflectances("colour")
    truth = true_srgb(refl)
    row: dict[str, object] = {"image": "ColorChecker (fit set, 24 patches)"}
    for kind, camera in cameras.items():
        mean, p95 = stats(delta_e00(direct(camera.responses(refl), camera, None), truth))
        row[f"{kind}_direct_none_mean"], row[f"{kind}_direct_none_p95"] = mean, p95
    return row


LEVELS: list[tuple[str, float | None]] = [("none", None), ("g8", GAIN)]


def columns(paths: list[str]) -> list[str]:
    """CSV columns after 'image': {kind}_{path}_{level}_{mean|p95}."""
    return [f"{kind}_{path}_{level}_{stat}" for path in paths for level, _ in LEVELS for kind in KINDS
            for stat in ("mean", "p95")]


def run(data: Path, subset: int | None, use_pipeline: bool) -> tuple[list[dict[str, object]], list[str]]:
    """Rows per Kodak image plus the pooled 'all' row; and the paths measured."""
    paths = ["direct"] + (["pipeline"] if use_pipeline else [])
    cameras = {kind: Camera.of(kind) for kind in KINDS}
    for kind, camera in cameras.items():   # the camera here is the one clisp.sim.spectral fits
        chart = spectral_colorchecker(kind)
        assert np.allclose(camera.wb, chart.wb) and np.allclose(camera.matrix, chart.matrix)
    pipe = PipelineRunner() if use_pipeline else None
    pooled: dict[str, list[np.ndarray]] = {}
    rows: list[dict[str, object]] = []
    for scene in toolkit.kodak(data, subset):
        t = time.perf_counter()
        responses, truth = spectral_image(scene.image, list(cameras.values()))
        row: dict[str, object] = {"image": scene.name}
        for kind, resp in zip(KINDS, responses):
            for level, gain in LEVELS:
                results = {"direct": delta_e00(direct(resp, cameras[kind], gain), truth)}
                if pipe is not None:
                    results["pipeline"] = pipe(resp.astype(np.float32), truth, kind, gain)
                for path, de in results.items():
                    key = f"{kind}_{path}_{level}"
                    row[f"{key}_mean"], row[f"{key}_p95"] = stats(de)
                    # pooled p95 from a fixed 1-in-16 sample (all images weigh the same), mean exact
                    pooled.setdefault(key, []).append(de.ravel()[::16])
                    pooled.setdefault(key + "#mean", []).append(np.array([de.mean()]))
        rows.append(row)
        print(f"{scene.name}: {time.perf_counter() - t:.1f} s", file=sys.stderr, flush=True)
    overall: dict[str, object] = {"image": f"all {len(rows)} images"}
    for key in {k for k in pooled if not k.endswith("#mean")}:
        overall[f"{key}_mean"] = float(np.mean(np.concatenate(pooled[key + "#mean"])))
        overall[f"{key}_p95"] = float(np.percentile(np.concatenate(pooled[key]), 95))
    return [chart_row(cameras)] + rows + [overall], paths


def markdown(rows: list[dict[str, object]], paths: list[str]) -> str:
    """The table: one row per image, cells 'mean / p95' for LMS and Bayer per path and level."""
    head = ["image"]
    for path in paths:
        for level, _ in LEVELS:
            for kind in KINDS:
                head.append(f"{path}, {'no noise' if level == 'none' else 'gain 8'}: {kind.upper() if kind == 'lms' else 'Bayer'}")
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        cells = [str(row["image"])]
        for path in paths:
            for level, _ in LEVELS:
                for kind in KINDS:
                    key = f"{kind}_{path}_{level}"
                    cells.append(f"{row[key + '_mean']:.2f} / {row[key + '_p95']:.2f}" if key + "_mean" in row else "")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    toolkit.add_data_option(parser, holding="kodak/")
    parser.add_argument("--subset", type=int, default=None, help="first N Kodak images only (default: all 24)")
    parser.add_argument("--no-pipeline", action="store_true",
                        help="only the demosaic-free path (no OpenCL; the full pipeline path is skipped)")
    parser.add_argument("--csv", type=Path, default=None, help="also write the rows to this CSV")
    args = parser.parse_args(argv)
    t = time.perf_counter()
    rows, paths = run(args.data, args.subset, not args.no_pipeline)
    print("CIEDE2000 per pixel, mean / 95th percentile; Mallett 2019 spectra, D65, matrices fitted on the "
          "ColorChecker only")
    print()
    print(markdown(rows, paths))
    print()
    print(f"{time.perf_counter() - t:.0f} s on {toolkit.cpu_model()}")
    if args.csv:
        toolkit.write_csv([{"image": r["image"], **{c: (f"{r[c]:.4f}" if c in r else "") for c in columns(paths)}}
                           for r in rows], args.csv)
    return 0


if __name__ == "__main__":
    sys.exit(main())
