"""Helpers shared by the whole-process measurement tools (tools/bench_peers.py, tools/check_mem.py).

Paths (REPO, DEFAULT_DATA, KODAK_SCENE), the neutral working directory of child processes, the
clisp command line and environment, size parsing, image headers, machine and git facts, CSV output
and the replacement of a tool's marked section in a Markdown results file.

tools/ is not a package: the tools import this as ``import toolkit`` (their own folder is first on
sys.path when run as scripts; the tests put it there).
"""
from __future__ import annotations

import argparse
import csv
import os
import subprocess
import sys
import tempfile
from collections.abc import Callable
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEFAULT_DATA = REPO.parent / "shared" / "data"
KODAK_SCENE = "kodak/kodim01.png"

NEUTRAL_CWD = tempfile.gettempdir()
"""Working directory of every child Python: ``python -m clisp`` puts its working directory first
on sys.path, so a child started in a clisp checkout imports that checkout whatever PYTHONPATH
says (a --baseline run from the repo root timed the repo's own code)."""


def parse_size(text: str) -> tuple[int, int]:
    """(W, H) from 'WxH'; both even and at least 64 (a whole number of CFA periods)."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not WxH, e.g. 6000x4000") from None
    if w < 64 or h < 64 or w % 2 or h % 2:
        raise argparse.ArgumentTypeError(f"{text!r}: W and H must be even and at least 64")
    return w, h


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


def write_csv(rows: list[dict[str, object]], path: Path) -> None:
    """``rows`` as CSV (header from the first row's keys), creating ``path``'s folder."""
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
