"""Command-line interface: ``clisp simulate | process | batch | info | demo``.

Names and options here are a contract with users and later work: keep them stable.
Every user-facing failure is one line on stderr (``clisp: error: FILE: problem``), exit status 2,
and no output file (all writes go to a temporary name and are renamed on success).
"""
from __future__ import annotations

import argparse
from collections import deque
import json
import os
import sys
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from contextlib import nullcontext
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from ..version import __version__
from ..errors import ClispError, clip, error_line
from ..engine import profile as engine_profile
from ..engine.profile import host_timer
from ..engine.runtime import get_runtime, list_devices, save_built_programs
from ..engine.streaming import progress_bar
from ..engine.tiling import Tile
from ..io.rawfile import RAW_SUFFIXES, is_raw_file, raw_band_writer, raw_info, read_raw, write_raw
from ..modules.resize.stage import check_long_edge, resize_note
from ..pipeline import (DEFAULT_BUDGET, DEFAULT_HIGHLIGHTS, DEFAULT_PRESET, DEMOSAICS, FILES_IN_FLIGHT,
                        GPU_FILES_IN_FLIGHT, HALF_SIZE_NO_DENOISE, PRESETS, SKIP_WHERE_IT_PAYS, denoise_params,
                        output_size, process_file, resolve_options)
from ..sim.colorimetry import srgb_decode
from ..sim.noise import GAIN_MAX, GAIN_MIN
from ..sim.simulate import simulate, simulate_large
# The modules above are loaded by `import clisp` anyway; the commands import the others where
# they use them, to keep `import clisp.app.cli` light (issue 11).

_LOADED = time.perf_counter()

EXIT_ERROR = 2


def _add_simulate(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="simulate a noisy LMS or Bayer raw from an sRGB or linear EXR scene",
                       description="Inverse ISP, Airy optics, shot + read noise at analog gain G, 10-bit ADC, "
                                   "mosaic (docs/model.md, sections 2-3). Writes a DNG-style raw.")
    p.add_argument("scene", nargs="?", help="sRGB-encoded PNG/TIFF (8 or 16 bit) or linear-sRGB float EXR")
    p.add_argument("--spectral", choices=("colorchecker",), default=None,
                   help="instead of SCENE, a ColorChecker from reflectance spectra under D65 (LMS: Stockman-"
                        "Sharpe cones; Bayer: Nikon D100); truth = its true sRGB")
    p.add_argument("--reflectances", default=None, metavar="MAT",
                   help="with --spectral: ISETCam's macbethChart.mat instead of colour-science's spectra")
    p.add_argument("-o", "--output", required=True, help="raw file to write (.dng)")
    p.add_argument("--cfa", default="lms",
                   help="lms or bayer (also bayer-grbg, bayer-gbrg, bayer-bggr, lms@dy,dx), lms-bayer (L, M, S on "
                        "the RGGB layout; lms-bayer-grbg, ...) or a pattern string of L, M, S or R, G, B letters, "
                        "rows joined by '/' (LMMS, ML/LS: L doubled on the Bayer layout, LMLS/MLML/LSLM/MLML)")
    noise = p.add_mutually_exclusive_group()
    noise.add_argument("--gain", type=float, default=None, help="analog gain 1..64 (default 1)")
    noise.add_argument("--noiseless", action="store_true", help="no noise, no quantisation, no clipping (float raw)")
    p.add_argument("--optics", choices=("airy", "none"), default="airy", help="diffraction blur (default airy)")
    p.add_argument("--seed", type=int, default=0, help="noise seed (default 0)")
    p.add_argument("--truth", help="also write the clean ground truth (linear sRGB float EXR)")
    p.add_argument("--size", type=image_size, default=None, metavar="WxH",
                   help="repeat the scene (alternate copies mirrored) to W x H and write raw and truth "
                        "band by band, for images larger than memory; the noise is seeded per band, "
                        "so the result is reproducible but not bit-identical to a run without --size")
    _add_sensor_defect_options(p)
    p.set_defaults(func=cmd_simulate)


def _add_sensor_defect_options(p: argparse.ArgumentParser) -> None:
    """simulate's sensor defects (clisp.sim.defects), the frames that match them and how the raw
    records them; ``--truth`` stays the ideal sensor's image."""
    g = p.add_argument_group("sensor defects (--truth stays the defect-free image)")
    g.add_argument("--hot-pixels", default=None, metavar="F[:LEVEL]",
                   help="fraction F of hot pixels (dark-current defects), excess LEVEL of full scale (default 0.5)")
    g.add_argument("--warm-pixels", default=None, metavar="F[:LEVEL]",
                   help="fraction F of warm pixels, excess LEVEL of full scale (default 0.05)")
    g.add_argument("--dead-pixels", default=None, metavar="F", help="fraction F of dead pixels (no response)")
    g.add_argument("--dark-current", default=None, metavar="E", help="dark current, electrons per second "
                   "(its fixed pattern: a lognormal per-pixel rate, std 0.4 of the mean)")
    g.add_argument("--exposure-time", default=None, metavar="S", help="exposure time in seconds (default 0.01)")
    g.add_argument("--shading", default=None, metavar="CORNER",
                   help="lens shading: relative illumination at the corners (cos^4 law, e.g. 0.5), with a "
                        "colour shading that differs per channel")
    g.add_argument("--prnu", default=None, metavar="STD", help="photo-response non-uniformity, std (e.g. 0.01)")
    g.add_argument("--sensor-seed", type=int, default=None, metavar="N",
                   help="seed of the defects' fixed pattern (default: --seed)")
    g.add_argument("--dark-frames", type=int, default=0, metavar="N",
                   help="also write N dark frames (same exposure, gain and pattern, no light) as OUT_dark01.dng ...")
    g.add_argument("--flat-frames", type=int, default=0, metavar="N",
                   help="also write N flat frames (an even light through the same shading and PRNU, base gain) "
                        "as OUT_flat01.dng ...")
    g.add_argument("--gainmap", action="store_true",
                   help="record the lens shading in the DNG as GainMap opcodes (OpcodeList2), as a phone does")
    g.add_argument("--bad-pixel-list", action="store_true",
                   help="record the hot, warm and dead pixels in the DNG as FixBadPixelsList (OpcodeList1)")


def _sensor_defects(args: argparse.Namespace):
    """The SensorDefects simulate's options ask for, or None; ClispError for a malformed value."""
    values: dict = {}

    def number(option: str, text: str, what: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = float("nan")
        if not np.isfinite(value) or value < 0:
            raise ClispError(f"{option} {text!r}: {what}")
        return value

    for kind in ("hot", "warm"):
        text = getattr(args, f"{kind}_pixels")
        if text is not None:
            fraction, colon, level = text.partition(":")
            values[kind] = number(f"--{kind}-pixels", fraction, "needs a fraction from 0 to 0.5, optionally :LEVEL")
            if colon:
                values[f"{kind}_level"] = number(f"--{kind}-pixels", level, "LEVEL is a share of full scale >= 0")
    for option, key, what in (("--dead-pixels", "dead", "needs a fraction from 0 to 0.5"),
                              ("--dark-current", "dark_current", "needs electrons per second >= 0"),
                              ("--exposure-time", "exposure_time", "needs seconds > 0"),
                              ("--shading", "shading", "needs the corners' relative illumination, in (0, 1]"),
                              ("--prnu", "prnu", "needs a standard deviation from 0 to 0.5")):
        text = getattr(args, key if key != "dead" else "dead_pixels")
        if text is not None:
            values[key] = number(option, text, what)
    if args.dark_frames < 0 or args.flat_frames < 0:
        raise ClispError("--dark-frames and --flat-frames take a number of frames >= 0")
    if not values and not (args.dark_frames or args.flat_frames or args.gainmap or args.bad_pixel_list):
        return None
    seed = args.sensor_seed if args.sensor_seed is not None else args.seed
    from ..sim.defects import SensorDefects           # deferred: only simulate's defect options use it
    return SensorDefects(**values, seed=int(seed))


def _add_process(sub: argparse._SubParsersAction) -> None:
    from .batch import FORMATS                  # loaded by _add_batch anyway
    p = sub.add_parser("process", help="process raws (ours or a camera's) into images, in this process",
                       description="One RAW and -o OUT: OUT by extension, .exr linear sRGB float; .tif/.tiff/.png "
                                   "16-bit sRGB-encoded; .jpg/.jpeg 8-bit sRGB. Several RAWs, folders, --format or an existing folder "
                                   "as -o: OUTDIR/<raw stem>.<format>, one after the other in one process "
                                   "(the OpenCL context and kernels are shared); a bad file is reported on "
                                   "one line and the others are processed (exit status 1 when any failed). "
                                   "clisp batch runs files in parallel, on Dask.")
    p.add_argument("raw", nargs="+", metavar="RAW",
                   help="a clisp DNG or a camera raw (DNG, CR2, NEF, CRW, ... through rawpy); several, or "
                        "folders of them (not recursive), with -o OUTDIR")
    p.add_argument("-o", "--output", required=True, metavar="OUT",
                   help="output image (.exr, .tif, .tiff, .png, .jpg), or the output folder OUTDIR (created if "
                        "missing) for several inputs")
    p.add_argument("--format", choices=FORMATS, default=None,
                   help="with OUTDIR: exr (default; linear sRGB float), tif or png (16-bit sRGB-encoded), "
                        "jpg (8-bit sRGB)")
    p.add_argument("--preset", default=None, help=f"parameter set: {', '.join(PRESETS)} (default {DEFAULT_PRESET})")
    _add_exposure_options(p)
    _add_resize_option(p)
    _add_half_size_option(p)
    p.add_argument("--demosaic", default=None, help=f"demosaic: {', '.join(DEMOSAICS)} (default from the preset)")
    p.add_argument("--tile", type=int, default=None,
                   help="tile side in pixels (default: chosen from --mem and the device's limits)")
    p.add_argument("--compression", default=None, metavar="NAME",
                   help="EXR/TIFF/PNG compression: none (default, fastest; PNG then stores its rows "
                        "uncompressed), zip, piz, dwaa, lzw, ...")
    p.add_argument("--mem", type=memory_size, default=DEFAULT_BUDGET, metavar="SIZE",
                   help="peak memory (resident set) of the whole process, e.g. 512M or 2G (default 1G): "
                        "the image is streamed from the raw file to the output in tiles as large as "
                        "fit; below the minimum for the raw and preset, an error says what it is")
    p.add_argument("--no-denoise", action="store_true", help="no chroma denoising (plain colour matrix)")
    p.add_argument("--denoise-scale", type=float, default=1.0, metavar="K",
                   help="multiply the noise levels the chroma denoiser assumes (default 1: the raw's noise "
                        "model, or an estimate from the raw when it has none)")
    p.add_argument("--chroma-strengths", default=None, metavar="S,S[,S]",
                   help="per-chroma strengths: LMS R-Y,G-Y,B-Y (default 1,1,1.5), Bayer U,V (default 1.5,1)")
    p.add_argument("--wb2", choices=("metadata", "gray_world", "gray_pixels"), default="metadata",
                   help="white balance pass 2: known illuminant (default), gray world, gray pixels")
    p.add_argument("--highlights", choices=("clip", "reconstruct", "clamp", "off"), default=None,
                   help="clipped highlights: reconstruct the colour from the unclipped channels and the "
                        "light's rim, clip to a neutral white, clamp every channel at that white (per pixel, "
                        "as LibRaw), or off (left as the sensor clipped them); default from the preset "
                        f"(fast: clamp, else {DEFAULT_HIGHLIGHTS}). Raws without clipped samples skip the stage")
    p.add_argument("--no-crop", action="store_true",
                   help="keep the whole mosaic; by default the output is the crop the raw declares "
                        "(a DNG's DefaultCrop inside its ActiveArea, a camera's recommended crop)")
    _add_sensor_options(p)
    p.add_argument("--backend", choices=("opencl", "reference"), default="opencl",
                   help="opencl kernels (default) or the NumPy reference")
    p.add_argument("--explain", action="store_true",
                   help="print the scene analysis, the per-tile plan (which tiles skip what, and why) and, "
                        "after the run, the time per stage and the estimated time saved")
    p.add_argument("--no-skip", action="store_true",
                   help="run every stage on every tile (default: tiles skip what the scene analysis "
                        "shows they do not need: demosaic + chroma denoise on tiles with nothing but noise, coarse "
                        "chroma-denoise levels where chroma noise is invisible)")
    p.add_argument("--profile", action="store_true",
                   help="print where the time went: device time per stage and kernel (OpenCL event "
                        "profiling), host time for decode, reading, writing and waiting")
    p.set_defaults(func=cmd_process)


def _add_sensor_options(p: argparse.ArgumentParser) -> None:
    """process's sensor corrections (clisp.pipeline.corrections)."""
    p.add_argument("--bad-pixels", default=None, metavar="auto|off|MAP",
                   help="defective pixels: auto (default; off for preset fast and --half-size) finds them "
                        "against the sensor's noise model and replaces them from neighbours of their channel, "
                        "with the DNG's FixBadPixels lists; MAP is a file of 'column row' lines (dcraw's format) used as given, no search; "
                        "off: none")
    p.add_argument("--dark", action="append", default=[], metavar="DARK",
                   help="a dark frame (same camera, exposure and ISO, no light; a raw file, or a folder of "
                        "them), subtracted; repeat for several, averaged; scaled by exposure time when both "
                        "raws state it")
    p.add_argument("--flat", action="append", default=[], metavar="FLAT",
                   help="a flat frame (an even light through the same lens; a raw file or a folder), "
                        "normalised per channel, dividing the raw (lens shading and PRNU); repeat for several")
    p.add_argument("--no-opcodes", action="store_true",
                   help="apply none of the DNG's opcodes (GainMap, FixVignetteRadial, FixBadPixels), as LibRaw")


def frame_files(paths: Sequence[str]) -> list[str]:
    """--dark / --flat values: files as given, folders as the raw files directly inside them (sorted)."""
    out: list[str] = []
    for path in paths:
        p = Path(path)
        if p.is_dir():
            found = sorted(str(f) for f in p.iterdir() if f.is_file() and f.suffix.lower() in RAW_SUFFIXES)
            if not found:
                raise ClispError(f"no raw files in {path}")
            out += found
        else:
            out.append(path)
    return out


def _add_resize_option(p: argparse.ArgumentParser) -> None:
    """--resize (process and batch alike); a string, checked by clisp.modules.resize.stage.check_long_edge
    so that a bad value gets the one-line refusal (argparse's own error is a usage block)."""
    p.add_argument("--resize", default=None, metavar="N",
                   help="long edge of the output in pixels (at least 16), the short edge in proportion: a "
                        "Lanczos-3 low-pass in linear light, on the device, after the crop and the camera's "
                        "orientation; never enlarges")


def _add_exposure_options(p: argparse.ArgumentParser) -> None:
    """--exposure, --auto-exposure and --wb (process and batch alike)."""
    p.add_argument("--exposure", type=float, default=0.0, metavar="EV",
                   help="exposure in EV on linear sRGB, after the colour conversion (default 0: colorimetric, "
                        "1.0 = the raw's white); recorded in the output's description")
    p.add_argument("--auto-exposure", action="store_true",
                   help="brighten as LibRaw's auto-bright does: the level the brightest 1%% of the pixels "
                        "exceed in the brightest channel goes to white (never darker); adds to --exposure")
    p.add_argument("--wb", default="camera", metavar="{camera,auto,daylight,R,G,B}",
                   help="white balance (pass 1, on the raw): camera = as shot (default; a raw without it gets "
                        "auto), auto = the scene's grey pixels, daylight = the camera's daylight multipliers "
                        "(rawpy's default), or multipliers in the CFA's channel order, e.g. 2.1,1,1.6; recorded "
                        "in the output's description when not camera")


def _add_half_size_option(p: argparse.ArgumentParser) -> None:
    """--half-size (process and batch alike)."""
    p.add_argument("--half-size", action="store_true",
                   help="the preview path: half the width and height, one pixel per 2x2 block of the mosaic "
                        "(Bayer: its R, the mean of its two G, its B; LMS: each channel's mean over the 4x4 "
                        "window around the block), no demosaic; the preset's demosaic and chroma denoise are "
                        "not used (--demosaic, --denoise-scale, --chroma-strengths are refused), highlights "
                        "clamp unless --highlights says otherwise")


def _add_batch(sub: argparse._SubParsersAction) -> None:
    from .batch import FORMATS                  # deferred: clisp.app.batch (hashlib, uuid) costs 9 ms of start-up
    p = sub.add_parser("batch", help="process many raws (files or folders) in parallel on Dask, resumably",
                       description="Writes OUTDIR/<input stem>.<format> and OUTDIR/manifest.jsonl (one record per "
                                   "file and attempt). A re-run skips outputs finished with the same settings. "
                                   "Exit status 1 when any input failed (the others are processed), 2 when the "
                                   "batch cannot run.")
    p.add_argument("inputs", nargs="+", metavar="INPUT", help="raw files, or folders of them (not recursive)")
    p.add_argument("-o", "--output", required=True, metavar="OUTDIR", help="output folder (created if missing)")
    p.add_argument("--preset", default=None, help=f"parameter set: {', '.join(PRESETS)} (default {DEFAULT_PRESET})")
    _add_exposure_options(p)
    _add_resize_option(p)
    _add_half_size_option(p)
    p.add_argument("--demosaic", default=None, help=f"demosaic: {', '.join(DEMOSAICS)} (default from the preset)")
    p.add_argument("--format", choices=FORMATS, default="exr",
                   help="exr: linear sRGB float (default); tif, png: 16-bit sRGB-encoded")
    p.add_argument("--compression", default=None, metavar="NAME", help="EXR/TIFF/PNG compression (as process)")
    p.add_argument("--mem", type=memory_size, default=None, metavar="SIZE",
                   help="peak memory of each worker's processing, as process --mem (default 1G)")
    p.add_argument("--no-skip", action="store_true", help="run every stage on every tile (as process --no-skip)")
    p.add_argument("--workers", type=int, default=None, metavar="N",
                   help="worker processes of the local Dask cluster (default: one per CPU)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run on an existing Dask cluster, e.g. tcp://host:8786 (its workers need clisp "
                        "installed and must see the inputs and OUTDIR at the same paths)")
    p.set_defaults(func=cmd_batch)


def _add_info(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("info", help="describe a raw file, or the OpenCL device with --device")
    p.add_argument("raw", nargs="?", help="raw file to describe")
    p.add_argument("--device", action="store_true", help="show the OpenCL platforms and the device clisp uses")
    p.add_argument("--warm", nargs="?", const="default", default=None, metavar="PRESETS",
                   help="with --device: build the OpenCL kernels ahead of the first run (compiled once per "
                        "machine, device and clisp version), for the default and fast presets, or for "
                        "PRESETS (comma-separated, or 'all')")
    p.add_argument("--json", action="store_true", help="print the raw's description as JSON")
    p.set_defaults(func=cmd_info)


def _add_thumb(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("thumb", help="extract the preview a camera embedded in its raw file",
                       description="Write the preview a camera embedded in RAW (no demosaic): a JPEG preview "
                                   "to -o x.jpg as stored, else decoded into OUT's format (.jpg, .png, .tif, "
                                   ".tiff: sRGB; .exr: linear).")
    p.add_argument("raw", metavar="RAW")
    p.add_argument("-o", "--output", required=True, metavar="OUT")
    p.set_defaults(func=cmd_thumb)


def cmd_thumb(args: argparse.Namespace) -> int:
    from ..io.imageio import JPEG_EXTENSIONS, atomic_path, output_kind, write_image   # deferred: 2 ms of start-up
    from ..io.preview import read_preview               # deferred: rawpy only for camera raws
    kind = output_kind(args.output)
    preview = read_preview(args.raw)
    if preview.jpeg is not None and Path(args.output).suffix.lower() in JPEG_EXTENSIONS:
        with atomic_path(args.output) as tmp:
            tmp.write_bytes(preview.jpeg)
        how = "JPEG, as stored"
    else:
        pixels = preview.decoded()
        if kind == "linear":
            pixels = srgb_decode(pixels)
        write_image(args.output, pixels)
        how = ("JPEG" if preview.jpeg is not None else "bitmap") + ", decoded"
    print(f"{args.output}: {preview.width}x{preview.height} preview embedded in {args.raw} ({how})")
    return 0


def _add_demo(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", help="simulate, process and score the built-in chart (no data files needed)")
    p.add_argument("--out", default="clisp-demo", help="folder for the images (default ./clisp-demo)")
    p.set_defaults(func=cmd_demo)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="clisp", description="OpenCL ISP for raw sensor data: LMS camera and Bayer.")
    parser.add_argument("--version", action="version", version=f"clisp {__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    _add_simulate(sub)
    _add_process(sub)
    _add_batch(sub)
    _add_info(sub)
    _add_thumb(sub)
    _add_demo(sub)
    return parser


def cmd_simulate(args: argparse.Namespace) -> int:
    from ..io.imageio import read_scene                  # deferred: clisp.io.imageio costs 2 ms of start-up
    _check_output_ext(args.output, (".dng", ".tif", ".tiff"))
    if args.truth:
        _check_output_ext(args.truth, (".exr",))
    gain = None if args.noiseless else (1.0 if args.gain is None else args.gain)
    if gain is not None and not GAIN_MIN <= gain <= GAIN_MAX:      # also NaN
        raise ClispError(f"--gain {gain:g} is outside the supported range {GAIN_MIN:g}..{GAIN_MAX:g}; "
                         f"--noiseless simulates without noise")
    if (args.scene is None) == (args.spectral is None):
        raise ClispError("simulate needs a SCENE file or --spectral colorchecker (one of them)")
    if args.spectral:
        return _simulate_spectral(args, gain)
    if is_raw_file(args.scene):
        raise ClispError(f"{args.scene}: is a raw file, not a scene; simulate takes an sRGB PNG/TIFF or a "
                         f"linear EXR (clisp process turns a raw into one)")
    defects = _sensor_defects(args)
    scene = read_scene(args.scene)
    if args.size:
        if defects is not None:
            raise ClispError("--size repeats a scene band by band and simulates no sensor defects; "
                             "leave out the defect options or --size")
        return _simulate_large(args, scene, gain)
    result = simulate(scene, cfa=args.cfa, gain=gain, optics=args.optics, seed=args.seed, defects=defects)
    result.raw.metadata["scene"] = Path(args.scene).name
    extra = _record_defects(args, result.raw, defects, gain)
    head, noise = _write_simulation(args, result, gain)
    print(f"{head}, {noise}, optics {args.optics}, seed {args.seed}" + extra)
    return 0


def _record_defects(args: argparse.Namespace, raw, defects, gain: float | None) -> str:
    """Write the frames simulate was asked for beside ``args.output`` and record the defects in the
    raw as a camera would (GainMap, FixBadPixelsList); the note for simulate's line."""
    if defects is None:
        return ""
    from ..sim import defects as sd   # deferred: only a simulation with defects loads the defect model (start-up)
    ops = []
    if args.gainmap:
        ops += sd.gain_map_opcodes(defects, raw.cfa, raw.shape)
    if args.bad_pixel_list:
        ops.append(sd.bad_pixel_list_opcode(defects, raw.shape))
    if ops:
        raw.metadata["opcodes"] = ops
    stem = Path(args.output).with_suffix("")
    written = []
    for kind, count, seed in (("dark", args.dark_frames, args.seed + 1000), ("flat", args.flat_frames, args.seed + 2000)):
        for i, frame in enumerate(sd.frames(raw, defects, kind, count, gain, seed)):
            path = f"{stem}_{kind}{i + 1:02d}.dng"
            write_raw(path, frame)
            written.append(path)
    parts = [name for name, on in (("GainMap", args.gainmap), ("FixBadPixelsList", args.bad_pixel_list)) if on]
    note = "; sensor defects" + (f", {' and '.join(parts)} in the DNG" if parts else "")
    if written:
        note += f"; {args.dark_frames} dark and {args.flat_frames} flat frames beside it ({Path(written[0]).name} ...)"
    return note


def _simulate_spectral(args: argparse.Namespace, gain: float | None) -> int:
    """``simulate --spectral colorchecker``: the spectral path (clisp.sim.spectral)."""
    from ..sim.spectral import simulate_spectral         # deferred: with sim.charts 4 ms of start-up
    if args.size:
        raise ClispError("--size repeats a scene file; it does not apply to --spectral")
    source = "isetcam" if args.reflectances else "colour"
    result = simulate_spectral(args.cfa, gain=gain, optics=args.optics, seed=args.seed, source=source,
                               data=args.reflectances)
    head, noise = _write_simulation(args, result, gain)
    print(f"{head} of the spectral ColorChecker ({source} reflectances, D65), {noise}, optics {args.optics}, "
          f"seed {args.seed}")
    return 0


def _write_simulation(args: argparse.Namespace, result: Any, gain: float | None) -> tuple[str, str]:
    """Write a simulation's raw (and ``--truth``'s image); the report line's head ('OUT: WxH CFA raw')
    and its noise ('noiseless' or 'gain G')."""
    from ..io.imageio import write_image                 # deferred: 2 ms of start-up
    write_raw(args.output, result.raw)
    if args.truth:
        write_image(args.truth, result.truth)
    h, w = result.raw.shape
    return f"{args.output}: {w}x{h} {result.raw.cfa.name} raw", "noiseless" if gain is None else f"gain {gain:g}"


def _simulate_large(args: argparse.Namespace, scene: np.ndarray, gain: float | None) -> int:
    """``simulate --size``: bands computed one after another, each written (raw and truth) on a
    writer thread while the next is computed; two bands in memory at most."""
    from ..io.imageio import ImageWriter                 # deferred: 2 ms of start-up
    width, height = args.size
    sim = simulate_large(scene, (height, width), cfa=args.cfa, gain=gain, optics=args.optics, seed=args.seed)
    sim.header.metadata["scene"] = Path(args.scene).name
    truth_file = ImageWriter(args.truth, width, height) if args.truth else nullcontext(None)
    with raw_band_writer(args.output, sim.header) as write_rows, truth_file as truth, \
            progress_bar(sim.bands, Path(args.output).name) as update, ThreadPoolExecutor(1) as writer:
        def write(band: Tile, dn: np.ndarray, rgb: np.ndarray) -> None:
            write_rows(band.y0, dn)
            if truth is not None:
                truth.write_rows(band.y0, rgb)
        pending = None
        for band in sim.bands:
            pixels = sim.band(band)
            if pending is not None:
                pending.result()
            pending = writer.submit(write, band, *pixels)
            update(band)
        pending.result()
    noise = "noiseless" if gain is None else f"gain {gain:g}"
    sh, sw = scene.shape[:2]
    print(f"{args.output}: {width}x{height} {sim.header.cfa.name} raw, {noise}, optics {args.optics}, "
          f"seed {args.seed} per band; {sw}x{sh} scene repeated (mirrored), {len(sim.bands)} bands")
    return 0


def cmd_process(args: argparse.Namespace) -> int:
    from ..io.imageio import check_compression, output_kind      # deferred: 2 ms of start-up
    many = is_many(args.raw, args.output, args.format)
    if not many:
        output_kind(args.output)
    resolve_options(args.preset, args.demosaic, half_size=args.half_size)   # fail on bad names before reading anything
    if args.half_size:
        _denoise_option(args, half_size=True)
    if args.compression:
        check_compression(f"x.{args.format or 'exr'}" if many else args.output, args.compression)
    if args.tile is not None and args.tile < 16:
        raise ClispError(f"--tile {args.tile}: tiles must be at least 16 pixels")
    if args.resize is not None:
        args.resize = check_long_edge(args.resize)
    if many:
        return _process_many(args)
    try:
        _process_one(args, args.raw[0], args.output)
    except ClispError as exc:
        raise naming_a_file(exc, args.raw[0], args.output) from exc.__cause__
    return 0


def naming_a_file(exc: ClispError, path: str, output: str) -> ClispError:
    """``exc`` as it is when its text names the raw or the output (by path or file name), else with
    the raw's path in front: every refusal names the file it is about (docs/messages.md), also
    those raised deep in a stage that does not know the file (a demosaic for another CFA)."""
    text = str(exc)
    if any(name and name in text for name in (path, Path(path).name, output, Path(output).name)):
        return exc
    return ClispError(f"{path}: {text}")


OUTPUT_SUFFIXES = (".exr", ".tif", ".tiff", ".png", ".jpg", ".jpeg")
"""Extensions of an output image: -o with one of them is never taken as a new output folder."""


def is_many(inputs: Sequence[str], output: str, fmt: str | None) -> bool:
    """Whether ``clisp process`` writes into an output folder: several inputs, --format, an existing
    folder as -o, or a folder as the input with an -o that does not name an image (a folder with
    ``-o x.exr`` stays the one-file form, whose error says the input is a folder)."""
    if len(inputs) > 1 or fmt is not None or Path(output).is_dir():
        return True
    return Path(inputs[0]).is_dir() and Path(output).suffix.lower() not in OUTPUT_SUFFIXES


def _process_one(args: argparse.Namespace, path: str, output: str) -> None:
    """Read ``path``, process it into ``output`` and print its line (and --explain/--profile)."""
    print(_run_one(args, path, output), flush=True)


def _run_one(args: argparse.Namespace, path: str, output: str, progress: bool = True) -> str:
    """Read ``path`` and process it into ``output``; returns its line (and --explain/--profile's)."""
    profile = _start_profile() if (args.profile or args.explain) and args.backend == "opencl" else None
    with host_timer("decode raw file (header, camera raw pixels)"):
        raw = read_raw(path, lazy=True)
    skip = (False if args.explain else None) if args.no_skip else SKIP_WHERE_IT_PAYS
    explained: dict = {}
    (height, width), stats = process_file(raw, output, tile=args.tile, budget=args.mem, backend=args.backend,
                                          progress=progress, compression=args.compression, preset=args.preset,
                                          demosaic=args.demosaic, denoise=_denoise_option(args), wb2=args.wb2,
                                          skip=skip, highlights=args.highlights, exposure=args.exposure,
                                          auto_exposure=args.auto_exposure, wb=args.wb, resize=args.resize,
                                          half_size=args.half_size, bad_pixels=args.bad_pixels,
                                          dark=frame_files(args.dark), flat=frame_files(args.flat),
                                          opcodes=not args.no_opcodes,
                                          explain=explained, crop=not args.no_crop)
    th, tw = stats.tile_shape
    size = resize_note(output_size(raw, not args.no_crop, args.half_size), (height, width), args.resize)
    lines = [f"{output}: {width}x{height}{size} from {raw.cfa.name} raw, {stats.megapixels:.1f} MP in "
             f"{stats.seconds:.2f} s ({stats.mp_per_s:.1f} MP/s, {stats.tiles} tile{'s' if stats.tiles != 1 else ''} "
             f"of {tw}x{th})"]
    corrections = getattr(explained.get("pipeline"), "corrections", None)
    for name in corrections.unapplied if corrections is not None else ():
        print(f"clisp: note: {path}: DNG opcode {name} not applied", file=sys.stderr, flush=True)
    if args.explain:
        from ..pipeline.skip import explain_run                   # deferred: skip and analysis cost 7 ms of start-up
        if corrections is not None:
            lines.append(corrections.explain(stats))
        if args.half_size:
            lines.append(f"explain: half-size path (one pixel per 2x2 block, no demosaic): "
                         f"{explained['pipeline'].describe()}")
        lines.append(explain_run(explained.get("pipeline"), stats, profile))
        if getattr(explained.get("pipeline"), "wb_explain", ""):
            lines.append(f"explain: {explained['pipeline'].wb_explain}")
    if profile is not None and args.profile:
        wall = _process_seconds()
        lines.append(profile.report(stats.megapixels, wall))
        lines.append(f"  {'process start-up (interpreter, imports, OpenCL)':<44}{_STARTUP.get('s', 0.0):8.3f}")
    if profile is not None:
        engine_profile.stop()                           # the next file's runs are not this file's
    return "\n".join(lines)


def files_in_flight(args: argparse.Namespace, count: int) -> int:
    """How many of ``count`` files ``clisp process`` runs at once: one with --profile or --explain
    (their figures are the one file's) or on the NumPy reference, else FILES_IN_FLIGHT (or
    GPU_FILES_IN_FLIGHT on a discrete device: clisp.pipeline)."""
    if count < 2 or args.profile or args.explain or args.backend != "opencl":
        return 1
    return FILES_IN_FLIGHT if get_runtime().host_unified else GPU_FILES_IN_FLIGHT


def _process_many(args: argparse.Namespace) -> int:
    """Every input into OUTDIR/<stem>.<format>, one after the other in this process. A file that
    fails gets one line on stderr naming it; the others go on. Exit status 1 when any failed."""
    from .batch import collect_inputs, error_line as file_error, plan_jobs   # loaded by the parser anyway
    outdir = Path(args.output)
    if (outdir.exists() and not outdir.is_dir()) or (not outdir.exists() and outdir.suffix.lower() in OUTPUT_SUFFIXES):
        raise ClispError(f"{outdir}: several inputs need an output folder (-o OUTDIR), not a file")
    inputs = collect_inputs(args.raw)
    if not inputs:
        raise ClispError(f"no raw files in {', '.join(args.raw)}")
    jobs = plan_jobs(inputs, outdir, args.format or "exr")
    try:
        outdir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ClispError(f"{outdir}: cannot create the output folder ({exc.strerror or exc})") from None
    start, failed = time.perf_counter(), 0
    in_flight = files_in_flight(args, len(jobs))

    def one(job: Any) -> tuple[str, str]:
        """(line for stdout, line for stderr) of one file."""
        try:
            return _run_one(args, job.input, job.output, progress=in_flight == 1), ""
        except (ClispError, MemoryError) as exc:
            return "", error_line(file_error(job.input, exc))
    with ThreadPoolExecutor(in_flight, thread_name_prefix="clisp-file") as files:
        pending: deque = deque()
        for job in jobs:                 # at most in_flight files read and held at once
            pending.append(files.submit(one, job))
            while len(pending) >= in_flight or (pending and job is jobs[-1]):
                out, err = pending.popleft().result()      # lines in the inputs' order
                if err:
                    failed += 1
                    print(err, file=sys.stderr, flush=True)
                else:
                    print(out, flush=True)
    done = len(jobs) - failed
    seconds = time.perf_counter() - start
    print(f"{done} of {len(jobs)} file{'s' if len(jobs) != 1 else ''} written to {outdir} in {seconds:.1f} s"
          + (f" ({done / seconds:.2f} files/s)" if done and seconds > 0 else "")
          + (f"; {failed} failed" if failed else ""))
    return 1 if failed else 0


def cmd_batch(args: argparse.Namespace) -> int:
    from .batch import BatchSettings, run_batch, summary_line   # deferred: 9 ms of start-up
    if args.workers is not None and args.workers < 1:
        raise ClispError(f"--workers {args.workers}: at least 1")
    if args.workers is not None and args.scheduler:
        raise ClispError("--workers sizes a local cluster; an existing cluster (--scheduler) has its own workers")
    resize = check_long_edge(args.resize) if args.resize is not None else None
    settings = BatchSettings(preset=args.preset, format=args.format, demosaic=args.demosaic,
                             compression=args.compression, mem=args.mem, skip=not args.no_skip,
                             exposure=args.exposure, auto_exposure=args.auto_exposure, wb=args.wb,
                             resize=resize, half_size=args.half_size)
    summary = run_batch(args.inputs, args.output, settings, workers=args.workers, scheduler=args.scheduler,
                        progress=True)
    for message in summary.failed:
        print(f"clisp: error: {message}", file=sys.stderr)
    print(summary_line(summary))
    return 1 if summary.errors else 0


_STARTUP: dict[str, float] = {}


def _process_seconds() -> float:
    """Seconds since this process started (Linux /proc), else since the CLI module loaded."""
    try:
        ticks = os.sysconf("SC_CLK_TCK")
        with open("/proc/self/stat") as f:
            started = int(f.read().rsplit(")", 1)[1].split()[19]) / ticks
        with open("/proc/uptime") as f:
            return float(f.read().split()[0]) - started
    except (OSError, ValueError, IndexError):
        return time.perf_counter() - _LOADED


def _start_profile() -> "object":
    """Profiling runtime and a fresh clisp.engine.profile.Profile; notes the start-up time so far."""
    get_runtime(profiling=True)
    _STARTUP["s"] = _process_seconds()
    return engine_profile.start()


def _denoise_option(args: argparse.Namespace, half_size: bool = False) -> "bool | None | object":
    """build_pipeline's ``denoise`` from --no-denoise, --denoise-scale and --chroma-strengths.
    ``half_size``: refuse the two that would turn a denoiser on (--half-size runs none)."""
    if args.no_denoise:
        return False
    if args.denoise_scale == 1.0 and args.chroma_strengths is None:
        return None                                   # the preset decides
    if half_size:
        raise ClispError(HALF_SIZE_NO_DENOISE)
    if args.denoise_scale < 0:
        raise ClispError(f"--denoise-scale {args.denoise_scale:g}: must be >= 0")
    try:
        strengths = tuple(float(v) for v in args.chroma_strengths.split(",")) if args.chroma_strengths else None
    except ValueError as exc:
        raise ClispError(f"--chroma-strengths {args.chroma_strengths!r}: expected numbers separated by commas") from exc
    levels = PRESETS[args.preset or DEFAULT_PRESET]["denoise_levels"]
    return replace(denoise_params(True, levels), noise_scale=args.denoise_scale, strengths=strengths)


def cmd_info(args: argparse.Namespace) -> int:
    if args.warm is not None and not args.device:
        raise ClispError("--warm builds the kernels of the device: use clisp info --device --warm")
    presets = _warm_presets(args.warm) if args.warm is not None else ()
    if args.device:
        _print_devices()
    if presets:
        from .warm import warm_kernels                 # deferred: only --warm runs it
        print(f"building the OpenCL kernels of presets {', '.join(presets)} (LMS and Bayer):", flush=True)
        print(f"kernels ready in {warm_kernels(presets, report=lambda line: print(line, flush=True)):.1f} s")
    if args.raw:
        info = raw_info(args.raw)
        if args.json:
            print(json.dumps(info, indent=2, default=_json_value))
        else:
            for key, value in info.items():
                print(f"{key:>22}: {_format_value(value)}")
    elif not args.device:
        raise ClispError("info needs a RAW file or --device")
    return 0


def _warm_presets(text: str) -> tuple[str, ...]:
    """The presets --warm names: 'default' (the default preset and fast), 'all', or a list."""
    if text == "default":
        from .warm import DEFAULT_WARM_PRESETS         # deferred: only --warm needs it
        return tuple(DEFAULT_WARM_PRESETS)
    names = tuple(PRESETS) if text == "all" else tuple(n.strip() for n in text.split(",") if n.strip())
    unknown = [n for n in names if n not in PRESETS]
    if unknown or not names:
        raise ClispError(f"--warm {text!r}: presets are {', '.join(PRESETS)}, or 'all'")
    return names


def cmd_demo(args: argparse.Namespace) -> int:
    from .demo import run_demo                          # deferred: demo loads imageio, metrics, charts (6 ms)
    run_demo(Path(args.out))
    return 0


def _print_devices() -> None:
    for pi, di, platform, device in list_devices():
        print(f"  {pi}:{di}  {platform.name} / {device.name.strip()}")
    print(f"clisp uses: {get_runtime().describe()}  (set CLISP_DEVICE to choose)")


_UNITS = {"": 1, "B": 1, "K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}


def memory_size(text: str) -> int:
    """Bytes from '1073741824', '512M', '1.5G', '2GiB' or '800MB' (binary units); for --mem."""
    value = text.strip().upper().removesuffix("IB").removesuffix("B")
    unit = value[-1:] if value[-1:] in _UNITS else ""
    try:
        size = float(value[:len(value) - len(unit)]) * _UNITS[unit]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a size such as 512M or 2G") from None
    if not 2**20 <= size < 2**60:
        raise argparse.ArgumentTypeError(f"{text!r}: the memory budget must be at least 1M")
    return int(size)


def image_size(text: str) -> tuple[int, int]:
    """(width, height) from 'WxH', e.g. '23040x17280'; for --size."""
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.strip().isdigit() and int(p) > 0 for p in parts):
        raise argparse.ArgumentTypeError(f"{text!r} is not a size such as 5760x4320 (width x height)")
    return int(parts[0]), int(parts[1])


def _check_output_ext(path: str, allowed: tuple[str, ...]) -> None:
    if Path(path).suffix.lower() not in allowed:
        raise ClispError(f"{path}: unsupported output extension; use {', '.join(allowed)}")


def _json_value(value: object) -> object:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return str(value)


def _format_value(value: object) -> str:
    if isinstance(value, np.ndarray):
        return np.array2string(value, precision=4, separator=", ").replace("\n", "")
    if isinstance(value, float):
        return f"{value:.6g}"
    return str(value)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``clisp`` console script; returns the exit status."""
    args = build_parser().parse_args(argv)
    try:
        return run_command(args.func, args)
    finally:
        save_built_programs()      # later processes load these programs' binaries instead of compiling


def run_command(func: "Callable[[argparse.Namespace], int | None]", args: argparse.Namespace) -> int:
    """Run one command and turn its failure into the CLI's contract: one line on stderr of at
    most errors.MAX_MESSAGE characters, exit status 2 (130 for Ctrl-C); no output file is left
    (every writer is atomic). Python warnings raised meanwhile (numpy, libraries) are held back:
    a failure's line names the first one when it has room, a success drops them."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            return int(func(args) or 0)
        except ClispError as exc:
            message = str(exc)
        except MemoryError:
            message = "out of memory; try a smaller --mem or --tile"
        except KeyboardInterrupt:
            print("clisp: interrupted; no output written", file=sys.stderr)
            return 130
    if caught and len(message) < 120:
        message += f" (warning: {clip(caught[0].message, 40)})"
    print(error_line(message), file=sys.stderr)
    return EXIT_ERROR


NORMAL_EXIT_COMMANDS = ("batch",)
"""Commands that leave through the interpreter's teardown: ``batch`` owns a Dask cluster, whose
worker processes are shut down by it."""


def console(argv: Sequence[str] | None = None) -> None:
    """The ``clisp`` console script (and ``python -m clisp``): :func:`main`, then out of the process
    without the interpreter's teardown (module clean-up, the OpenCL context's release: 0.05 s of a
    0.33 s small-raw run on the 2-core CI machine). By then every output file is closed and renamed,
    the kept programs are saved (main) and the streams are flushed here; ``batch``
    (NORMAL_EXIT_COMMANDS) exits normally."""
    arguments = list(sys.argv[1:] if argv is None else argv)
    code = main(arguments)
    if next((a for a in arguments if not a.startswith("-")), None) in NORMAL_EXIT_COMMANDS:
        sys.exit(code)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


if __name__ == "__main__":
    console()
