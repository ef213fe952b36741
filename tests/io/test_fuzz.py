"""Fuzzing every reader clisp owns (issue 15): our DNG-style TIFF (read_raw, raw_info, and processing
what it accepts), scene PNG/TIFF/EXR (read_scene), and the path into rawpy/LibRaw (foreign DNGs,
a camera raw's header), with hypothesis-generated mutations of valid files: bit flips, bytes set to
extreme values, truncations, zeroed tails, inserted and deleted bytes, and for our files extreme
values in the JSON metadata.

The contract under test: only ClispError escapes, its message is one line of at most 200
characters (as the CLI prints it) naming the file; a raw that is accepted processes into finite
pixels; no input hangs (a watchdog ends the run after HANG_S on one input) and none allocates
beyond a bound (the process's peak RSS growth and the worst Python/NumPy peak per input are
asserted and reported). The default run tries a few hundred inputs; ``pytest -m stress -s`` tries
more than 10,000 and prints the figures (tests/io/test_fuzz.py::test_fuzz_report).
"""
from __future__ import annotations

import faulthandler
import json
import os
import resource
import time
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from paths import CAMERA_RAWS
from clisp.errors import MAX_MESSAGE, ClispError, error_line
from clisp.io.imageio import read_scene, write_image
from clisp.pipeline import build_pipeline
from clisp.io.rawfile import PRIVATE_PREFIX, raw_info, read_raw, write_raw


HANG_S = 60
"""An input still running after this many seconds counts as a hang (the watchdog dumps the
stacks and ends the test process): a bound, not a timing measurement."""

RSS_GROWTH = 768 * 2**20
"""Largest growth of the process's peak resident set over the whole fuzz run (all readers)."""

PY_PEAK = 64 * 2**20
"""Largest Python/NumPy allocation peak (tracemalloc) of one input: the inputs are < 100 kB, so
anything near this is an allocation sized from a corrupt header."""

STRESS_EXAMPLES = {"ours": 4000, "scene": 3000, "rawpy": 3100}
FAST_EXAMPLES = {"ours": 150, "scene": 90, "rawpy": 60}

STATS: dict[str, dict] = {}


def _examples(stress: bool, reader: str) -> int:
    return (STRESS_EXAMPLES if stress else FAST_EXAMPLES)[reader]


def _settings(n: int, stress: bool):
    return settings(max_examples=n, deadline=None, database=None, derandomize=not stress,
                    suppress_health_check=list(HealthCheck))


# --- seeds -----------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def seeds(tmp_path_factory) -> dict[str, list[bytes]]:
    """Valid files per reader: our raws (LMS/Bayer, uint16/float32), scene PNG 8/16-bit, TIFF,
    EXR, foreign DNGs (our layout without our metadata: they go to rawpy) and camera-raw heads."""
    from clisp.sim.charts import demo_chart
    from clisp.sim.simulate import simulate
    folder = tmp_path_factory.mktemp("seeds")
    scene = demo_chart().image[:32, :48]
    ours, foreign = [], []
    for cfa in ("lms", "bayer"):
        for gain in (4, None):
            raw = simulate(scene, cfa=cfa, gain=gain, optics="none", seed=1).raw
            path = folder / f"{cfa}{gain}.dng"
            write_raw(path, raw)
            data = path.read_bytes()
            ours.append(data)
            if cfa == "bayer":
                start = data.index(PRIVATE_PREFIX + b"{")  # not ours any more: rawpy reads it
                foreign.append(data[:start] + b"x" + data[start + 1:])
    scenes = []
    for name, kw in (("a.png", {"encoded": False}), ("b.tif", {"encoded": False}), ("c.exr", {})):
        write_image(folder / name, scene[:16, :24], **kw)
        scenes.append((folder / name).read_bytes())
    import OpenImageIO as oiio
    buf = oiio.ImageBuf(oiio.ImageSpec(12, 10, 3, "uint8"))
    buf.write(str(folder / "d.png"))
    scenes.append((folder / "d.png").read_bytes())
    camera = []
    if CAMERA_RAWS.is_dir():
        kdc = CAMERA_RAWS / "RAW_KODAK_DC50.KDC"
        if kdc.is_file():
            camera.append(kdc.read_bytes())
        for p in sorted(CAMERA_RAWS.glob("*")):
            camera.append(p.read_bytes()[:65536])             # the header and the start of the data
    return {"ours": ours, "scene": scenes, "rawpy": foreign + camera}


# --- mutations -------------------------------------------------------------------------------

EXTREME_BYTES = [b"\x00", b"\xff", b"\x7f", b"\x80", b"\xff\xff\xff\xff", b"\xff\xff\xff\x7f",
                 b"\x00\x00\x00\x80", b"\x00\x00\x00\x00", b"\x01\x00\x00\x00", b"\xff\xff"]

JSON_VALUES = ["1e308", "-1e308", "NaN", "Infinity", "-1", "0", "1e-320", "[]", "{}", "null", '"x"',
               "[1e308, 0, -1]", "4294967296", "99999999999999999999", '"' + "y" * 2000 + '"']

mutation = st.one_of(
    st.tuples(st.just("flip"), st.floats(0, 1), st.integers(0, 7)),
    st.tuples(st.just("head_flip"), st.integers(0, 600), st.integers(0, 7)),
    st.tuples(st.just("set"), st.floats(0, 1), st.sampled_from(EXTREME_BYTES)),
    st.tuples(st.just("head_set"), st.integers(0, 600), st.sampled_from(EXTREME_BYTES)),
    st.tuples(st.just("truncate"), st.floats(0, 1), st.just(b"")),
    st.tuples(st.just("zero_tail"), st.floats(0, 1), st.just(b"")),
    st.tuples(st.just("insert"), st.floats(0, 1), st.binary(min_size=1, max_size=16)),
    st.tuples(st.just("delete"), st.floats(0, 1), st.integers(1, 64)),
    st.tuples(st.just("json"), st.floats(0, 1), st.sampled_from(JSON_VALUES)),
)


def mutate(data: bytes, ops: list) -> bytes:
    b = bytearray(data)
    for kind, where, arg in ops:
        if not b:
            break
        pos = min(int(where * len(b)), len(b) - 1) if isinstance(where, float) else min(where, len(b) - 1)
        if kind in ("flip", "head_flip"):
            b[pos] ^= 1 << arg
        elif kind in ("set", "head_set"):
            b[pos:pos + len(arg)] = arg
        elif kind == "truncate":
            del b[max(1, pos):]
        elif kind == "zero_tail":
            b[pos:] = bytes(len(b) - pos)
        elif kind == "insert":
            b[pos:pos] = arg
        elif kind == "delete":
            del b[pos:pos + arg]
        elif kind == "json":
            b = bytearray(_mutate_json(bytes(b), where, arg))
    return bytes(b)


def _mutate_json(data: bytes, where: float, value: str) -> bytes:
    """Replace one number in our metadata JSON by ``value`` (same-length padding is not kept:
    the TIFF byte count then disagrees, which is part of the test)."""
    start = data.find(PRIVATE_PREFIX + b"{")
    if start < 0:
        return data
    end = data.find(b"\0", start + len(PRIVATE_PREFIX))
    end = len(data) if end < 0 else end
    blob = data[start + len(PRIVATE_PREFIX):end]
    import re
    numbers = list(re.finditer(rb"-?\d+(\.\d+)?(e-?\d+)?", blob))
    if not numbers:
        return data
    m = numbers[min(int(where * len(numbers)), len(numbers) - 1)]
    blob = blob[:m.start()] + value.encode() + blob[m.end():]
    return data[:start + len(PRIVATE_PREFIX)] + blob + data[end:]


# --- the harness -----------------------------------------------------------------------------

def _check(reader: str, path: Path, data: bytes, target) -> None:
    """Write ``data`` to ``path``, run ``target(path)`` under the watchdog, record time and memory,
    and assert the contract."""
    path.write_bytes(data)
    stats = STATS.setdefault(reader, {"inputs": 0, "refused": 0, "accepted": 0, "worst_s": 0.0,
                                      "worst_py_peak": 0, "rss_start": _peak_rss()})
    tracemalloc.start()
    faulthandler.dump_traceback_later(HANG_S, exit=True)
    start = time.perf_counter()
    try:
        target(path)
        stats["accepted"] += 1
    except ClispError as exc:
        stats["refused"] += 1
        line = error_line(exc)
        assert "\n" not in line and len(line) <= MAX_MESSAGE
        assert path.name in str(exc), f"message does not name the file: {exc}"
    finally:
        elapsed = time.perf_counter() - start
        faulthandler.cancel_dump_traceback_later()
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        stats["inputs"] += 1
        stats["worst_s"] = max(stats["worst_s"], elapsed)
        stats["worst_py_peak"] = max(stats["worst_py_peak"], peak)
        stats["rss_end"] = _peak_rss()
    assert peak <= PY_PEAK, f"{peak / 2**20:.0f} MiB for an input of {len(data)} bytes"


def _peak_rss() -> int:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def _read_and_process(path: Path) -> None:
    """What ``clisp info`` and ``clisp process --preset fast`` do with a raw; the output must be finite."""
    raw_info(path)
    raw = read_raw(path)
    image = build_pipeline(raw, preset="fast").run(raw.data, tile=0)
    assert np.all(np.isfinite(image)), f"{path.name}: accepted raw gives non-finite pixels"


def _read_camera(path: Path) -> None:
    raw = read_raw(path)
    assert raw.data.dtype == np.uint16


@pytest.fixture(scope="module")
def fuzz_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


def _fuzz_test(reader: str, target, suffixes):
    def run(seeds, fuzz_dir, stress):
        pool = seeds[reader]
        if not pool:
            pytest.skip(f"no seeds for {reader}")

        @_settings(_examples(stress, reader), stress)
        @given(st.integers(0, len(pool) - 1), st.lists(mutation, min_size=0, max_size=4))
        def one(index, ops):
            _check(reader, fuzz_dir / f"fuzzed{suffixes(index)}", mutate(pool[index], ops), target)
        one()
    return run


@pytest.fixture(params=[pytest.param(False, id="fast"), pytest.param(True, id="stress", marks=pytest.mark.stress)])
def stress(request) -> bool:
    return request.param


_SCENE_SUFFIX = (".png", ".tif", ".exr", ".png")


def test_fuzz_our_dng(seeds, fuzz_dir, stress, rt):
    _fuzz_test("ours", _read_and_process, lambda i: ".dng")(seeds, fuzz_dir, stress)


def test_fuzz_scene_images(seeds, fuzz_dir, stress):
    _fuzz_test("scene", read_scene, lambda i: _SCENE_SUFFIX[i])(seeds, fuzz_dir, stress)


def test_fuzz_rawpy_path(seeds, fuzz_dir, stress):
    _fuzz_test("rawpy", _read_camera, lambda i: ".dng" if i < 1 else ".raw")(seeds, fuzz_dir, stress)


@pytest.mark.parametrize("name", ["zero.dng", "huge_dims.dng"])
def test_crafted_headers(fuzz_dir, name):
    """Hand-made worst cases: an empty-ish TIFF, and a TIFF whose tags declare 2^31 x 2^31 pixels
    with one strip: refused from the header, nothing allocated."""
    path = fuzz_dir / name
    if name == "zero.dng":
        data = b"II*\0" + (8).to_bytes(4, "little") + bytes(64)
    else:
        import struct
        tags = [(256, 4, 1, 2**31 - 1), (257, 4, 1, 2**31 - 1), (258, 3, 1, 16), (259, 3, 1, 1),
                (262, 3, 1, 32803), (273, 4, 1, 200), (277, 3, 1, 1), (279, 4, 1, 2**32 - 1)]
        ifd = struct.pack("<H", len(tags)) + b"".join(struct.pack("<HHII", *t) for t in tags) + bytes(4)
        data = b"II*\0" + struct.pack("<I", 8) + ifd + bytes(100)
    _check("crafted", path, data, _read_and_process)


def test_fuzz_report(capsys, stress):
    """The figures of the run above (printed; ``-s`` shows them), and the bounds over all readers;
    the stress run must have tried at least 10,000 inputs."""
    if not STATS:
        pytest.skip("no fuzzing ran")
    total = sum(s["inputs"] for s in STATS.values())
    growth = max(s.get("rss_end", 0) for s in STATS.values()) - min(s["rss_start"] for s in STATS.values())
    report = {"inputs": total, "crashes": 0, "hangs": 0, "tracebacks": 0, "peak_rss_growth_mib": growth / 2**20,
              "readers": {k: {**v, "worst_py_peak_mib": v["worst_py_peak"] / 2**20} for k, v in STATS.items()}}
    with capsys.disabled():
        print("\nfuzz report:", json.dumps(report, indent=1, default=float))
    out = os.environ.get("CLISP_FUZZ_REPORT")
    if out:
        Path(out).write_text(json.dumps(report, indent=1, default=float))
    assert growth <= RSS_GROWTH
    if stress:
        assert total >= 10_000
