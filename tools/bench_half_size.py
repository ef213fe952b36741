"""--half-size against the fast preset and rawpy's half_size (issue 31, item 3): whole-process
speed, and a quality check.

    python tools/bench_half_size.py [--repeat 5] [--size 6000x4000] [--data DIR] [--work DIR]
                                    [--crop-png docs/half_size/crop.png] [--results docs/RESULTS.md]

Input: tools/bench_peers.py's Bayer DNG, the Canon D30's CFA mosaic (``--data``/raw) tiled to
``--size`` (a simulated Bayer raw without the camera raw), built in ``--work`` when missing and
reused otherwise (``--work /tmp/peers`` shares bench_peers' file).

Speed: three commands, each a whole process from the command line (start-up, decode, compute,
write), one untimed warm-up each, then ``--repeat`` interleaved rounds (bench_peers.run_all), medians:

* ``clisp process RAW -o fast.tif --preset fast`` (16-bit TIFF, full size);
* ``clisp process RAW -o half.tif --half-size`` (16-bit TIFF, half the width and height);
* rawpy ``postprocess(half_size=True, output_bps=16)`` written by tifffile (the peer: LibRaw's
  half-size path, one of the two G of each cell, its defaults otherwise).

and, as a fourth, the process's floor: ``clisp process SMALL -o floor.tif --half-size`` on the same
camera's mosaic at FLOOR_SIZE (start-up, imports, OpenCL, writer: what any clisp process pays).

Printed: the CPU, the load average before and after, the table, and the ratio of the medians
half / fast against the target 0.5 (met or not met).

Quality: the half-size output against the fast preset's downscaled 2x by box averaging (2 x 2
means of its 16-bit codes), PSNR in sRGB (codes / 65535, 10 px border). ``--crop-png``: a
comparison of one region, side by side with 4 px gaps: the fast preset at full size, the fast
preset box-averaged 2x, the half-size output (both enlarged 2x, nearest, to the same size).
"""
from __future__ import annotations

import argparse
import datetime
import math
import os
import shlex
import sys
import tempfile
from pathlib import Path

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path
from toolkit import REPO, clisp_cmd, cpu_model, markers, parse_size, repo_env, update_results
from bench_peers import Command, Result, build_inputs, fmt, run_all, run_once

TARGET = 0.5
"""Issue 31: --half-size at most this share of the fast preset's whole-process time."""

FLOOR_SIZE = (512, 384)
"""The small raw of the floor row (W, H): 0.2 MP, so its time is the process's, not the pixels'."""

CROP = (220, 1140, 360, 360)
"""(top, left, height, width) of the comparison crop on the full-size image (even, so that it
halves exactly): the D30 scene's lighter wheel and red cap (teeth, edges, saturated colour)."""

RAWPY_HALF = """\
import sys, rawpy, tifffile
src, out = sys.argv[1:3]
with rawpy.imread(src) as raw:
    rgb = raw.postprocess(half_size=True, output_bps=16)
tifffile.imwrite(out, rgb)
"""


def commands(raw: Path, small: Path, out: Path, work: Path, size: tuple[int, int]) -> list[Command]:
    """fast, half-size and rawpy half_size on ``raw`` (W x H = ``size``), half-size on ``small``."""
    width, height = size
    full, half = (height, width), ((height + 1) // 2, (width + 1) // 2)
    env = repo_env(REPO)
    script = work / "rawpy_half_size.py"
    script.write_text(RAWPY_HALF)
    return [Command("clisp", "fast", "bayer", "tif",
                    clisp_cmd("process", str(raw), "-o", str(out / "fast.tif"), "--preset", "fast"),
                    out / "fast.tif", full, env),
            Command("clisp", "--half-size", "bayer", "tif",
                    clisp_cmd("process", str(raw), "-o", str(out / "half.tif"), "--half-size"),
                    out / "half.tif", half, env),
            Command("rawpy", "half_size", "bayer", "tif", [sys.executable, str(script), str(raw), str(out / "rawpy.tif")],
                    out / "rawpy.tif", half),
            Command("clisp", f"--half-size, {FLOOR_SIZE[0]}x{FLOOR_SIZE[1]} raw (floor)", "bayer", "tif",
                    clisp_cmd("process", str(small), "-o", str(out / "floor.tif"), "--half-size"),
                    out / "floor.tif", (FLOOR_SIZE[1] // 2, FLOOR_SIZE[0] // 2), env)]


def box2(image: np.ndarray) -> np.ndarray:
    """2 x 2 box means of an H x W x C image (H, W even), float64."""
    h, w = image.shape[0] // 2 * 2, image.shape[1] // 2 * 2
    x = image[:h, :w].astype(np.float64)
    return (x[0::2, 0::2] + x[0::2, 1::2] + x[1::2, 0::2] + x[1::2, 1::2]) / 4.0


def quality(fast: Command, half: Command, crop_png: Path | None) -> tuple[float, str]:
    """(PSNR of the half-size output against the fast one box-averaged 2x, in sRGB; a line on the
    crop PNG written or ''). Runs both commands once more, untimed, to keep their outputs."""
    import tifffile
    for cmd in (fast, half):
        _, _, error = run_once(cmd)
        if error:
            raise SystemExit(f"{cmd.label}: {error}")
    full = tifffile.imread(fast.output).astype(np.float64) / 65535.0
    small = tifffile.imread(half.output).astype(np.float64) / 65535.0
    reference = box2(full)
    h, w = min(small.shape[0], reference.shape[0]), min(small.shape[1], reference.shape[1])
    score = toolkit.cpsnr(small[:h, :w], reference[:h, :w])
    note = ""
    if crop_png is not None:
        top, left, ch, cw = CROP
        if top + ch > full.shape[0] or left + cw > full.shape[1]:
            top, left = (full.shape[0] - ch) // 4 * 2, (full.shape[1] - cw) // 4 * 2
        region = (slice(top // 2, (top + ch) // 2), slice(left // 2, (left + cw) // 2))
        enlarge = lambda a: np.repeat(np.repeat(a, 2, axis=0), 2, axis=1)   # noqa: E731
        panels = [full[top:top + ch, left:left + cw], enlarge(reference[region]), enlarge(small[region])]
        gap = np.ones((ch, 4, 3))
        row = np.concatenate([panels[0], gap, panels[1], gap, panels[2]], axis=1)
        from PIL import Image
        crop_png.parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(np.round(np.clip(row, 0, 1) * 255).astype(np.uint8)).save(crop_png)
        note = (f"{crop_png}: rows {top}..{top + ch}, columns {left}..{left + cw} of the full-size image; left to "
                f"right: fast (full size), fast box-averaged 2x, --half-size (both enlarged 2x, nearest)")
    for cmd in (fast, half):
        cmd.output.unlink(missing_ok=True)
    return score, note


def table(results: list[Result], megapixels: float) -> list[str]:
    """Markdown rows: median / min / max s, MP/s of the raw (of ``megapixels``; not for the floor),
    peak RSS, output."""
    lines = ["| command | median s | min s | max s | raw MP/s | peak RSS MiB | output |",
             "|---|---:|---:|---:|---:|---:|---|"]
    for r in results:
        c = r.command
        if not r.ok:
            lines.append(f"| {c.tool} {c.preset} | {r.status} | | | | | |")
            continue
        rate = "" if "floor" in c.preset else fmt(megapixels / r.median, 1)
        lines.append(f"| {c.tool} {c.preset} | {fmt(r.median)} | {fmt(min(r.seconds))} | {fmt(max(r.seconds))} | "
                     f"{rate} | {max(r.rss_mib):.0f} | {r.output} |")
    return lines


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--size", type=parse_size, default=(6000, 4000), metavar="WxH", help="image size (default 6000x4000)")
    toolkit.add_repeat_option(p, 5, "timed runs per command, interleaved, median kept")
    toolkit.add_data_option(p, "raw/ (the Canon D30 raw)")
    toolkit.add_work_option(p, "the input raw and the outputs")
    p.add_argument("--crop-png", type=Path, default=None, metavar="PNG", help="write the crop comparison here")
    p.add_argument("--results", type=Path, default=None, help="update this Markdown file's bench_half_size section")
    p.add_argument("--quiet", action="store_true", help="no per-run progress on stderr")
    args = p.parse_args(argv)
    with toolkit.work_folder(args.work, "bench_half_size-") as work:
        raw, what = build_inputs({"bayer"}, args.data, work, args.size)["bayer"]
        small = build_inputs({"bayer"}, args.data, work, FLOOR_SIZE)["bayer"][0]
        out = Path(tempfile.mkdtemp(prefix="half-out-", dir=work))
        cmds = commands(raw, small, out, work, args.size)
        load_before = os.getloadavg()
        results = run_all(cmds, args.repeat, verbose=not args.quiet)
        load_after = os.getloadavg()
        width, height = args.size
        fast, half = results[0], results[1]
        ratio = half.median / fast.median if fast.ok and half.ok else math.nan
        verdict = "met" if ratio <= TARGET else "not met"
        score, note = quality(cmds[0], cmds[1], args.crop_png) if fast.ok and half.ok else (math.nan, "")
        out.rmdir()
        header = [f"- CPU: {cpu_model()}, {os.cpu_count()} cores; load average (1 min) {load_before[0]:.2f} "
                  f"before, {load_after[0]:.2f} after",
                  f"- Input: {what} ({width * height / 1e6:.1f} MP)",
                  f"- Median of {args.repeat} interleaved runs per command, after one warm-up each"]
        summary = [f"**--half-size / fast: {fmt(ratio)}** (target at most {TARGET}: {verdict})",
                   f"Quality: --half-size against the fast preset box-averaged 2x: PSNR {fmt(score)} dB (sRGB, "
                   f"{toolkit.BORDER} px border)"]
        print("\n".join(header + [""] + table(results, width * height / 1e6) + [""] + summary + ([note] if note else [])),
              flush=True)
        if args.results:
            start, end = markers("bench_half_size")
            argv_text = " ".join(shlex.quote(a) for a in ["python", "tools/bench_half_size.py", *(argv or sys.argv[1:])])
            body = [start, "### The measured skip (tools/bench_half_size.py)", "",
                    f"Measured {datetime.date.today().isoformat()} with `{argv_text}`.", "", *header, "",
                    *table(results, width * height / 1e6), "", *(f"{line}." if not line.endswith(")") else line
                                                                 for line in summary), end]
            update_results(args.results, "\n".join(body) + "\n", "bench_half_size")
    return 0 if all(r.ok for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
