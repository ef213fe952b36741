"""Whole-process speed of clisp against rawpy, darktable-cli and RawTherapee (issue 11, item 2).

    python tools/bench_peers.py [--size 6000x4000] [--repeat 3] [--baseline DIR] [--only REGEX]
                                [--data DIR] [--work DIR] [--csv PATH] [--results docs/RESULTS.md]

Every command runs as its own process from the command line (start-up, decode, compute, write),
as a user would run it. The inputs, built in ``--work`` (reused when already there):

* a Bayer DNG (clisp's DNG writer) whose mosaic is a real camera's CFA data: the Canon D30 raw
  of ``--data``/raw, cropped to even size and tiled to ``--size``. Without the camera raw (a
  clone without ../shared) it is a Bayer raw simulated by ``clisp simulate --cfa bayer``.
* an LMS raw: ``clisp simulate SCENE --cfa lms --gain 8 --size WxH``, SCENE a Kodak image from
  ``--data``/kodak, or clisp's demo chart when there is none.

Commands: clisp's fast / balanced / quality presets to 16-bit TIFF and to EXR on the Bayer DNG,
quality and fast to both on the LMS raw; the same for a ``--baseline`` clisp source tree
(reported as clisp@REV); rawpy LINEAR / AHD / DHT to 16-bit TIFF; darktable-cli (CPU, OpenCL
off, 16-bit uncompressed TIFF) and rawtherapee-cli (16-bit TIFF, neutral profile) on the Bayer
DNG. A peer that is not installed is reported as absent. One untimed warm-up of every command,
then ``--repeat`` rounds, interleaved (every command once per round), so that drift and other
load hit all alike. Each output is deleted before the run and checked after it (exists, size);
a command that fails is reported as failed with its message, not timed.

Per command: median / min / max wall time (s), MP/s from the median, the child's peak RSS (MiB,
``os.wait4`` rusage; the largest over the timed runs), and ratios clisp time / peer time (below
1: clisp is faster) against rawpy LINEAR, darktable-cli, rawtherapee-cli and the baseline.
The machine is shared: run it under ``flock /tmp/clisp-bench.lock``.
"""
from __future__ import annotations

import argparse
import dataclasses
import datetime
import math
import os
import re
import shlex
import shutil
import statistics
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import toolkit
from toolkit import (NEUTRAL_CWD, REPO, clisp_cmd, cpu_model, describe_output, git_rev, last_line, markers,
                     measure_process, parse_size, repo_env, scene_file, update_results, write_csv)

CAMERA_RAW = "raw/RAW_CANON_D30_SRGB.CRW"
STALE_METADATA = ("flip", "raw_size", "visible_origin", "default_crop", "crop")
"""Camera metadata that no longer describes the tiled mosaic (orientation, sensor geometry)."""

CLISP_BAYER = [(p, f) for p in ("fast", "balanced", "quality") for f in ("tif", "exr")]
CLISP_LMS = [(p, f) for p in ("quality", "fast") for f in ("exr", "tif")]
RAWPY_ALGORITHMS = ("LINEAR", "AHD", "DHT")
RT_BORDER = 8
"""Pixels RawTherapee may drop on every side (its neutral profile's RAW Bayer Border is 4)."""

RAWPY_SCRIPT = """\
import sys, rawpy, tifffile
src, out, algorithm = sys.argv[1:4]
with rawpy.imread(src) as raw:
    rgb = raw.postprocess(demosaic_algorithm=rawpy.DemosaicAlgorithm[algorithm], output_bps=16)
tifffile.imwrite(out, rgb)
"""


@dataclass
class Command:
    """One command line to time, and what its output must look like."""

    tool: str  # clisp, clisp@REV, rawpy, darktable-cli, rawtherapee-cli
    preset: str  # clisp preset, rawpy algorithm, or "default"
    kind: str  # input: bayer or lms
    fmt: str  # output format: tif or exr
    argv: list[str]
    output: Path
    shape: tuple[int, int]  # expected output H, W
    env: dict[str, str] | None = None
    border: int = 0  # pixels the tool may crop on every side
    absent: str = ""  # why the tool cannot run here ("" when it can)

    @property
    def label(self) -> str:
        return f"{self.tool} {self.preset} {self.kind} {self.fmt}"


@dataclass
class Result:
    """The runs of one command: wall times (s) and peak RSS (MiB) of the timed runs."""

    command: Command
    seconds: list[float] = field(default_factory=list)
    rss_mib: list[float] = field(default_factory=list)
    status: str = "ok"  # ok, failed: MESSAGE, absent: WHY
    output: str = ""  # what the output turned out to be, e.g. 6000x4000x3 uint16

    @property
    def median(self) -> float:
        return statistics.median(self.seconds) if self.ok else math.nan

    @property
    def ok(self) -> bool:
        return self.status == "ok" and bool(self.seconds)


# --------------------------------------------------------------------------------------------
# Inputs
# --------------------------------------------------------------------------------------------

def tiled_camera_raw(camera: Path, out: Path, width: int, height: int) -> None:
    """Write ``out``: the camera raw's mosaic (even crop) tiled to height x width, as our DNG."""
    from clisp.io.rawfile import read_raw, write_raw
    raw = read_raw(camera)
    h, w = raw.shape
    big = np.ascontiguousarray(toolkit.repeat_to(raw.data[:h // 2 * 2, :w // 2 * 2], height, width))
    metadata = {k: v for k, v in raw.metadata.items() if k not in STALE_METADATA}
    metadata["tiled_from"] = camera.name
    write_raw(out, dataclasses.replace(raw, data=big, metadata=metadata))


def simulated_raw(scene: Path, out: Path, cfa: str, width: int, height: int) -> None:
    """Write ``out`` with ``clisp simulate SCENE --cfa CFA --gain 8 --size WxH``."""
    argv = clisp_cmd("simulate", str(scene), "-o", str(out), "--cfa", cfa, "--gain", "8",
                     "--size", f"{width}x{height}")
    subprocess.run(argv, env=repo_env(REPO), cwd=NEUTRAL_CWD, check=True, stdout=subprocess.DEVNULL)


def build_inputs(kinds: set[str], data: Path, work: Path, size: tuple[int, int]) -> dict[str, tuple[Path, str]]:
    """The input raw per kind ('bayer', 'lms') and a line saying what it is; reused if present."""
    width, height = size
    inputs: dict[str, tuple[Path, str]] = {}
    if "bayer" in kinds:
        camera = data / CAMERA_RAW
        if camera.is_file():
            path = work / f"bayer-{camera.stem}-{width}x{height}.dng"
            what = f"{camera.name}'s CFA mosaic tiled to {width}x{height}, as clisp DNG"
            if not path.is_file():
                tiled_camera_raw(camera, path, width, height)
        else:
            scene = scene_file(data, work)
            path = work / f"bayer-sim-{scene.stem}-{width}x{height}.dng"
            what = f"simulated Bayer raw (no camera raw in {data}): {scene.name} at gain 8, {width}x{height}"
            if not path.is_file():
                simulated_raw(scene, path, "bayer", width, height)
        inputs["bayer"] = (path, what)
    if "lms" in kinds:
        scene = scene_file(data, work)
        path = work / f"lms-{scene.stem}-{width}x{height}.dng"
        if not path.is_file():
            simulated_raw(scene, path, "lms", width, height)
        inputs["lms"] = (path, f"simulated LMS raw: {scene.name} at gain 8, repeated to {width}x{height}")
    return inputs


# --------------------------------------------------------------------------------------------
# Commands
# --------------------------------------------------------------------------------------------

def clisp_commands(tool: str, root: Path, inputs: dict[str, tuple[Path, str]], out: Path,
                   shape: tuple[int, int]) -> list[Command]:
    """clisp's presets on every input, with the source tree ``root`` on PYTHONPATH."""
    env = repo_env(root)
    tag = tool.replace("@", "-")
    cmds = []
    for kind, runs in (("bayer", CLISP_BAYER), ("lms", CLISP_LMS)):
        if kind not in inputs:
            continue
        for preset, fmt in runs:
            target = out / f"{tag}-{preset}-{kind}.{fmt}"
            argv = clisp_cmd("process", str(inputs[kind][0]), "-o", str(target), "--preset", preset)
            cmds.append(Command(tool, preset, kind, fmt, argv, target, shape, env))
    return cmds


def peer_commands(bayer: Path, out: Path, work: Path, shape: tuple[int, int]) -> list[Command]:
    """rawpy's demosaics, darktable-cli and rawtherapee-cli on the Bayer DNG."""
    cmds = []
    script = work / "rawpy_develop.py"
    script.write_text(RAWPY_SCRIPT)
    for alg in RAWPY_ALGORITHMS:
        target = out / f"rawpy-{alg}.tif"
        cmds.append(Command("rawpy", alg, "bayer", "tif", [sys.executable, str(script), str(bayer), str(target), alg],
                            target, shape))
    target = out / "darktable.tif"
    dt = shutil.which("darktable-cli")
    argv = [dt or "darktable-cli", str(bayer), str(target), "--core", "--disable-opencl",
            "--configdir", str(work / "darktable-config"), "--library", ":memory:",
            "--conf", "plugins/imageio/format/tiff/bpp=16", "--conf", "plugins/imageio/format/tiff/compress=0"]
    cmds.append(Command("darktable-cli", "default", "bayer", "tif", argv, target, shape,
                        absent="" if dt else "darktable-cli not installed"))
    target = out / "rawtherapee.tif"
    rt = shutil.which("rawtherapee-cli")
    argv = [rt or "rawtherapee-cli", "-t", "-b16", "-Y", "-o", str(target), "-c", str(bayer)]
    cmds.append(Command("rawtherapee-cli", "default", "bayer", "tif", argv, target, shape, border=RT_BORDER,
                        absent="" if rt else "rawtherapee-cli not installed"))
    return cmds


# --------------------------------------------------------------------------------------------
# Running
# --------------------------------------------------------------------------------------------

def run_once(cmd: Command) -> tuple[float, float, str]:
    """Run ``cmd`` once as its own process (toolkit.measure_process: started from a small launcher,
    so that its peak RSS is its own): (wall s, child's peak RSS MiB, '' or the failure message)."""
    cmd.output.unlink(missing_ok=True)
    run = measure_process(cmd.argv, cmd.env)
    if not run.started:
        return math.nan, math.nan, f"could not start: {last_line(run.stderr)}"
    if run.code != 0:
        said = last_line("\n".join((run.stdout, run.stderr)))
        return run.wall_s, run.peak_mib, f"exit {run.code}: {said}"
    return run.wall_s, run.peak_mib, check_output(cmd)


def check_output(cmd: Command) -> str:
    """'' when ``cmd`` wrote its output with the expected size (and 16-bit for TIFF), else why not."""
    if not cmd.output.is_file():
        return f"no output file {cmd.output.name}"
    try:
        h, w, c, fmt = describe_output(cmd.output)
    except (ValueError, OSError) as exc:
        return f"{cmd.output.name}: {exc}"
    (eh, ew), b = cmd.shape, 2 * cmd.border
    if not (eh - b <= h <= eh and ew - b <= w <= ew) or c < 3:
        crop = f" (less up to {b})" if b else ""
        return f"{cmd.output.name} is {w}x{h}x{c}, expected {ew}x{eh}x3{crop}"
    if cmd.fmt == "tif" and fmt != "uint16":
        return f"{cmd.output.name} is {fmt}, expected 16-bit"
    return ""


def output_note(cmd: Command) -> str:
    """What a command's output is, e.g. '6000x4000x3 uint16, 137 MiB' ('' when unreadable)."""
    try:
        h, w, c, fmt = describe_output(cmd.output)
    except (ValueError, OSError):
        return ""
    return f"{w}x{h}x{c} {fmt}, {cmd.output.stat().st_size / 2**20:.0f} MiB"


def run_all(cmds: list[Command], repeat: int, verbose: bool = True) -> list[Result]:
    """Warm-up of every command, then ``repeat`` interleaved rounds; a failure ends that command."""
    results = [Result(c, status=f"absent: {c.absent}" if c.absent else "ok") for c in cmds]
    for rnd in range(repeat + 1):
        for res in results:
            if res.status != "ok":
                continue
            wall, rss, error = run_once(res.command)
            if error:
                res.status = f"failed: {error}"
            elif rnd == 0:
                res.output = output_note(res.command)
            else:
                res.seconds.append(wall)
                res.rss_mib.append(rss)
            if verbose:
                what = "warm-up" if rnd == 0 else f"round {rnd}/{repeat}"
                print(f"  {what:>11}  {res.command.label:<40} {wall:7.2f} s  {rss:6.0f} MiB"
                      f"{'  ' + res.status if error else ''}", file=sys.stderr, flush=True)
            res.command.output.unlink(missing_ok=True)
    return results


# --------------------------------------------------------------------------------------------
# Reporting
# --------------------------------------------------------------------------------------------

def reference(results: list[Result], tool: str, preset: str = "") -> Result | None:
    """The first successful result of ``tool`` (and ``preset`` if given) on the Bayer input."""
    for r in results:
        if r.ok and r.command.tool == tool and r.command.kind == "bayer" and preset in ("", r.command.preset):
            return r
    return None


def ratio(ours: Result, peer: Result | None) -> float:
    """ours / peer median time (NaN when either is missing)."""
    return ours.median / peer.median if peer is not None and ours.ok else math.nan


def rows_for(results: list[Result], megapixels: float, baseline: str | None) -> list[dict[str, object]]:
    """One row per command: times, MP/s, RSS, output and ratios to the peers and the baseline."""
    peers = {"vs rawpy LINEAR": reference(results, "rawpy", "LINEAR"),
             "vs darktable": reference(results, "darktable-cli"),
             "vs RawTherapee": reference(results, "rawtherapee-cli")}
    rows = []
    for r in results:
        c = r.command
        row: dict[str, object] = dict(tool=c.tool, preset=c.preset, input=c.kind, output_format=c.fmt,
                                      median_s=r.median, min_s=min(r.seconds) if r.ok else math.nan,
                                      max_s=max(r.seconds) if r.ok else math.nan,
                                      mp_per_s=megapixels / r.median if r.ok else math.nan,
                                      peak_rss_mib=max(r.rss_mib) if r.ok else math.nan,
                                      runs=len(r.seconds), status=r.status, output=r.output)
        mine = c.tool.startswith("clisp")
        for name, peer in peers.items():
            row[name] = ratio(r, peer) if mine else math.nan
        base = next((b for b in results if baseline and b.command.tool == baseline and c.tool == "clisp"
                     and (b.command.preset, b.command.kind, b.command.fmt) == (c.preset, c.kind, c.fmt)), None)
        row["vs baseline"] = ratio(r, base)
        rows.append(row)
    return rows


RATIO_COLUMNS = ("vs rawpy LINEAR", "vs darktable", "vs RawTherapee", "vs baseline")


def fmt(value: object, digits: int = 2) -> str:
    """A table cell: numbers with ``digits`` decimals, '' for NaN."""
    if isinstance(value, float):
        return "" if math.isnan(value) else f"{value:.{digits}f}"
    return str(value)


def table(rows: list[dict[str, object]]) -> list[str]:
    """The results as a Markdown table (ratios: clisp time / peer time, below 1: clisp faster)."""
    used = [k for k in RATIO_COLUMNS if any(not math.isnan(float(r[k])) for r in rows)]  # type: ignore[arg-type]
    head = ["command", "median s", "min s", "max s", "MP/s", "peak RSS MiB", *used, "output"]
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join(["---"] + ["---:"] * (len(head) - 2) + ["---"]) + "|"]
    for r in rows:
        name = f"{r['tool']} {r['preset']} {r['input']}→{r['output_format']}"
        if r["status"] != "ok":
            lines.append(f"| {name} | {r['status']} |" + " |" * (len(head) - 2))
            continue
        cells = [name, fmt(r["median_s"]), fmt(r["min_s"]), fmt(r["max_s"]), fmt(r["mp_per_s"]),
                 fmt(r["peak_rss_mib"], 0), *(fmt(r[k]) for k in used), str(r["output"])]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def first_line(argv: list[str], pattern: str = "") -> str:
    """The first output line of ``argv`` matching ``pattern`` ('' if it cannot run)."""
    try:
        out = subprocess.run(argv, capture_output=True, text=True, timeout=60, env=repo_env(REPO), cwd=NEUTRAL_CWD)
    except (OSError, subprocess.TimeoutExpired):
        return ""
    lines = [line.strip() for line in (out.stdout + out.stderr).splitlines() if re.search(pattern, line)]
    return lines[0] if lines else ""


def versions() -> dict[str, str]:
    """Versions of clisp, rawpy/LibRaw, darktable-cli and rawtherapee-cli ('absent' if missing)."""
    import rawpy
    found = {"clisp": f"{first_line(clisp_cmd('--version'))} ({git_rev(REPO)})",
             "rawpy": f"rawpy {rawpy.__version__}, LibRaw {rawpy.libraw_version}"}
    for tool, pattern in (("darktable-cli", "darktable"), ("rawtherapee-cli", "version")):
        found[tool] = first_line([tool, "--version" if tool == "darktable-cli" else "-v"], pattern) \
            if shutil.which(tool) else "absent"
    return found


def machine_lines(inputs: dict[str, tuple[Path, str]]) -> list[str]:
    """The machine, OpenCL device, tool versions and inputs, as Markdown list items."""
    device = first_line(clisp_cmd("info", "--device"), "clisp uses") or "unknown"
    lines = [f"- Machine: {cpu_model()}, {os.cpu_count()} cores; OpenCL: {device.removeprefix('clisp uses: ')}"]
    lines += [f"- {tool}: {v}" for tool, v in versions().items()]
    lines += [f"- Input {kind}: {what}" for kind, (_, what) in inputs.items()]
    return lines


MARK_START, MARK_END = markers("bench_peers")
SECTION_TITLE = "## Whole-process speed against peers (tools/bench_peers.py)"


def section(rows: list[dict[str, object]], header: list[str], argv: list[str]) -> str:
    """The RESULTS.md section, between its markers."""
    body = [MARK_START, SECTION_TITLE, "",
            f"Measured {datetime.date.today().isoformat()} with `{' '.join(shlex.quote(a) for a in argv)}`.",
            "", *header, "",
            "Each command is a whole process (start-up, decode, compute, write) run from the command line; "
            "one untimed warm-up each, then interleaved rounds. Ratios are clisp time / peer time "
            "(below 1: clisp is faster), the peers' on the Bayer input (for the LMS rows too: same pixel "
            "count, other sensor); peak RSS is the child process's, the largest over the timed runs. Peers: "
            "rawpy postprocess defaults (auto-bright, sRGB gamma) with the named demosaic; darktable-cli with its "
            "default pipeline, OpenCL off, 16-bit uncompressed TIFF; rawtherapee-cli with its neutral profile "
            "(AMaZE; it crops a 4 px border).", "",
            *table(rows), MARK_END]
    return "\n".join(body) + "\n"


# --------------------------------------------------------------------------------------------
# Main
# --------------------------------------------------------------------------------------------

def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--size", type=parse_size, default=(6000, 4000), metavar="WxH", help="image size (default 6000x4000)")
    toolkit.add_repeat_option(p, 3, "timed runs per command, median kept")
    p.add_argument("--baseline", type=Path, default=None, metavar="DIR", help="another clisp source tree to time too")
    p.add_argument("--only", default=None, metavar="REGEX",
                   help="run only commands whose label ('TOOL PRESET INPUT FORMAT', e.g. 'clisp fast bayer tif') matches")
    toolkit.add_data_option(p, "raw/ and kodak/")
    toolkit.add_work_option(p, "inputs and outputs")
    p.add_argument("--csv", type=Path, default=None, help="write one row per command here")
    p.add_argument("--results", type=Path, default=None, help="update this Markdown file's bench_peers section")
    p.add_argument("--quiet", action="store_true", help="no per-run progress on stderr")
    return p.parse_args(argv)


def planned_commands(args: argparse.Namespace, work: Path) -> tuple[list[Command], dict[str, tuple[Path, str]]]:
    """Build the needed inputs and the commands --only selects."""
    width, height = args.size
    shape = (height, width)
    out = work / "out"
    out.mkdir(parents=True, exist_ok=True)
    placeholder = {k: (work / f"{k}.dng", "") for k in ("bayer", "lms")}
    tools = [("clisp", REPO)]
    if args.baseline:
        tools.append((f"clisp@{git_rev(args.baseline)}", args.baseline.resolve()))

    def plan(inputs: dict[str, tuple[Path, str]]) -> list[Command]:
        cmds = [c for tool, root in tools for c in clisp_commands(tool, root, inputs, out, shape)]
        cmds += peer_commands(inputs["bayer"][0], out, work, shape)
        return [c for c in cmds if not args.only or re.search(args.only, c.label)]

    kinds = {c.kind for c in plan(placeholder)}
    inputs = build_inputs(kinds, args.data, work, args.size)
    return plan({**placeholder, **inputs}), inputs


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    with toolkit.work_folder(args.work, "bench_peers-") as work:
        cmds, inputs = planned_commands(args, work)
        if not cmds:
            print(f"bench_peers: no command matches --only {args.only!r}", file=sys.stderr)
            return 2
        results = run_all(cmds, args.repeat, verbose=not args.quiet)
        width, height = args.size
        baseline = next((c.tool for c in cmds if c.tool.startswith("clisp@")), None)
        rows = rows_for(results, width * height / 1e6, baseline)
        header = machine_lines(inputs) + [f"- Size: {width}x{height} ({width * height / 1e6:.1f} MP), "
                                          f"median of {args.repeat} runs"]
        print("\n".join(header + [""] + table(rows)), flush=True)
        if args.csv:
            write_csv(rows, args.csv)
        if args.results:
            update_results(args.results, section(rows, header, ["python", "tools/bench_peers.py", *(argv or sys.argv[1:])]),
                           "bench_peers")
    return 0 if all(r.ok or r.status.startswith("absent") for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
