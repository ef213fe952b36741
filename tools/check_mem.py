"""Check that ``clisp process --mem`` bounds the peak resident memory of the whole process (issue 11).

    python tools/check_mem.py [--sizes 6000x4000,23040x17360] [--presets fast,balanced,quality]
                              [--mems 1G,2G] [--formats exr,tif] [--cfas lms,bayer] [--only REGEX]
                              [--refuse-mem 150M | --no-refusal] [--clisp DIR] [--data DIR]
                              [--work DIR] [--csv PATH] [--results docs/RESULTS.md] [--quiet]

Inputs, made in ``--work`` (reused when already there): LMS and Bayer raws of every ``--sizes``
by ``clisp simulate SCENE --cfa lms|bayer --gain 8 --size WxH``, SCENE a Kodak image of
``--data``/kodak, or clisp's demo chart (written to a PNG) when there is none.

Runs: every input x preset x ``--mem`` x output format (EXR, 16-bit TIFF) as its own
``clisp process`` process, with ``--clisp DIR``'s source first on PYTHONPATH. Per run: the
process's peak RSS (MiB), headroom (--mem - peak, MiB), pass/FAIL (FAIL: peak above --mem, a
non-zero exit, or an output that is missing or of the wrong size/type), wall time (s) and the
tiles clisp reports. Each output is deleted after its run (400 MP outputs are gigabytes).

Peak RSS: ``ru_maxrss`` (KiB on Linux) of ``os.wait4`` on the clisp process. A process's
ru_maxrss starts from the RSS of the process it was forked from (Linux keeps it across exec), so
clisp is started by a tiny launcher (``python -S``, about 10 MiB) that waits for it and reports its
rusage; the floor is checked with ``true`` and a 256 MiB allocation (also against
``/usr/bin/time -v`` when present) before the runs.

Refusal: for every input x preset x format, ``--mem --refuse-mem`` (default 150M, far below the
minimum) must exit 2 with one line on stderr naming the output and the minimum, and leave no
output; that line also gives the planner's figures (what the process holds when planning, with
clisp.engine.memory.RSS_MARGIN, and the smallest tile), shown per row as "min --mem".

Exit status 1 if any run or refusal check failed, 2 if nothing matched ``--only``.
Peak RSS does not depend on load; wall times do (the machine may be shared).
"""
from __future__ import annotations

import argparse
import datetime
import math
import os
import platform
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import toolkit
from toolkit import (NEUTRAL_CWD, REPO, ProcessRun, clisp_cmd, describe_output, markers, measure_process, parse_size,
                     write_csv)
from toolkit import repo_env as clisp_env

PRESETS = ("fast", "balanced", "quality", "best")
DEFAULT_PRESETS = ("fast", "balanced", "quality")
"""best (ARI, about a minute per 24 MP) only on request."""
FORMATS = ("exr", "tif")
CFAS = ("lms", "bayer")
MIB = 2**20

MARK_START, MARK_END = markers("check_mem")
SECTION_TITLE = "## Peak memory against --mem (tools/check_mem.py)"

# --------------------------------------------------------------------------------------------
# Arguments
# --------------------------------------------------------------------------------------------

def parse_mem(text: str) -> int:
    """Bytes from '512M', '1G', '1.5G' (binary units, as clisp's --mem)."""
    units = {"K": 2**10, "M": 2**20, "G": 2**30, "T": 2**40}
    value = text.strip().upper().removesuffix("IB").removesuffix("B")
    try:
        return int(float(value[:-1]) * units[value[-1]]) if value[-1:] in units else int(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a size such as 512M or 2G") from None


def listed(choices: tuple[str, ...]):
    """argparse type: a comma-separated subset of ``choices``."""
    def parse(text: str) -> list[str]:
        items = [v.strip() for v in text.split(",") if v.strip()]
        bad = [v for v in items if v not in choices]
        if bad or not items:
            raise argparse.ArgumentTypeError(f"{text!r}: choose from {', '.join(choices)}")
        return items
    return parse


def comma_list(kind):
    """argparse type: a comma-separated list of ``kind``."""
    return lambda text: [kind(v.strip()) for v in text.split(",") if v.strip()]


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sizes", type=comma_list(parse_size), default=[(6000, 4000), (23040, 17360)], metavar="WxH,...",
                   help="raw sizes (default 6000x4000,23040x17360: 24 and 400 MP)")
    p.add_argument("--presets", type=listed(PRESETS), default=list(DEFAULT_PRESETS),
                   help="of fast, balanced, quality, best (default fast,balanced,quality)")
    p.add_argument("--mems", type=comma_list(str), default=["1G", "2G"], help="--mem values (default 1G,2G)")
    p.add_argument("--formats", type=listed(FORMATS), default=list(FORMATS), help="outputs (default exr,tif)")
    p.add_argument("--cfas", type=listed(CFAS), default=list(CFAS), help="inputs (default lms,bayer)")
    p.add_argument("--only", default=None, metavar="REGEX",
                   help="only runs whose label matches, e.g. 'lms 24MP quality exr 1G'")
    p.add_argument("--refuse-mem", default="150M", metavar="SIZE", help="--mem far below the minimum (default 150M)")
    p.add_argument("--no-refusal", action="store_true", help="skip the refusal checks")
    p.add_argument("--clisp", type=Path, default=REPO, help=f"clisp checkout under test (default {REPO})")
    toolkit.add_data_option(p, "kodak/")
    toolkit.add_work_option(p)
    p.add_argument("--csv", type=Path, default=None, help="write one row per run here")
    p.add_argument("--results", type=Path, default=None, help="update this Markdown file's check_mem section")
    p.add_argument("--quiet", action="store_true", help="no per-run progress on stderr")
    args = p.parse_args(argv)
    for text in [*args.mems, args.refuse_mem]:
        parse_mem(text)                                  # fail early on a bad size
    args.clisp = args.clisp.resolve()
    return args


# --------------------------------------------------------------------------------------------
# Inputs
# --------------------------------------------------------------------------------------------

def size_label(size: tuple[int, int]) -> str:
    """'24MP', '400MP', '0.12MP': megapixels to 3 significant digits."""
    return f"{size[0] * size[1] / 1e6:.3g}MP"


def make_raw(scene: Path, cfa: str, size: tuple[int, int], work: Path, root: Path) -> Path:
    """``work``/CFA-SCENE-WxH.dng by ``clisp simulate --gain 8 --size``; reused when present."""
    w, h = size
    path = work / f"{cfa}-{scene.stem}-{w}x{h}.dng"
    if not path.is_file():
        part = path.with_suffix(".part.dng")
        argv = clisp_cmd("simulate", str(scene), "-o", str(part), "--cfa", cfa, "--gain", "8", "--size", f"{w}x{h}")
        subprocess.run(argv, env=clisp_env(root), cwd=NEUTRAL_CWD, check=True, stdout=subprocess.DEVNULL)
        part.rename(path)
    return path


# --------------------------------------------------------------------------------------------
# Runs
# --------------------------------------------------------------------------------------------

@dataclass
class Run:
    """One ``clisp process`` to measure."""

    cfa: str
    size: tuple[int, int]  # W, H
    preset: str
    fmt: str  # exr or tif
    mem: str  # --mem as given, e.g. 1G

    @property
    def label(self) -> str:
        return f"{self.cfa} {size_label(self.size)} {self.preset} {self.fmt} {self.mem}"

    @property
    def mem_mib(self) -> float:
        return parse_mem(self.mem) / MIB


@dataclass
class Result:
    """A run's figures and verdict."""

    run: Run
    measured: ProcessRun | None = None
    tiles: int = 0
    tile_w: int = 0
    tile_h: int = 0
    problems: list[str] = field(default_factory=list)  # why it failed ([] = pass)

    @property
    def ok(self) -> bool:
        return self.measured is not None and not self.problems

    @property
    def headroom_mib(self) -> float:
        return self.run.mem_mib - self.measured.peak_mib if self.measured else math.nan


def time_v_peak_mib(argv: list[str]) -> float:
    """Peak RSS (MiB) of ``argv`` by ``/usr/bin/time -v``'s 'Maximum resident set size' (NaN without it)."""
    if not Path("/usr/bin/time").is_file():
        return math.nan
    done = subprocess.run(["/usr/bin/time", "-v", *argv], capture_output=True, text=True)
    found = re.search(r"Maximum resident set size \(kbytes\): (\d+)", done.stderr)
    return int(found.group(1)) / 1024 if found else math.nan


ALLOC_MIB = 256


def launcher_check() -> tuple[bool, str]:
    """(ok, summary): the launcher's floor (``true``) and a touched 256 MiB allocation, which must
    read 256 MiB plus an interpreter (and agree with /usr/bin/time -v)."""
    floor = measure_process(["true"]).peak_mib
    alloc = [sys.executable, "-S", "-c", f"b = b'x' * ({ALLOC_MIB} * 2**20)"]
    got = measure_process(alloc).peak_mib
    ref = time_v_peak_mib(alloc)
    ok = floor < 32 and ALLOC_MIB <= got < ALLOC_MIB + 48 and (math.isnan(ref) or abs(got - ref) < 8)
    text = (f"peak RSS of `true` {floor:.1f} MiB; of a touched {ALLOC_MIB} MiB allocation in python -S "
            f"{got:.1f} MiB" + ("" if math.isnan(ref) else f" (/usr/bin/time -v: {ref:.1f} MiB)"))
    return ok, text + ("" if ok else " — MEASUREMENT SUSPECT")


TILES_RE = re.compile(r"(\d+) tiles? of (\d+)x(\d+)")


def output_problem(path: Path, run: Run) -> str:
    """'' when ``path`` is a W x H x 3 image (16-bit for TIFF), else what is wrong."""
    if not path.is_file():
        return "no output file"
    try:
        h, w, c, pixel = describe_output(path)
    except (ValueError, OSError, ImportError) as exc:
        return f"output unreadable: {exc}"
    if (w, h) != run.size or c < 3:
        return f"output is {w}x{h}x{c}, expected {run.size[0]}x{run.size[1]}x3"
    if run.fmt == "tif" and pixel != "uint16":
        return f"output is {pixel}, expected 16-bit"
    return ""


def process_argv(raw: Path, out: Path, preset: str, mem: str) -> list[str]:
    """``clisp process RAW -o OUT --preset P --mem M``."""
    return clisp_cmd("process", str(raw), "-o", str(out), "--preset", preset, "--mem", mem)


def run_one(run: Run, raw: Path, outdir: Path, root: Path) -> Result:
    """Run ``run``: measure, check the output and the peak against --mem, delete the output."""
    out = outdir / f"{run.cfa}-{run.size[0]}x{run.size[1]}-{run.preset}-{run.mem}.{run.fmt}"
    out.unlink(missing_ok=True)
    m = measure_process(process_argv(raw, out, run.preset, run.mem), clisp_env(root))
    res = Result(run, m)
    found = TILES_RE.search(m.stdout)
    if found:
        res.tiles, res.tile_w, res.tile_h = (int(v) for v in found.groups())
    if m.code != 0:
        res.problems.append(f"exit {m.code}: {toolkit.last_line(m.stderr, limit=300)}")
    else:
        problem = output_problem(out, run)
        if problem:
            res.problems.append(problem)
    if not m.peak_mib <= run.mem_mib:
        res.problems.append(f"peak {m.peak_mib:.0f} MiB above --mem {run.mem}")
    out.unlink(missing_ok=True)
    return res


# --------------------------------------------------------------------------------------------
# Refusal
# --------------------------------------------------------------------------------------------

MIN_RE = re.compile(r"minimum of (\S+) .*?\((\S+) for the process itself, (\S+) for the smallest tile\)")


@dataclass
class Refusal:
    """``--mem`` far below the minimum for one input, preset and format: what clisp said."""

    cfa: str
    size: tuple[int, int]
    preset: str
    fmt: str
    mem: str
    code: int = 0
    line: str = ""  # clisp's stderr (one line expected)
    minimum: str = ""  # the minimum it named, e.g. 227M
    held: str = ""  # planner: what the process holds when planning, with RSS_MARGIN
    smallest: str = ""  # planner: the smallest tile's bytes
    problems: list[str] = field(default_factory=list)

    @property
    def key(self) -> tuple[str, tuple[int, int], str, str]:
        return self.cfa, self.size, self.preset, self.fmt


def check_refusal(ref: Refusal, raw: Path, outdir: Path, root: Path) -> Refusal:
    """Run with ``--mem ref.mem``: exit 2, one stderr line naming the output and a minimum, no file."""
    out = outdir / f"refuse-{ref.cfa}-{ref.size[0]}x{ref.size[1]}-{ref.preset}.{ref.fmt}"
    out.unlink(missing_ok=True)
    m = measure_process(process_argv(raw, out, ref.preset, ref.mem), clisp_env(root))
    lines = [line for line in m.stderr.splitlines() if line.strip()]
    ref.code, ref.line = m.code, " / ".join(lines)
    found = MIN_RE.search(ref.line)
    if found:
        ref.minimum, ref.held, ref.smallest = found.groups()
    if m.code != 2:
        ref.problems.append(f"exit {m.code}, expected 2")
    if len(lines) != 1:
        ref.problems.append(f"{len(lines)} lines on stderr, expected 1")
    if out.name not in ref.line:                  # long folders are shortened to .../ (200 characters)
        ref.problems.append("does not name the output")
    if not found:
        ref.problems.append("names no minimum")
    if out.exists():
        ref.problems.append("left an output file")
        out.unlink()
    return ref


# --------------------------------------------------------------------------------------------
# Reporting
# --------------------------------------------------------------------------------------------

def fmt_num(value: float, digits: int = 0) -> str:
    """A number with ``digits`` decimals, '' for NaN."""
    return "" if math.isnan(value) else f"{value:.{digits}f}"


def row_for(res: Result, refusals: dict[tuple, Refusal]) -> dict[str, object]:
    """One CSV/table row."""
    r, m = res.run, res.measured
    ref = refusals.get((r.cfa, r.size, r.preset, r.fmt))
    return dict(label=r.label, input=f"{r.cfa} {size_label(r.size)}", cfa=r.cfa, width=r.size[0], height=r.size[1],
                preset=r.preset, output_format=r.fmt, mem=r.mem, mem_mib=round(r.mem_mib, 1),
                peak_rss_mib=round(m.peak_mib, 1) if m else math.nan, headroom_mib=round(res.headroom_mib, 1),
                result="pass" if res.ok else "FAIL", wall_s=round(m.wall_s, 2) if m else math.nan,
                exit=m.code if m else "", tiles=res.tiles, tile=f"{res.tile_w}x{res.tile_h}" if res.tiles else "",
                min_mem=ref.minimum if ref else "", planner_held=ref.held if ref else "",
                smallest_tile=ref.smallest if ref else "", problems="; ".join(res.problems))


def table(rows: list[dict[str, object]]) -> list[str]:
    """The runs as a Markdown table."""
    head = ["input", "preset", "output", "--mem", "peak RSS MiB", "headroom MiB", "result", "wall s", "tiles",
            "min --mem (held + tile)"]
    lines = ["| " + " | ".join(head) + " |", "|---|---|---|---:|---:|---:|---|---:|---|---|"]
    for r in rows:
        tiles = f"{r['tiles']} of {r['tile']}" if r["tiles"] else ""
        minimum = f"{r['min_mem']} ({r['planner_held']} + {r['smallest_tile']})" if r["min_mem"] else ""
        result = r["result"] + (f": {r['problems']}" if r["problems"] else "")
        cells = [r["input"], r["preset"], r["output_format"], r["mem"], fmt_num(float(r["peak_rss_mib"])),
                 fmt_num(float(r["headroom_mib"])), result, fmt_num(float(r["wall_s"]), 1), tiles, minimum]
        lines.append("| " + " | ".join(str(c) for c in cells) + " |")
    return lines


def refusal_lines(refusals: list[Refusal]) -> list[str]:
    """The refusal checks as Markdown list items (clisp's message shown once, the rest summarised)."""
    if not refusals:
        return []
    bad = [f for f in refusals if f.problems]
    lines = [f"- Refusal (`--mem {refusals[0].mem}`, far below the minimum): {len(refusals) - len(bad)} of "
             f"{len(refusals)} exit 2 with one stderr line naming the output and the minimum, and no output file; "
             f"e.g. ({refusals[0].cfa} {size_label(refusals[0].size)} {refusals[0].preset} {refusals[0].fmt}) "
             f"`{refusals[0].line}`"]
    lines += [f"- Refusal FAIL {f.cfa} {size_label(f.size)} {f.preset} {f.fmt}: {'; '.join(f.problems)}: "
              f"`{f.line}`" for f in bad]
    return lines


def device_line(root: Path) -> str:
    """The OpenCL device clisp uses (``clisp info --device``)."""
    done = subprocess.run(clisp_cmd("info", "--device"), capture_output=True, text=True, env=clisp_env(root), cwd=NEUTRAL_CWD)
    found = [line for line in done.stdout.splitlines() if line.startswith("clisp uses")]
    return found[0].removeprefix("clisp uses: ") if found else "unknown"


def header_lines(root: Path, inputs: dict[tuple[str, tuple[int, int]], Path], scene: Path,
                 launcher: str) -> list[str]:
    """Machine, clisp revision, inputs and the launcher check, as Markdown list items."""
    cpu = toolkit.cpu_model(lambda: platform.processor() or "unknown CPU")
    lines = [f"- Machine: {cpu}, {os.cpu_count()} cores, {toolkit.total_memory_gib():.0f} GiB; "
             f"OpenCL: {device_line(root)}",
             f"- clisp: {root} at {toolkit.git_rev(root, dirty=True)}",
             f"- Inputs: `clisp simulate {scene.name} --cfa lms|bayer --gain 8 --size WxH`: "
             + ", ".join(f"{cfa} {w}x{h}" for cfa, (w, h) in inputs),
             f"- Peak RSS: ru_maxrss of os.wait4 on the clisp process, started by a python -S launcher; {launcher}"]
    return lines


def section(rows: list[dict[str, object]], header: list[str], refusals: list[str], argv: list[str]) -> str:
    """The Markdown section, between its markers."""
    body = [MARK_START, SECTION_TITLE, "",
            f"Measured {datetime.date.today().isoformat()} with `{' '.join(shlex.quote(a) for a in argv)}`.",
            "", *header, *refusals, "",
            "`--mem` bounds the peak resident set of the whole `clisp process` (clisp/engine/memory.py). Headroom is "
            "--mem - peak; \"min --mem\" is the minimum clisp names when refusing a too-small --mem (what the "
            "process holds when planning, RSS_MARGIN included, + the smallest tile). Wall times are on a shared "
            "machine.", "",
            *table(rows), MARK_END]
    return "\n".join(body) + "\n"


# --------------------------------------------------------------------------------------------
# Main
# --------------------------------------------------------------------------------------------

def planned_runs(args: argparse.Namespace) -> list[Run]:
    """Every size x CFA x preset x format x --mem that ``--only`` selects."""
    runs = [Run(cfa, size, preset, fmt, mem) for size in args.sizes for cfa in args.cfas for preset in args.presets
            for fmt in args.formats for mem in args.mems]
    return [r for r in runs if not args.only or re.search(args.only, r.label)]


def progress(quiet: bool, text: str) -> None:
    """A progress line on stderr unless ``quiet``."""
    if not quiet:
        print(text, file=sys.stderr, flush=True)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    runs = planned_runs(args)
    if not runs:
        print(f"check_mem: no run matches --only {args.only!r}", file=sys.stderr)
        return 2
    root = args.clisp
    with toolkit.work_folder(args.work, "check_mem-") as work:
        outdir = work / "out"
        outdir.mkdir(parents=True, exist_ok=True)
        launcher_ok, launcher = launcher_check()
        progress(args.quiet, f"launcher: {launcher}")
        scene = toolkit.scene_file(args.data, work, root)
        inputs: dict[tuple[str, tuple[int, int]], Path] = {}
        for r in runs:
            if (r.cfa, r.size) not in inputs:
                progress(args.quiet, f"input {r.cfa} {r.size[0]}x{r.size[1]} ...")
                inputs[(r.cfa, r.size)] = make_raw(scene, r.cfa, r.size, work, root)
        refusals: dict[tuple, Refusal] = {}
        if not args.no_refusal:
            for r in runs:
                ref = Refusal(r.cfa, r.size, r.preset, r.fmt, args.refuse_mem)
                if ref.key not in refusals:
                    refusals[ref.key] = check_refusal(ref, inputs[(r.cfa, r.size)], outdir, root)
                    verdict = "; ".join(ref.problems) or "ok"
                    progress(args.quiet, f"  refusal {r.cfa} {size_label(r.size)} {r.preset} {r.fmt}: "
                                         f"exit {ref.code} {verdict} (min {ref.minimum})")
        results = []
        for r in runs:
            res = run_one(r, inputs[(r.cfa, r.size)], outdir, root)
            results.append(res)
            m = res.measured
            progress(args.quiet, f"  {r.label:<28} {m.peak_mib:7.0f} MiB  {m.wall_s:7.1f} s  "
                                 f"{'pass' if res.ok else 'FAIL: ' + '; '.join(res.problems)}")
        rows = [row_for(res, refusals) for res in results]
        header = header_lines(root, inputs, scene, launcher)
        refused = refusal_lines(list(refusals.values()))
        print("\n".join(header + refused + [""] + table(rows)), flush=True)
        if args.csv:
            write_csv(rows, args.csv)
        if args.results:
            command = ["python", "tools/check_mem.py", *(sys.argv[1:] if argv is None else argv)]
            toolkit.update_results(args.results, section(rows, header, refused, command), "check_mem")
    ok = launcher_ok and all(r.ok for r in results) and not any(f.problems for f in refusals.values())
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
