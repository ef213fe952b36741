"""The catalogue of messages users can see (docs/messages.md), each exercised here through the CLI
(issue 15): exit status 2, exactly one line on stderr, at most 200 characters, naming the file,
nothing else printed before it, and no output file (an existing one left as it was).

The catalogue and MESSAGES must list the same ids: test_catalogue_lists_every_message.
"""
from __future__ import annotations

import dataclasses

import errno
import re
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from paths import CAMERA_RAWS, DOCS
from clisp.app.cli import main
from clisp.errors import MAX_MESSAGE, ClispError
from clisp.io.imageio import write_image
from clisp.io.rawfile import write_raw

DOC = DOCS / "messages.md"


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    """A small valid raw of each kind, a scene PNG, and the damaged variants the messages need."""
    from clisp.sim.charts import demo_chart
    from clisp.sim.simulate import simulate
    d = tmp_path_factory.mktemp("msg")
    scene = demo_chart().image[:32, :48]
    f = {"scene": d / "scene.png"}
    write_image(f["scene"], scene, encoded=False)
    raw = simulate(scene, cfa="bayer", gain=4, optics="none").raw
    raw.metadata["pad"] = "x" * 40          # room to lengthen other values in place
    f["good"] = d / "good.dng"
    write_raw(f["good"], raw)
    fl = simulate(scene, cfa="lms", gain=None, optics="none").raw
    f["float"] = d / "float.dng"
    write_raw(f["float"], fl)
    data = f["good"].read_bytes()

    def variant(name: str, content: bytes) -> None:
        f[name] = d / name
        f[name].write_bytes(content)

    variant("truncated.dng", data[:len(data) // 2])
    variant("empty.dng", b"")
    variant("notes.txt", b"not a raw file\n")
    variant("badjson.dng", data.replace(b'"dtype": "uint16"', b'"dtype"# "uint16"'))
    variant("newer.dng", data.replace(b'"version": 1', b'"version": 9'))
    variant("whiteblack.dng", _same_length(data, b'"white_level": 1023.0', b'"white_level": 0.0'))
    variant("huge.dng", _same_length(data, b'"shape": [32, 48]', b'"shape": [99999, 99999]'))
    variant("damaged.tif", data[:8] + bytes(400) + data[408:][:len(data) // 3])
    variant("scene_bad.png", f["scene"].read_bytes()[:200])
    nan = fl.data.copy()
    nan[3, 3], nan[4, 5] = np.nan, np.inf
    fl.data = nan
    f["nan.dng"] = d / "nan.dng"
    write_raw(f["nan.dng"], fl)
    fl.data = np.where(np.isfinite(nan), nan, 3e37).astype(np.float32)
    f["far.dng"] = d / "far.dng"
    write_raw(f["far.dng"], fl)
    tiny = simulate(scene, cfa="bayer", gain=4, optics="none").raw
    tiny.data = tiny.data[:1, :1].copy()
    f["tiny.dng"] = d / "tiny.dng"
    write_raw(f["tiny.dng"], tiny)
    f["nodaylight.dng"] = d / "nodaylight.dng"     # one of our raws that is no simulation: no known light
    write_raw(f["nodaylight.dng"], dataclasses.replace(raw, metadata={}))
    small = simulate(scene[:16, :24], cfa="bayer", gain=4, optics="none").raw
    f["dark_small.dng"] = d / "dark_small.dng"
    write_raw(f["dark_small.dng"], small)
    f["dark_black.dng"] = d / "dark_black.dng"
    write_raw(f["dark_black.dng"], dataclasses.replace(raw, black_level=np.full(3, 60.0)))
    f["flat_dark.dng"] = d / "flat_dark.dng"
    write_raw(f["flat_dark.dng"], dataclasses.replace(raw, data=np.full_like(raw.data, 64)))
    (d / "map_bad.txt").write_text("# column row\n3 4\n12 x\n")
    f["map_bad.txt"] = d / "map_bad.txt"
    (d / "map_out.txt").write_text("100 4\n")
    f["map_out.txt"] = d / "map_out.txt"
    import OpenImageIO as oiio
    buf = oiio.ImageBuf(oiio.ImageSpec(4, 4, 3, "float"))
    oiio.ImageBufAlgo.fill(buf, (float("nan"), 0.0, 0.0))
    f["nan.exr"] = d / "nan.exr"
    buf.write(str(f["nan.exr"]))
    return f


def _same_length(data: bytes, old: bytes, new: bytes) -> bytes:
    """``old`` replaced by ``new`` in our metadata, the 40-character pad adjusted so that the file
    keeps its length (its TIFF offsets stay right)."""
    pad = b'"pad": "' + b"x" * 40 + b'"'
    assert old in data and pad in data
    grow = len(new) - len(old)
    return data.replace(old, new, 1).replace(pad, b'"pad": "' + b"x" * (40 - grow) + b'"')


def _camera_truncated(files, tmp: Path) -> Path:
    kdc = CAMERA_RAWS / "RAW_KODAK_DC50.KDC"
    if not kdc.is_file():
        pytest.skip("no camera raws in ../shared/data/raw")
    p = tmp / "cut.kdc"
    p.write_bytes(kdc.read_bytes()[:50000])
    return p


# id -> (arguments from (files, tmp), regex the message must match after 'clisp: error: ')
MESSAGES = {
    "no-such-file": (lambda f, t: ["process", t / "missing.dng", "-o", t / "o.exr"],
                     r"cannot read raw file '.*missing\.dng': no such file"),
    "empty-file": (lambda f, t: ["process", f["empty.dng"], "-o", t / "o.exr"],
                   r"cannot read raw file '.*empty\.dng': the file is empty"),
    "is-a-folder": (lambda f, t: ["process", t, "-o", t / "o.exr"],
                    r"cannot read raw file '.*': it is a folder"),
    "not-a-raw-image": (lambda f, t: ["process", f["scene"], "-o", t / "o.exr"],
                        r"cannot read raw file '.*scene\.png': it is a PNG image, not a raw file"),
    "not-a-raw-text": (lambda f, t: ["process", f["notes.txt"], "-o", t / "o.exr"],
                       r"cannot read raw file '.*notes\.txt': it is a text file, not a raw file"),
    "truncated": (lambda f, t: ["process", f["truncated.dng"], "-o", t / "o.exr"],
                  r"cannot read raw file '.*truncated\.dng': truncated \(image data needs \d+ bytes, file has \d+\)"),
    "corrupt-metadata": (lambda f, t: ["process", f["badjson.dng"], "-o", t / "o.exr"],
                         r"cannot read raw file '.*badjson\.dng': corrupt clisp metadata \(.*\)"),
    "newer-format": (lambda f, t: ["process", f["newer.dng"], "-o", t / "o.exr"],
                     r"cannot read raw file '.*newer\.dng': written by a newer clisp \(format version 9\)"),
    "bad-levels": (lambda f, t: ["process", f["whiteblack.dng"], "-o", t / "o.exr"],
                   r"cannot read raw file '.*whiteblack\.dng': corrupt clisp metadata \(white level 0 is not "
                   r"above the black level \d+\)"),
    "too-many-pixels": (lambda f, t: ["process", f["huge.dng"], "-o", t / "o.exr"],
                        r"cannot read raw file '.*huge\.dng': declares 99999x99999 pixels, more than clisp's "
                        r"limit of 1024 MP"),
    "damaged-tiff": (lambda f, t: ["process", f["damaged.tif"], "-o", t / "o.exr"],
                     r"cannot read raw file '.*damaged\.tif': (damaged or truncated TIFF|not a raw file LibRaw can read) .*"),
    "libraw-damaged": (lambda f, t: ["process", _camera_truncated(f, t), "-o", t / "o.exr"],
                       r"cannot read raw file '.*cut\.kdc': damaged or truncated raw data \(.*\); "
                       r"Unexpected end of file"),
    "non-finite-samples": (lambda f, t: ["process", f["nan.dng"], "-o", t / "o.exr"],
                           r".*nan\.dng: 2 of 1536 samples are NaN or infinite \(corrupt float raw\); not processed"),
    "samples-out-of-range": (lambda f, t: ["process", f["far.dng"], "-o", t / "o.exr"],
                             r".*far\.dng: 2 of 1536 samples lie beyond 1\.04858e\+06 times the white level "
                             r"\(corrupt float raw\); not processed"),
    "smaller-than-cfa": (lambda f, t: ["process", f["tiny.dng"], "-o", t / "o.exr"],
                         r".*tiny\.dng: raw of 1x1 is smaller than one 2x2 CFA tile"),
    "output-extension": (lambda f, t: ["process", f["good"], "-o", t / "o.bmp"],
                         r".*o\.bmp: unsupported output extension '\.bmp'; use \.exr, \.tif, \.tiff, \.png or \.jpg"),
    "output-no-extension": (lambda f, t: ["process", f["good"], "-o", t / "picture"],
                            r".*picture: the output name has no extension; use \.exr, \.tif, \.tiff, \.png or \.jpg "
                            r"\(several raws go to an output folder\)"),
    "jpeg-quality": (lambda f, t: ["process", f["good"], "-o", t / "o.jpg", "--compression", "jpeg:101"],
                     r".*o\.jpg: JPEG quality '101' is not a whole number from 1 to 100 \(jpeg:N\)"),
    "folder-takes-no-files": (lambda f, t: ["process", f["good"], "-o", "/proc/x.tif"],
                              r"/proc/x\.tif: cannot write in /proc: it takes no new files \(a system folder such "
                              r"as /proc or /sys\?\)"),
    "output-folder-missing": (lambda f, t: ["process", f["good"], "-o", t / "nowhere" / "o.exr"],
                              r".*o\.exr: output folder .*nowhere does not exist"),
    "unknown-preset": (lambda f, t: ["process", f["good"], "-o", t / "o.exr", "--preset", "nope"],
                       r"unknown preset 'nope'; available: fast, balanced, quality, best"),
    "demosaic-for-cfa": (lambda f, t: ["process", f["float"], "-o", t / "o.exr", "--demosaic", "ari"],
                         r".*float\.dng: demosaic 'ari' works on bayer CFAs, not lms"),
    "exposure-range": (lambda f, t: ["process", f["good"], "-o", t / "o.exr", "--exposure", "12"],
                       r".*good\.dng: --exposure 12: EV must be within -10\.\.\+10"),
    "wb-multipliers": (lambda f, t: ["process", f["good"], "-o", t / "o.exr", "--wb", "2,1"],
                       r".*good\.dng: --wb '2,1' is neither camera, auto, daylight nor 3 positive multipliers R,G,B"),
    "no-daylight-wb": (lambda f, t: ["process", f["nodaylight.dng"], "-o", t / "o.exr", "--wb", "daylight"],
                       r".*nodaylight\.dng: has no daylight white balance \(try --wb auto or --wb camera\)"),
    "half-size-demosaic": (lambda f, t: ["process", f["good"], "-o", t / "o.exr", "--half-size", "--demosaic", "malvar"],
                           r"--half-size bins each 2x2 block into one pixel, without a demosaic: leave out "
                           r"--demosaic malvar"),
    "half-size-denoise": (lambda f, t: ["process", f["good"], "-o", t / "o.exr", "--half-size", "--denoise-scale", "2"],
                          r"--half-size runs no chroma denoise \(the binning averages the samples\): leave out "
                          r"--denoise-scale and --chroma-strengths"),
    "tile-too-small": (lambda f, t: ["process", f["good"], "-o", t / "o.exr", "--tile", "4"],
                       r"--tile 4: tiles must be at least 16 pixels"),
    "resize-size": (lambda f, t: ["process", f["good"], "-o", t / "o.exr", "--resize", "8"],
                    r"--resize 8: the long edge must be a whole number of pixels, at least 16"),
    "mem-too-small": (lambda f, t: ["process", f["good"], "-o", t / "o.exr", "--mem", "1M"],
                      r".*o\.exr: --mem 1M is below the minimum of \d+M for this 48x32 raw .*"),
    "dark-mismatch": (lambda f, t: ["process", f["good"], "-o", t / "o.exr", "--dark", f["dark_small.dng"]],
                      r".*dark_small\.dng: dark frame does not match .*good\.dng: size 24x16, the raw's 48x32"),
    "dark-levels": (lambda f, t: ["process", f["good"], "-o", t / "o.exr", "--dark", f["dark_black.dng"]],
                    r".*dark_black\.dng: dark frame does not match .*good\.dng: black 60 and white 1023, the raw's "
                    r"64 and 1023"),
    "flat-mismatch": (lambda f, t: ["process", f["good"], "-o", t / "o.exr", "--flat", f["float"]],
                      r".*float\.dng: flat frame does not match .*good\.dng: CFA lms, the raw's bayer-rggb"),
    "flat-no-light": (lambda f, t: ["process", f["good"], "-o", t / "o.exr", "--flat", f["flat_dark.dng"]],
                      r".*flat_dark\.dng: flat frame has no light in channel R \(its brightest region reads 0 DN "
                      r"above black\)"),
    "bad-pixel-map-missing": (lambda f, t: ["process", f["good"], "-o", t / "o.exr", "--bad-pixels", t / "nomap.txt"],
                              r".*nomap\.txt: cannot read bad pixel map \(no such file; --bad-pixels is auto, off "
                              r"or a map file\)"),
    "bad-pixel-map-line": (lambda f, t: ["process", f["good"], "-o", t / "o.exr", "--bad-pixels", f["map_bad.txt"]],
                           r".*map_bad\.txt: bad pixel map line 3: '12 x' is not 'column row'"),
    "bad-pixel-map-outside": (lambda f, t: ["process", f["good"], "-o", t / "o.exr", "--bad-pixels",
                                            f["map_out.txt"]],
                              r".*map_out\.txt: bad pixel map line 1: pixel \(100, 4\) lies outside the 48x32 mosaic"),
    "defect-option": (lambda f, t: ["simulate", f["scene"], "-o", t / "r.dng", "--hot-pixels", "lots"],
                      r"--hot-pixels 'lots': needs a fraction from 0 to 0\.5, optionally :LEVEL"),
    "defects-with-size": (lambda f, t: ["simulate", f["scene"], "-o", t / "r.dng", "--size", "64x64", "--prnu", "0.01"],
                          r"--size repeats a scene band by band and simulates no sensor defects; leave out the "
                          r"defect options or --size"),
    "scene-unreadable": (lambda f, t: ["simulate", f["scene_bad.png"], "-o", t / "r.dng"],
                         r".*scene_bad\.png: .*"),
    "scene-not-finite": (lambda f, t: ["simulate", f["nan.exr"], "-o", t / "r.dng"],
                         r".*nan\.exr: scene contains NaN or infinite values"),
    "scene-is-a-raw": (lambda f, t: ["simulate", f["good"], "-o", t / "r.dng"],
                       r".*good\.dng: is a raw file, not a scene; simulate takes an sRGB PNG/TIFF or a linear EXR "
                       r"\(clisp process turns a raw into one\)"),
    "gain-out-of-range": (lambda f, t: ["simulate", f["scene"], "-o", t / "r.dng", "--gain", "100"],
                          r"--gain 100 is outside the supported range 1\.\.64; --noiseless simulates without noise"),
    "no-preview": (lambda f, t: ["thumb", f["good"], "-o", t / "o.jpg"],
                   r".*good\.dng: has no embedded preview \(clisp process --preset fast makes one\)"),
    "info-needs-file": (lambda f, t: ["info"], r"info needs a RAW file or --device"),
    "outdir-is-a-file": (lambda f, t: ["process", f["good"], f["float"], "-o", t / "o.exr"],
                         r".*o\.exr: several inputs need an output folder \(-o OUTDIR\), not a file"),
    "no-raws-in-folder": (lambda f, t: ["process", t, "-o", t / "out"], r"no raw files in .*"),
    "warm-without-device": (lambda f, t: ["info", "--warm"],
                            r"--warm builds the kernels of the device: use clisp info --device --warm"),
    "warm-unknown-preset": (lambda f, t: ["info", "--device", "--warm", "fastest"],
                            r"--warm 'fastest': presets are fast, balanced, quality, best, or 'all'"),
}

# Messages of failures that need the system to misbehave: provoked by monkeypatching (below).
FAULTS = ("unwritable-folder", "disk-full-output", "disk-full-raw", "interrupted", "non-finite-output")


def _run(args: list, capfd) -> tuple[int, str]:
    code = main([str(a) for a in args])
    captured = capfd.readouterr()
    return code, captured.err


def _assert_one_line(code: int, err: str, pattern: str) -> None:
    assert code == 2, err
    assert err.count("\n") == 1 and err.endswith("\n"), f"not one line: {err!r}"
    line = err.rstrip("\n")
    assert len(line) <= MAX_MESSAGE, f"{len(line)} characters: {line}"
    assert line.startswith("clisp: error: "), line
    assert re.fullmatch(pattern, line[len("clisp: error: "):]), line


@pytest.mark.parametrize("name", list(MESSAGES))
def test_message(name, files, tmp_path, capfd):
    make_args, pattern = MESSAGES[name]
    args = make_args(files, tmp_path)
    existing = tmp_path / "o.exr"
    existing.write_bytes(b"previous output")
    code, err = _run(args, capfd)
    _assert_one_line(code, err, pattern)
    assert existing.read_bytes() == b"previous output"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")], "partial file left"


def test_unwritable_folder(files, tmp_path, capfd, monkeypatch):
    import tempfile

    def refuse(*a, **k):
        raise PermissionError(errno.EACCES, "Permission denied")
    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    code, err = _run(["process", files["good"], "-o", tmp_path / "o.exr"], capfd)
    _assert_one_line(code, err, r".*o\.exr: cannot write in .* \(Permission denied\)")
    code, err = _run(["simulate", files["scene"], "-o", tmp_path / "r.dng"], capfd)
    _assert_one_line(code, err, r"cannot write raw file '.*r\.dng': .*Permission denied")


def test_disk_full_output_keeps_previous(files, tmp_path, capfd, monkeypatch):
    """A write that fails (ENOSPC from the library) leaves the previous output as it was."""
    import OpenImageIO as oiio
    real = oiio.ImageOutput.create

    class Full:
        def __init__(self, *a):
            self.out = real(*a)

        def open(self, *a):
            return self.out.open(*a)

        def write_scanlines(self, *a):
            return False

        def geterror(self):
            return "No space left on device"

        def close(self):
            return self.out.close()
    monkeypatch.setattr(oiio.ImageOutput, "create", lambda *a: Full(*a))
    out = tmp_path / "o.exr"
    out.write_bytes(b"previous output")
    code, err = _run(["process", files["good"], "-o", out], capfd)
    _assert_one_line(code, err, r".*o\.exr: write failed \(No space left on device\)")
    assert out.read_bytes() == b"previous output" and len(list(tmp_path.iterdir())) == 1


def test_disk_full_raw(files, tmp_path, capfd, monkeypatch):
    import tifffile

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")
    monkeypatch.setattr(tifffile, "imwrite", full)
    code, err = _run(["simulate", files["scene"], "-o", tmp_path / "r.dng"], capfd)
    _assert_one_line(code, err, r"cannot write raw file '.*r\.dng': .*No space left on device")
    assert list(tmp_path.iterdir()) == []


def test_interrupted_leaves_no_file(files, tmp_path, capfd, monkeypatch):
    """Ctrl-C while the output is written: 'clisp: interrupted; no output written', exit 130, the
    temporary file removed and a previous output kept."""
    from clisp.io import imageio

    def interrupt(self, rows):
        raise KeyboardInterrupt
    monkeypatch.setattr(imageio.ImageWriter, "_write_rows", interrupt)
    out = tmp_path / "o.exr"
    out.write_bytes(b"previous output")
    code = main(["process", str(files["good"]), "-o", str(out)])
    err = capfd.readouterr().err
    assert code == 130 and err == "clisp: interrupted; no output written\n"
    assert out.read_bytes() == b"previous output" and len(list(tmp_path.iterdir())) == 1


@pytest.mark.stress
def test_sigint_subprocess(files, tmp_path):
    """A real SIGINT to ``clisp process`` of a raw large enough to be caught mid-run."""
    from clisp.io.rawfile import read_raw
    big = read_raw(files["good"])
    big.data = np.tile(big.data, (40, 40))
    write_raw(tmp_path / "big.dng", big)
    proc = subprocess.Popen([sys.executable, "-m", "clisp", "process", str(tmp_path / "big.dng"), "-o",
                             str(tmp_path / "o.exr"), "--tile", "64"], stderr=subprocess.PIPE, text=True)
    import time
    time.sleep(4.0)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    if proc.returncode == 0:
        pytest.skip("the run finished before the signal")
    assert proc.returncode == 130 and err.strip().splitlines()[-1] == "clisp: interrupted; no output written"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["big.dng"]


def test_non_finite_output_is_not_written(tmp_path):
    """The writers' last guard: float rows with NaN/Inf never reach a file."""
    image = np.zeros((8, 8, 3), np.float32)
    image[2, 3, 1] = np.nan
    with pytest.raises(ClispError, match=r"o\.exr: 1 non-finite values in output rows 0\.\.7; nothing written"):
        write_image(tmp_path / "o.exr", image)
    assert list(tmp_path.iterdir()) == []


def test_library_stderr_is_folded(tmp_path):
    """What LibRaw prints on stderr ('file: Unexpected end of file') comes in our one line only:
    run as a subprocess so that the real file descriptor 2 is seen."""
    kdc = CAMERA_RAWS / "RAW_KODAK_DC50.KDC"
    if not kdc.is_file():
        pytest.skip("no camera raws in ../shared/data/raw")
    cut = tmp_path / "cut.kdc"
    cut.write_bytes(kdc.read_bytes()[:50000])
    damaged = tmp_path / "hdr.dng"
    data = bytearray(cut.read_bytes()[:0] or b"II*\0" + (8).to_bytes(4, "little") + bytes(200))
    damaged.write_bytes(bytes(data))
    for path in (cut, damaged):
        r = subprocess.run([sys.executable, "-m", "clisp", "process", str(path), "-o", str(tmp_path / "o.exr")],
                           capture_output=True, text=True)
        assert r.returncode == 2 and r.stderr.count("\n") == 1 and r.stderr.startswith("clisp: error:"), r.stderr
        assert len(r.stderr.rstrip("\n")) <= MAX_MESSAGE


def test_catalogue_lists_every_message():
    """docs/messages.md has one row per message id here (and no other)."""
    ids = set(re.findall(r"^\| `([a-z-]+)` \|", DOC.read_text(), flags=re.M))
    assert ids == set(MESSAGES) | set(FAULTS)
