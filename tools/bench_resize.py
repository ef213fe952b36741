"""Aliasing of ``--resize`` on a zone plate (issue 31, item 3): ours against nearest, bilinear and Pillow's LANCZOS.

    python tools/bench_resize.py [--size 6000x4000] [--long-edge 2048] [--e2e-size WxH] [--e2e-long-edge N]
                                 [--no-e2e] [--work DIR] [--figure docs/resize/zone_plate_crops.png]

The zone plate (made in code, no data needed) is grey, in linear light, MEAN + AMPLITUDE cos(k r^2), r
from the image's centre, k such that the local frequency k r / pi (cycles per input pixel) reaches
the input's Nyquist (0.5) at the corners. The ideal output is that pattern band-limited to the
output grid's Nyquist and rendered at the output's pixel centres, analytically: the cosine where
its local frequency (fx, fy) lies inside the output's Nyquist square |fx| < 0.5 s_x, |fy| < 0.5 s_y
(s = output / input size), the mean outside. Figures, as the RMS of (output - ideal) relative to
the pattern's RMS (AMPLITUDE / sqrt 2), in dB, over the output less a border of 3 output pixels
(the edges are another question), in bands of q = max(|fx| / (0.5 s_x), |fy| / (0.5 s_y)):

* **alias** q >= STOP (1.25): beyond any filter's transition band, where an ideal output is flat;
  what is left there is aliasing (the pattern folded back below Nyquist) and leakage;
* **alias, input < 0.7 Nyq**: the same, less the corners, where the pattern is past INPUT_HIGH (0.7)
  of the input's own Nyquist (end to end, a Bayer demosaic's false colour is there, before any resize);
* **transition** 1 <= q < STOP: just past Nyquist, where a realisable filter still passes part of it;
* **passband** q < PASS (0.8), and q < 0.5: detail the output can hold; the error is blur (and ringing).

The threshold is ALIAS_TARGET_DB (-30 dB, printed as met / not met): an alias residual 30 dB below
the pattern is an aliased sinusoid of 3 % of its amplitude: 0.0047 in linear light, about one 8-bit
sRGB code at the mean (0.85 codes RMS), at the limit of what 8-bit output can show; nearest and plain
bilinear interpolation leave about 0 dB (the pattern folded back whole).

Resamplers, all in the same run: ours (clisp.modules.resize on the OpenCL device, what ``clisp
process --resize`` runs), nearest (the input pixel under each output centre), bilinear (interpolation
at the output centres, no low-pass: what a GPU texture fetch or cv2.INTER_LINEAR does) and Pillow's
``Image.resize(LANCZOS, reducing_gap=None)`` on a float ('F') image. End to end: ``clisp simulate``
of the zone plate (Bayer, --noiseless, --optics none) then ``clisp process --resize`` to linear EXR,
the mean of its channels (luminance) and each channel (the worst per band: false colour counts)
against the grey ideal; beside it, the same figures of the full-size output resized by ours
afterwards: where they are equal, what remains is the pipeline's (the demosaic's errors near the
input's Nyquist, folded before any resizer sees them). ``seconds``: one run's wall time, on a shared
machine (ours: three channels, with the copy to them; the others one). ``--figure``: a PNG (sRGB,
each output pixel 2x2) of the zone plate's corner and of a crop across the output's Nyquist:
ideal, ours, nearest.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path

MEAN, AMPLITUDE = 0.25, 0.15
"""The zone plate's mean and amplitude in linear light (0.10 .. 0.40: grey, moderate contrast)."""
PASS, STOP = 0.8, 1.25
"""Band edges in units of the output's Nyquist (see the module docstring)."""
ALIAS_TARGET_DB = -30.0
"""Largest alias residual (dB relative to the pattern) the tool reports as met."""
BORDER = 3
"""Output pixels left out at each edge (the Lanczos-3 kernel's reach, in output pixels)."""
INPUT_HIGH = 0.7
"""Column 'alias, input < 0.7 Nyq': the alias band without the corners, where the pattern is within
30 % of the input's Nyquist (a Bayer demosaic's false colour lives there, before any resize)."""


def zone_plate(height: int, width: int, mean: float = MEAN, amplitude: float = AMPLITUDE) -> np.ndarray:
    """height x width float64 linear zone plate (see the module docstring), one channel."""
    y = np.arange(height, dtype=np.float64)[:, None] + 0.5 - height / 2.0
    x = np.arange(width, dtype=np.float64)[None, :] + 0.5 - width / 2.0
    return mean + amplitude * np.cos(_chirp(height, width) * (x * x + y * y))


def _chirp(height: int, width: int) -> float:
    """k of cos(k r^2): local frequency k r / pi = 0.5 cycles/px at the corners."""
    return np.pi / (2.0 * np.hypot(height / 2.0, width / 2.0))


def output_grid(in_hw: tuple[int, int],
                out_hw: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(ideal output, band q, inner mask, input band) on the output grid, out_h x out_w each (see
    the module docstring): the pattern at the output pixels' centres where its local frequency lies
    inside the output's Nyquist square, the mean elsewhere; q = the local frequency in units of
    that Nyquist; the mask leaves BORDER pixels out at each edge; the input band = the local
    frequency in units of the input's Nyquist, max(|fx|, |fy|) / 0.5."""
    (h, w), (oh, ow) = in_hw, out_hw
    y = (np.arange(oh, dtype=np.float64)[:, None] + 0.5) * h / oh - h / 2.0
    x = (np.arange(ow, dtype=np.float64)[None, :] + 0.5) * w / ow - w / 2.0
    k = _chirp(h, w)
    fy, fx = np.abs(k * y / np.pi), np.abs(k * x / np.pi)         # cycles per input pixel
    q = np.maximum(fx / (0.5 * ow / w), fy / (0.5 * oh / h))
    ideal = np.where(q < 1.0, MEAN + AMPLITUDE * np.cos(k * (x * x + y * y)), MEAN)
    inner = np.zeros((oh, ow), dtype=bool)
    inner[BORDER:oh - BORDER, BORDER:ow - BORDER] = True
    return ideal, q, inner, np.maximum(fx, fy) / 0.5


def figures(out: np.ndarray, in_hw: tuple[int, int]) -> dict[str, float]:
    """{'alias', 'alias_mid' (alias where the input's own frequency is below INPUT_HIGH of its
    Nyquist), 'transition', 'passband', 'low' (q < 0.5)}: RMS(out - ideal) in each band, dB
    relative to the pattern's RMS; ``out`` an out_h x out_w linear image of the zone plate."""
    ideal, q, inner, input_band = output_grid(in_hw, out.shape[:2])
    error = out.astype(np.float64) - ideal
    pattern = AMPLITUDE ** 2 / 2.0
    bands = {"alias": q >= STOP, "alias_mid": (q >= STOP) & (input_band < INPUT_HIGH),
             "transition": (q >= 1.0) & (q < STOP), "passband": q < PASS, "low": q < 0.5}
    with np.errstate(divide="ignore"):                  # -inf dB: exact (nearest at a whole-number scale)
        return {name: float(10 * np.log10(np.mean(error[mask & inner] ** 2) / pattern))
                for name, mask in bands.items()}


# ------------------------------------------------------------------------------------------ resamplers

def nearest(image: np.ndarray, oh: int, ow: int) -> np.ndarray:
    """The input pixel under each output pixel's centre."""
    h, w = image.shape[:2]
    ys = np.minimum(((np.arange(oh) + 0.5) * h / oh).astype(int), h - 1)
    xs = np.minimum(((np.arange(ow) + 0.5) * w / ow).astype(int), w - 1)
    return image[ys[:, None], xs[None, :]]


def bilinear(image: np.ndarray, oh: int, ow: int) -> np.ndarray:
    """Bilinear interpolation at the output pixels' centres, no low-pass (edges clamped)."""
    h, w = image.shape[:2]

    def axis(n_in: int, n_out: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        c = np.clip((np.arange(n_out) + 0.5) * n_in / n_out - 0.5, 0, n_in - 1)
        i0 = np.minimum(np.floor(c).astype(int), n_in - 2)
        return i0, i0 + 1, c - i0
    y0, y1, fy = axis(h, oh)
    x0, x1, fx = axis(w, ow)
    top = image[y0][:, x0] * (1 - fx) + image[y0][:, x1] * fx
    bottom = image[y1][:, x0] * (1 - fx) + image[y1][:, x1] * fx
    return top * (1 - fy[:, None]) + bottom * fy[:, None]


def pillow_lanczos(image: np.ndarray, oh: int, ow: int) -> np.ndarray:
    """Pillow's Image.resize(LANCZOS, reducing_gap=None) on a float32 ('F') image."""
    from PIL import Image
    resample = getattr(Image, "Resampling", Image).LANCZOS
    return np.asarray(Image.fromarray(image.astype(np.float32), mode="F").resize((ow, oh), resample,
                                                                                 reducing_gap=None))


def ours(image: np.ndarray, oh: int, ow: int) -> np.ndarray:
    """clisp.modules.resize on the OpenCL device (grey in, channel 0 out)."""
    from clisp.modules.resize.stage import resize_image
    rgb = np.repeat(image.astype(np.float32)[..., None], 3, axis=2)
    return resize_image(rgb, oh, ow)[..., 0]


RESAMPLERS = {"clisp --resize (Lanczos-3, device)": ours, "Pillow LANCZOS": pillow_lanczos,
              "bilinear (no low-pass)": bilinear, "nearest": nearest}


# ------------------------------------------------------------------------------------------ the run

def direct(size: tuple[int, int], long_edge: int) -> tuple[list[tuple[str, dict[str, float], float]], dict]:
    """Every resampler on the zone plate of ``size`` (W, H) to ``long_edge``: rows of (name,
    figures, seconds) and the outputs by name."""
    from clisp.modules.resize.stage import resized_size
    w, h = size
    oh, ow = resized_size(h, w, long_edge)
    plate = zone_plate(h, w)
    ours(plate[:64, :96], 24, 36)                           # builds the programs outside the timing
    rows, outputs = [], {}
    for name, fn in RESAMPLERS.items():
        start = time.perf_counter()
        out = fn(plate, oh, ow)
        rows.append((name, figures(out, (h, w)), time.perf_counter() - start))
        outputs[name] = out
    return rows, outputs


def end_to_end(size: tuple[int, int], long_edge: int, work: Path) -> list[tuple[str, dict[str, float], float]]:
    """The zone plate of ``size`` simulated (Bayer, noiseless, no optics), processed by ``clisp
    process --resize`` to EXR, and processed at full size then resized by ours: rows as :func:`direct`."""
    from clisp.io.imageio import read_image, write_image
    from clisp.modules.resize.stage import resize_image, resized_size
    w, h = size
    oh, ow = resized_size(h, w, long_edge)
    scene, raw = work / "zone_plate.exr", work / "zone_plate.dng"
    write_image(scene, np.repeat(zone_plate(h, w)[..., None], 3, axis=2).astype(np.float32))
    run = lambda *args: subprocess.run(toolkit.clisp_cmd(*args), check=True, capture_output=True, text=True)
    run("simulate", str(scene), "-o", str(raw), "--cfa", "bayer", "--noiseless", "--optics", "none")
    rows = []
    start = time.perf_counter()
    run("process", str(raw), "-o", str(work / "resized.exr"), "--resize", str(long_edge))
    seconds = time.perf_counter() - start
    resized = read_image(work / "resized.exr")[0].astype(np.float64)
    assert resized.shape[:2] == (oh, ow), resized.shape
    run("process", str(raw), "-o", str(work / "full.exr"))
    after = resize_image(read_image(work / "full.exr")[0], oh, ow)
    for what, pick in (("mean of R, G, B", lambda rgb: figures(rgb.mean(axis=2), (h, w))),
                       ("worst of R, G, B", lambda rgb: worst_channel(rgb, (h, w)))):
        rows.append((f"clisp process --resize {long_edge} (quality, Bayer), {what}", pick(resized), seconds))
        rows.append((f"clisp process, then ours on its output, {what}", pick(after), float("nan")))
    return rows


def worst_channel(rgb: np.ndarray, in_hw: tuple[int, int]) -> dict[str, float]:
    """:func:`figures` of each of R, G, B against the grey ideal, the worst per band (false colour counts)."""
    per_channel = [figures(rgb[..., c], in_hw) for c in range(3)]
    return {band: max(f[band] for f in per_channel) for band in per_channel[0]}


def corner_figure(outputs: dict, in_hw: tuple[int, int], path: Path, crop: int = 128, zoom: int = 2) -> None:
    """PNG of two ``crop`` x ``crop`` output regions, sRGB-encoded, each pixel ``zoom`` x ``zoom``,
    columns ideal | ours | nearest: top row the zone plate's top-left corner (all past the output's
    Nyquist: an ideal output is flat there), bottom row across the output's Nyquist on the
    horizontal line through the centre (the pattern on the right, flat on the left)."""
    from PIL import Image
    from clisp.sim.colorimetry import srgb_encode
    shape = next(iter(outputs.values())).shape
    ideal, q, _, _ = output_grid(in_hw, shape)
    middle = shape[0] // 2
    edge = int(np.argmax(q[middle] < 1.0))                   # first column inside Nyquist on the centre line
    y0, x0 = max(0, middle - crop // 2), max(0, edge - crop // 2)
    regions = [(slice(0, crop), slice(0, crop)), (slice(y0, y0 + crop), slice(x0, x0 + crop))]
    panels = [ideal, outputs["clisp --resize (Lanczos-3, device)"], outputs["nearest"]]
    gap, rows = 6, []
    for region in regions:
        tiles = [np.kron(srgb_encode(np.clip(p[region], 0, 1)), np.ones((zoom, zoom))) for p in panels]
        spacer = np.ones((tiles[0].shape[0], gap))
        rows.append(np.concatenate([tiles[0], spacer, tiles[1], spacer, tiles[2]], axis=1))
    strip = np.concatenate([rows[0], np.ones((gap, rows[0].shape[1])), rows[1]], axis=0)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.round(strip * 255).astype(np.uint8), mode="L").save(path)


def table(rows: list[tuple[str, dict[str, float], float]]) -> list[str]:
    lines = ["| resampler | alias (q >= 1.25) | alias, input < 0.7 Nyq | transition (1 <= q < 1.25) | "
             "passband (q < 0.8) | q < 0.5 | seconds |", "|---|---:|---:|---:|---:|---:|---:|"]
    for name, f, seconds in rows:
        secs = "" if seconds != seconds else f"{seconds:.2f}"
        cells = " | ".join(f"{f[band]:.1f} dB" for band in ("alias", "alias_mid", "transition", "passband", "low"))
        lines.append(f"| {name} | {cells} | {secs} |")
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=toolkit.parse_size, default=(6000, 4000), metavar="WxH")
    ap.add_argument("--long-edge", type=int, default=2048, metavar="N")
    ap.add_argument("--e2e-size", type=toolkit.parse_size, default=None, metavar="WxH",
                    help="zone plate of the end-to-end run (simulate + process; default --size; 20 s at 6000x4000 "
                         "on 2 cores)")
    ap.add_argument("--e2e-long-edge", type=int, default=None, metavar="N", help="default --long-edge")
    ap.add_argument("--no-e2e", action="store_true", help="leave out the end-to-end run")
    ap.add_argument("--figure", type=Path, default=None, metavar="PNG", help="write the corner crops here")
    toolkit.add_work_option(ap)
    args = ap.parse_args(argv)
    from clisp.engine.runtime import get_runtime
    print(f"CPU: {toolkit.cpu_model()}; device: {get_runtime().describe()}; "
          f"clisp {toolkit.git_rev(toolkit.REPO, True)}")
    w, h = args.size
    print(f"zone plate {w}x{h}, linear {MEAN:g} +- {AMPLITUDE:g}, to long edge {args.long_edge}; "
          f"RMS(output - ideal) / RMS(pattern) in dB, {BORDER} px border left out")
    rows, outputs = direct(args.size, args.long_edge)
    print("\n".join(table(rows)))
    if args.figure:
        corner_figure(outputs, (h, w), args.figure)
        print(f"crops (ideal | ours | nearest; corner, then across Nyquist): {args.figure}")
    alias = rows[0][1]["alias"]
    verdict = "met" if alias <= ALIAS_TARGET_DB else "NOT met"
    print(f"ours: alias {alias:.1f} dB, target <= {ALIAS_TARGET_DB:g} dB: {verdict}")
    if not args.no_e2e:
        size, long_edge = args.e2e_size or args.size, args.e2e_long_edge or args.long_edge
        print(f"\nend to end: zone plate {size[0]}x{size[1]}, clisp simulate --cfa bayer --noiseless --optics none, "
              f"clisp process --resize {long_edge}")
        with toolkit.work_folder(args.work, "clisp-resize-") as work:
            print("\n".join(table(end_to_end(size, long_edge, work))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
