"""The tools' harness: paths, shared command-line options, data sets, timing, metrics and output.

Every tool in tools/ is a thin script on top of this module:

* paths: REPO (this checkout), DEFAULT_DATA (../shared/data beside it) and, on import, the repo root
  put on sys.path once, so that ``clisp`` and ``research`` import from this checkout;
* options: ``add_data_option``, ``add_repeat_option``, ``add_out_option``, ``add_work_option``
  and the argparse types ``parse_size`` (WxH) and ``parse_shape`` (HxW);
* data sets: one function per scene set (``kodak``, ``mcmaster``, ``dead_leaves_charts``,
  ``zone_plates``, ``demo_charts``), each a list of :class:`Scene`; ``image_files`` lists a
  set's files for the tools that read them one by one;
* timing: ``best_of`` (one callable), ``best_times`` (several, in interleaved rounds) and ``measure_process`` (wall time, peak RSS and exit code of a whole child process);
* metrics: ``BORDER`` and ``cpsnr``, on top of clisp.metrics (PSNR, SNR and colour errors live there);
* facts and output: CPU model, memory, git revision, CSV, a marked section of a Markdown file.

tools/ is not a package: a tool imports this as ``import toolkit`` (Python puts the script's own
folder first on sys.path; the tests put tools/ there). The tool imports it before clisp, so that
the repo root is on sys.path first. clisp itself is imported lazily here: check_mem.py runs another
checkout's clisp in child processes and keeps this one out of its own process.
"""
from __future__ import annotations

import argparse
import contextlib
import csv
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple, TypeVar

import numpy as np

T = TypeVar("T")

# --------------------------------------------------------------------------------------------
# Paths
# --------------------------------------------------------------------------------------------

TOOLS = Path(__file__).resolve().parent
REPO = TOOLS.parent
KODAK_SCENE = "kodak/kodim01.png"
"""The Kodak image (relative to the data folder) that whole-process tools simulate their raws from."""


def _put_repo_on_path() -> None:
    """Put REPO on sys.path (after the tools folder, before PYTHONPATH's entries) unless it is there,
    so that the tools import this checkout's clisp and research packages."""
    entries = [Path(p).resolve() if p else Path.cwd() for p in sys.path]
    if REPO not in entries:
        sys.path.insert(1 if entries and entries[0] == TOOLS else 0, str(REPO))


_put_repo_on_path()


def _main_checkout(repo: Path) -> Path | None:
    """The main checkout of a git worktree at ``repo`` (its .git is a file 'gitdir: MAIN/.git/worktrees/NAME'),
    None for a main checkout or outside git."""
    git = repo / ".git"
    if not git.is_file():
        return None
    head, _, gitdir = git.read_text().partition(":")
    path = Path(gitdir.strip())
    if head.strip() != "gitdir" or path.parent.name != "worktrees":
        return None
    return path.parent.parent.parent


def _default_data() -> Path:
    """../shared/data beside the repository; for a git worktree without one, beside its main checkout."""
    beside = REPO.parent / "shared" / "data"
    main = _main_checkout(REPO)
    if not beside.is_dir() and main is not None and (main.parent / "shared" / "data").is_dir():
        return main.parent / "shared" / "data"
    return beside


DEFAULT_DATA = _default_data()

NEUTRAL_CWD = tempfile.gettempdir()
"""Working directory of every child Python: ``python -m clisp`` puts its working directory first
on sys.path, so a child started in a clisp checkout imports that checkout whatever PYTHONPATH
says (a --baseline run from the repo root timed the repo's own code)."""


# --------------------------------------------------------------------------------------------
# Command-line options
# --------------------------------------------------------------------------------------------

def parse_size(text: str) -> tuple[int, int]:
    """(W, H) from 'WxH'; both even and at least 64 (a whole number of CFA periods)."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not WxH, e.g. 6000x4000") from None
    if w < 64 or h < 64 or w % 2 or h % 2:
        raise argparse.ArgumentTypeError(f"{text!r}: W and H must be even and at least 64")
    return w, h


def parse_shape(text: str) -> tuple[int, int]:
    """(H, W) from 'HxW', in pixels (an array's shape, rows first)."""
    h, w = (int(v) for v in text.lower().split("x"))
    return h, w


def resolved_path(text: str) -> Path:
    """An absolute path from a command-line argument (children run in NEUTRAL_CWD)."""
    return Path(text).expanduser().resolve()


def add_data_option(parser: argparse.ArgumentParser, holding: str = "kodak/ and mcmaster/") -> None:
    """``--data DIR``: the data folder (an absolute Path), default DEFAULT_DATA."""
    parser.add_argument("--data", type=resolved_path, default=DEFAULT_DATA, metavar="DIR",
                        help=f"data folder holding {holding} (default: ../shared/data beside the repository, "
                             f"here {DEFAULT_DATA})")


def add_repeat_option(parser: argparse.ArgumentParser, default: int, what: str = "timed runs, best kept") -> None:
    """``--repeat N``: how many timed runs (or rounds) a measurement takes."""
    parser.add_argument("--repeat", type=int, default=default, metavar="N", help=f"{what} (default {default})")


def add_scene_set_options(parser: argparse.ArgumentParser) -> None:
    """``--sets``, ``--subset``, ``--dead-leaves`` and ``--csv`` of the tools that score demosaics on
    Kodak, McMaster and dead leaves (bench_demosaic_quality.load_scenes reads the first three)."""
    parser.add_argument("--sets", default="kodak,mcmaster,deadleaves")
    parser.add_argument("--subset", type=int, default=None, help="first N images of each file set")
    parser.add_argument("--dead-leaves", type=int, default=8, help="dead-leaves charts (512 px, seeds 0..N-1)")
    parser.add_argument("--csv", default=None, help="write one row per result")


def time_demosaic(stage: object, cfa: object, mosaic: np.ndarray, repeat: int, label_width: int = 16,
                  profiled: bool = False) -> float:
    """Device speed of one demosaic stage alone through clisp's tiler (default 1 GiB budget), warm
    (a small run first builds the programs), best of ``repeat``; prints its line (and, with
    ``profiled``, one more run's device time per kernel). Returns the best seconds."""
    from clisp.engine import profile
    from clisp.pipeline import Pipeline
    pipeline = Pipeline(cfa, [stage])
    plan = pipeline.plan(mosaic.shape, mosaic.dtype, None, 2**30, "opencl")
    pipeline.run(mosaic[:2 * stage.halo + 64, :2 * stage.halo + 64])
    _, best = best_of(lambda: pipeline.run(mosaic), repeat)
    mp = mosaic.size / 1e6
    print(f"{type(stage).__name__:{label_width}s} halo {stage.halo:3d}  window {plan.window_shape}  "
          f"{best:7.2f} s  {mp / best:7.2f} MP/s", flush=True)
    if profiled:
        prof = profile.start()
        t0 = time.perf_counter()
        pipeline.run(mosaic)
        print(prof.report(mp, time.perf_counter() - t0), flush=True)
        profile._ACTIVE = None
    return best


def add_out_option(parser: argparse.ArgumentParser, default: str, what: str) -> None:
    """``--out DIR``: where a tool writes its files, default ``default`` relative to the repository."""
    parser.add_argument("--out", type=Path, default=REPO / default, metavar="DIR",
                        help=f"folder for {what} (default {default} in the repository)")


def add_work_option(parser: argparse.ArgumentParser, what: str = "raws and outputs",
                    default: Path | None = None) -> None:
    """``--work DIR``: a scratch folder for a tool's inputs and outputs (see :func:`work_folder`)."""
    where = "a temporary one" if default is None else str(default)
    parser.add_argument("--work", type=Path, default=default, metavar="DIR", help=f"folder for {what} (default: {where})")


@contextlib.contextmanager
def work_folder(work: Path | None, prefix: str) -> Iterator[Path]:
    """``work`` (absolute, created), or with None a temporary folder removed afterwards."""
    with tempfile.TemporaryDirectory(prefix=prefix) as tmp:
        path = (work or Path(tmp)).resolve()
        path.mkdir(parents=True, exist_ok=True)
        yield path


# --------------------------------------------------------------------------------------------
# Data sets
# --------------------------------------------------------------------------------------------

class Scene(NamedTuple):
    """One image of a scene set: its name (a file's name, or a generated chart's) and H x W x 3
    float64 pixels (linear sRGB unless the loader says otherwise)."""

    name: str
    image: np.ndarray


@dataclass(frozen=True)
class ImageSet:
    """A set of image files in a folder of the data folder."""

    label: str
    folder: str
    patterns: tuple[str, ...]


KODAK = ImageSet("Kodak", "kodak", ("*.png",))
MCMASTER = ImageSet("McMaster", "mcmaster", ("*.tif", "*.tiff"))


def missing_data(folder: Path, what: str) -> SystemExit:
    """The error of a tool that finds no ``what`` in ``folder`` (of the data folder)."""
    return SystemExit(f"no {what} in {folder}; pass --data DIR, the folder holding kodak/, mcmaster/ and raw/ "
                      f"(default {DEFAULT_DATA})")


def image_files(data: Path, image_set: ImageSet, subset: int | None = None, *, numeric: bool = False,
                required: bool = True) -> list[Path]:
    """The first ``subset`` files of ``image_set`` under ``data`` (all for None), ordered by file
    name, or with ``numeric`` by length then name (1, 2, ..., 10: McMaster's numbers). With
    ``required``, no file at all is an error (SystemExit); else it gives []."""
    folder = data / image_set.folder
    files = sorted({p for pattern in image_set.patterns for p in folder.glob(pattern)},
                   key=(lambda p: (len(p.stem), p.stem)) if numeric else None)
    if not files and required:
        raise missing_data(folder, f"{image_set.label} images ({', '.join(image_set.patterns)})")
    return files[:subset]


def load_scene(path: Path) -> np.ndarray:
    """An image file as linear sRGB (clisp.io.imageio.read_scene), cropped at the bottom and right
    to multiples of 4 px (the LMS CFA's period)."""
    from clisp.io.imageio import read_scene
    scene = read_scene(path)
    return scene[:scene.shape[0] // 4 * 4, :scene.shape[1] // 4 * 4]


def load_8bit(path: Path) -> np.ndarray:
    """An 8-bit sRGB file as float64 H x W x 3 in [0, 1], exactly k / 255 (no linearisation: the
    classic demosaic protocol's input)."""
    from clisp.io.imageio import read_image
    pixels = read_image(path)[0].astype(np.float64) * 255.0
    codes = np.round(pixels)
    if np.abs(pixels - codes).max() > 1e-3:
        raise SystemExit(f"{path}: not an 8-bit image")
    return codes / 255.0


def _file_scenes(files: list[Path], read: Callable[[Path], np.ndarray]) -> list[Scene]:
    return [Scene(path.name, read(path)) for path in files]


def kodak(data: Path, subset: int | None = None, *, read: Callable[[Path], np.ndarray] = load_scene,
          required: bool = True) -> list[Scene]:
    """The Kodak set (24 PNG, kodim01..kodim24), the first ``subset``, read by ``read``."""
    return _file_scenes(image_files(data, KODAK, subset, required=required), read)


def mcmaster(data: Path, subset: int | None = None, *, numeric: bool = False,
             read: Callable[[Path], np.ndarray] = load_scene, required: bool = True) -> list[Scene]:
    """The McMaster set (18 TIFF, 1..18), the first ``subset`` by file name (1, 10, 11, ...) or with
    ``numeric`` by number (1, 2, 3, ...), read by ``read``."""
    return _file_scenes(image_files(data, MCMASTER, subset, numeric=numeric, required=required), read)


def kodak_path(data: Path, number: int) -> Path:
    """Kodak image ``number`` (1..24)."""
    return data / KODAK.folder / f"kodim{number:02d}.png"


def mcmaster_path(data: Path, number: int) -> Path:
    """McMaster image ``number`` (1..18)."""
    return data / MCMASTER.folder / f"{number}.tif"


def dead_leaves_charts(count: int, size: int = 512) -> list[Scene]:
    """``count`` dead-leaves charts (clisp.sim.charts.dead_leaves, size x size, seeds 0..count - 1)."""
    from clisp.sim.charts import dead_leaves
    return [Scene(f"dead_leaves_{seed}", dead_leaves(size, seed=seed)) for seed in range(count)]


def zone_plates(size: int = 256) -> list[Scene]:
    """The neutral sRGB-cosine zone plate (clisp.sim.charts.zone_plate), one image."""
    from clisp.sim.charts import zone_plate
    return [Scene(f"zone_plate_{size}", zone_plate(size))]


def demo_charts() -> list[Scene]:
    """clisp's demo chart (clisp.sim.charts.demo_chart), one image."""
    from clisp.sim.charts import demo_chart
    return [Scene("demo chart", demo_chart().image)]


def scene_file(data: Path, work: Path, root: Path = REPO) -> Path:
    """A Kodak image file from ``data`` (KODAK_SCENE), else clisp's demo chart written as a 16-bit
    PNG in ``work`` by the clisp of the checkout at ``root`` (in a child process)."""
    kodak_file = data / KODAK_SCENE
    if kodak_file.is_file():
        return kodak_file
    path = work / "demo_chart.png"
    if not path.is_file():
        code = ("import sys; from clisp.sim.charts import demo_chart; from clisp.io.imageio import write_image; "
                "write_image(sys.argv[1], demo_chart().image, encoded=False)")
        subprocess.run([sys.executable, "-c", code, str(path)], env=repo_env(root), cwd=NEUTRAL_CWD, check=True)
    return path


def repeat_to(array: np.ndarray, height: int, width: int) -> np.ndarray:
    """``array`` (H x W or H x W x C) repeated down and across and cropped to height x width."""
    reps = (-(-height // array.shape[0]), -(-width // array.shape[1])) + (1,) * (array.ndim - 2)
    return np.tile(array, reps)[:height, :width]


# --------------------------------------------------------------------------------------------
# Timing
# --------------------------------------------------------------------------------------------

def best_of(fn: Callable[[], T], repeat: int, warmup: bool = False) -> tuple[T | None, float]:
    """(the last result, the best wall time in seconds) of ``repeat`` calls of ``fn``, after one
    untimed call with ``warmup`` (program builds, buffer pools, page faults)."""
    if warmup:
        fn()
    result, best = None, math.inf
    for _ in range(repeat):
        start = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - start)
    return result, best


def best_times(runs: dict[str, Callable[[], object]], repeat: int) -> dict[str, float]:
    """Best wall time (s) of every callable: one untimed warm-up each, then ``repeat`` rounds, each
    calling all of them once in turn, so that drift and other load on a shared machine hit every
    variant alike."""
    for fn in runs.values():
        fn()
    best = {name: math.inf for name in runs}
    for _ in range(repeat):
        for name, fn in runs.items():
            start = time.perf_counter()
            fn()
            best[name] = min(best[name], time.perf_counter() - start)
    return best


LAUNCHER = """\
import os, sys, time
t0 = time.perf_counter()
pid = os.posix_spawnp(sys.argv[2], sys.argv[2:], os.environ)
_, status, usage = os.wait4(pid, 0)
with open(sys.argv[1], "w") as f:
    f.write(f"{time.perf_counter() - t0} {usage.ru_maxrss} {os.waitstatus_to_exitcode(status)}")
"""
"""``python -S -c LAUNCHER RESULT ARGV...``: runs ARGV (stdin/stdout/stderr inherited) and writes its
wall time (s), peak RSS (ru_maxrss, KiB) and exit code to RESULT. A child's ru_maxrss starts from
the RSS of the process it was forked from (Linux keeps the larger across exec), so the commands
are started from this small process (about 10 MiB), not from the tool itself."""


@dataclass
class ProcessRun:
    """What one child process did: wall time (s), peak RSS (MiB), exit code, stdout and stderr.
    ``started`` is False when the launcher failed (the figures are then NaN, the code -1)."""

    wall_s: float
    peak_mib: float
    code: int
    stdout: str
    stderr: str
    started: bool = True


def measure_process(argv: list[str], env: dict[str, str] | None = None) -> ProcessRun:
    """Run ``argv`` as its own process (in NEUTRAL_CWD, stdin closed) through the launcher: its
    wall time from spawn to exit, its peak RSS and exit code, and what it printed."""
    with tempfile.TemporaryDirectory(prefix="clisp-tools-") as tmp:
        out, err, res = (Path(tmp) / n for n in ("out", "err", "res"))
        with open(out, "w") as fo, open(err, "w") as fe:
            proc = subprocess.Popen([sys.executable, "-S", "-c", LAUNCHER, str(res), *argv], env=env, cwd=NEUTRAL_CWD,
                                    stdin=subprocess.DEVNULL, stdout=fo, stderr=fe)
            code = proc.wait()
        text_out, text_err = out.read_text(errors="replace"), err.read_text(errors="replace")
        if code != 0 or not res.is_file():
            return ProcessRun(math.nan, math.nan, -1, text_out, f"launcher failed ({code}): {text_err}", started=False)
        wall, kib, status = res.read_text().split()
    return ProcessRun(float(wall), int(kib) / 1024, int(status), text_out, text_err)


# --------------------------------------------------------------------------------------------
# Metrics (clisp.metrics has PSNR, SNR and colour errors: only the tools' conventions here)
# --------------------------------------------------------------------------------------------

BORDER = 10
"""Pixels left out on every side in the tools' PSNR figures (clisp.metrics.psnr's default)."""


def cpsnr(output: np.ndarray, truth: np.ndarray) -> float:
    """The classic demosaic protocol's CPSNR (dB): 10 log10(1 / MSE) over the 3 channels in [0, 1]
    (output clipped), BORDER px left out, no tone mapping (clisp.metrics.psnr)."""
    from clisp.metrics import psnr
    return psnr(output, truth, border=BORDER, tone_mapped=False)


# --------------------------------------------------------------------------------------------
# Child processes: clisp's command line and environment
# --------------------------------------------------------------------------------------------

def clisp_cmd(*args: str) -> list[str]:
    """argv running clisp's CLI with this interpreter."""
    return [sys.executable, "-m", "clisp", *args]


def repo_env(root: Path) -> dict[str, str]:
    """The environment with the clisp checkout ``root`` first on PYTHONPATH."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(root)] + [p for p in [env.get("PYTHONPATH", "")] if p])
    return env


def last_line(text: str, limit: int = 200) -> str:
    """The last non-empty line of ``text`` (a tool's error message, usually), cut to ``limit`` characters."""
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return lines[-1][:limit] if lines else "(no message)"


def tree_child(script: str | Path, tree: Path, args: list[str]) -> object:
    """Run ``script``'s ``_child --tree TREE ARGS...`` subcommand with the clisp of ``tree`` first on
    PYTHONPATH (in NEUTRAL_CWD) and return the JSON its last stdout line holds; SystemExit naming
    the tool and the tree with the child's last error line if it fails. The child puts ``tree`` first
    on sys.path itself (toolkit put this checkout there)."""
    script = Path(script).resolve()
    proc = subprocess.run([sys.executable, str(script), "_child", "--tree", str(tree), *args], check=False,
                          env=repo_env(tree), cwd=NEUTRAL_CWD, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"{script.stem}: {tree}: {last_line(proc.stderr)}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def enter_tree(tree: Path) -> None:
    """In a :func:`tree_child` child: put ``tree`` first on sys.path and import its clisp, so that the
    child measures that tree and not this checkout (toolkit put it on sys.path); SystemExit where
    ``tree`` holds no clisp of its own."""
    tree = tree.resolve()
    assert "clisp" not in sys.modules, "enter_tree must run before clisp is imported"
    sys.path.insert(0, str(tree))
    import clisp
    if not Path(clisp.__file__).resolve().is_relative_to(tree):
        raise SystemExit(f"{tree} holds no clisp (imported {clisp.__file__})")


def describe_output(path: Path) -> tuple[int, int, int, str]:
    """(H, W, channels, pixel type) of an image file, from its header (OpenImageIO)."""
    import OpenImageIO as oiio
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise ValueError(f"unreadable: {oiio.geterror()}")
    try:
        spec = inp.spec()
        return spec.height, spec.width, spec.nchannels, str(spec.format)
    finally:
        inp.close()


# --------------------------------------------------------------------------------------------
# Machine and git facts
# --------------------------------------------------------------------------------------------

def git_rev(root: Path, dirty: bool = False) -> str:
    """Short git revision of the checkout at ``root`` ('unknown' outside git); with ``dirty``,
    '+dirty' appended when tracked files are modified."""
    try:
        rev = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True,
                             text=True, check=True).stdout.strip()
        if not dirty:
            return rev
        changed = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                                 capture_output=True, text=True, check=True).stdout.strip()
        return rev + ("+dirty" if changed else "")
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def cpu_model(fallback: Callable[[], str] | None = None) -> str:
    """CPU model name from /proc/cpuinfo, else ``fallback()`` (default 'unknown CPU')."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return fallback() if fallback else "unknown CPU"


def total_memory_gib() -> float:
    """Physical memory (GiB; NaN where the system does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    except (OSError, ValueError):
        return math.nan


# --------------------------------------------------------------------------------------------
# Output
# --------------------------------------------------------------------------------------------

def write_csv(rows: list[dict[str, object]], path: Path) -> None:
    """``rows`` as CSV (header from the first row's keys), creating ``path``'s folder."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def markers(name: str) -> tuple[str, str]:
    """The start and end markers of section ``name`` in a results file: ``<!-- NAME:start -->``, ..."""
    return f"<!-- {name}:start -->", f"<!-- {name}:end -->"


def update_results(path: Path, text: str, name: str) -> None:
    """Replace section ``name`` of ``path`` (between its markers) with ``text``, or append it the first time."""
    start_mark, end_mark = markers(name)
    old = path.read_text() if path.is_file() else ""
    start, end = old.find(start_mark), old.find(end_mark)
    if start >= 0 and end > start:
        new = old[:start] + text + old[end + len(end_mark):].lstrip("\n")
    else:
        new = old.rstrip("\n") + ("\n\n" if old else "") + text
    path.write_text(new)
