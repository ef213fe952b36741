"""End-to-end: the CLI contract, the array API, bad input and camera raws.

Scenes are generated in code; camera raws in ../shared/data/raw are used when present (skipped in
a user's clone, which has no ../shared).
"""
from __future__ import annotations

import re

from pathlib import Path

import numpy as np
import pytest

from paths import CAMERA_RAWS
import clisp
from clisp.sim.charts import demo_chart
from clisp.app.cli import main
from clisp.io.imageio import read_image, write_image
from clisp.metrics import psnr
from clisp.pipeline import crop_of
from clisp.io.rawfile import read_raw



@pytest.fixture(scope="module")
def scene_png(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 16-bit sRGB PNG of the top-left 256 x 320 of the demo chart."""
    path = tmp_path_factory.mktemp("scene") / "chart.png"
    write_image(path, demo_chart().image[:256, :320], encoded=False)
    return path


def run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("cfa", ["lms", "bayer"])
def test_simulate_then_process(tmp_path: Path, scene_png: Path, cfa: str, capsys) -> None:
    raw_path, truth_path = tmp_path / "r.dng", tmp_path / "truth.exr"
    code, _, err = run(["simulate", scene_png, "-o", raw_path, "--cfa", cfa, "--noiseless",
                        "--truth", truth_path], capsys)
    assert code == 0, err
    for out_name in ("o.exr", "o.png", "o.tif"):
        code, out, err = run(["process", raw_path, "-o", tmp_path / out_name, "--tile", "64"], capsys)
        assert code == 0, err
        assert "MP/s" in out
    linear, is_float = read_image(tmp_path / "o.exr")
    encoded, _ = read_image(tmp_path / "o.png")
    truth, _ = read_image(truth_path)
    assert is_float and linear.shape == truth.shape == encoded.shape == (256, 320, 3)
    # Flat ColorChecker patches come back exactly (noiseless; linear demosaic of a constant).
    y0, y1, x0, x1 = 40, 60, 200, 220   # inside the first patch row of the chart crop
    assert np.allclose(linear[y0:y1, x0:x1], truth[y0:y1, x0:x1], atol=2e-3)
    assert psnr(linear, truth) > 15.0
    # The 16-bit PNG is the tone-mapped EXR within one 16-bit step (plus float32 rounding).
    from clisp.sim.colorimetry import srgb_encode
    assert np.abs(encoded - srgb_encode(linear)).max() < 2.0 / 65535


def test_array_api_matches_cli_pipeline(scene_png: Path) -> None:
    scene = demo_chart().image[:128, :128]
    sim = clisp.simulate(scene, cfa="lms", gain=8, seed=3)
    again = clisp.simulate(scene, cfa="lms", gain=8, seed=3)
    assert np.array_equal(sim.raw.data, again.raw.data)
    out = clisp.process(sim.raw)
    ref = clisp.process(sim.raw, backend="reference")
    assert out.shape == (128, 128, 3) and out.dtype == np.float32
    assert np.abs(out - ref).max() <= 1e-5 * max(1.0, float(np.abs(ref).max()))


def test_raw_file_round_trip_through_cli(tmp_path: Path, scene_png: Path, capsys) -> None:
    raw_path = tmp_path / "r.dng"
    assert run(["simulate", scene_png, "-o", raw_path, "--gain", "8", "--seed", "5"], capsys)[0] == 0
    raw = read_raw(raw_path)
    direct = clisp.simulate(clisp.io.imageio.read_scene(scene_png), cfa="lms", gain=8, seed=5).raw
    assert np.array_equal(raw.data, direct.data)
    assert raw.metadata["gain"] == 8 and raw.metadata["seed"] == 5


def test_info(tmp_path: Path, scene_png: Path, capsys) -> None:
    raw_path = tmp_path / "r.dng"
    run(["simulate", scene_png, "-o", raw_path, "--cfa", "bayer"], capsys)
    code, out, _ = run(["info", raw_path], capsys)
    assert code == 0 and "bayer-rggb" in out
    code, out, _ = run(["info", "--device"], capsys)
    assert code == 0 and "clisp uses:" in out


def _bad_inputs(tmp_path: Path, good_raw: Path) -> dict[str, Path]:
    truncated = tmp_path / "truncated.dng"
    truncated.write_bytes(good_raw.read_bytes()[:5000])
    text = tmp_path / "notes.txt"
    text.write_text("not a raw file\n")
    return {"missing": tmp_path / "missing.dng", "truncated": truncated, "unsupported": text}


def test_bad_input_exits_nonzero_without_output(tmp_path: Path, scene_png: Path, capsys) -> None:
    good = tmp_path / "good.dng"
    run(["simulate", scene_png, "-o", good], capsys)
    for kind, path in _bad_inputs(tmp_path, good).items():
        out_path = tmp_path / f"out_{kind}.exr"
        code, _, err = run(["process", path, "-o", out_path], capsys)
        assert code == 2, kind
        assert path.name in err and err.count("\n") == 1, err
        assert not out_path.exists()
    leftovers = [p.name for p in tmp_path.iterdir() if "partial" in p.name]
    assert leftovers == []


def test_bad_options(tmp_path: Path, scene_png: Path, capsys) -> None:
    raw_path = tmp_path / "r.dng"
    run(["simulate", scene_png, "-o", raw_path], capsys)
    for args in (["--demosaic", "nope"], ["--preset", "nope"], ["--tile", "4"]):
        code, _, err = run(["process", raw_path, "-o", tmp_path / "o.exr", *args], capsys)
        assert code == 2 and err.startswith("clisp: error:")
    code, _, err = run(["process", raw_path, "-o", tmp_path / "o.bmp"], capsys)
    assert code == 2 and "o.bmp" in err
    code, _, err = run(["simulate", scene_png, "-o", tmp_path / "x.dng", "--gain", "100"], capsys)
    assert code == 2 and not (tmp_path / "x.dng").exists()
    assert not (tmp_path / "o.exr").exists()


def test_failed_write_leaves_no_file(tmp_path: Path, monkeypatch) -> None:
    import OpenImageIO as oiio

    class Broken:
        def open(self, *args):
            return True

        def write_scanlines(self, *args):
            return False

        def geterror(self):
            return "disk full"

        def close(self):
            pass

    monkeypatch.setattr(oiio.ImageOutput, "create", lambda *a: Broken())
    with pytest.raises(clisp.errors.ClispError, match="disk full"):
        write_image(tmp_path / "o.exr", np.zeros((8, 8, 3), np.float32))
    assert list(tmp_path.iterdir()) == []


def test_demo(tmp_path: Path, capsys) -> None:
    code, out, err = run(["demo", "--out", tmp_path], capsys)
    assert code == 0, err
    assert "gray-panel SNR" in out and "throughput" in out
    rows = [line.split() for line in out.splitlines() if line.startswith(("lms ", "bayer "))]
    assert len(rows) == 6
    for row in rows:   # PSNR, linear, zone, six SNRs, MP/s: all finite numbers
        values = [float(v) for v in row[2:]]
        assert len(values) == 10 and all(np.isfinite(values))
    assert {p.name for p in tmp_path.glob("*.png")} >= {"scene.png", "lms_gain8.png", "bayer_gain64.png"}


@pytest.mark.skipif(not CAMERA_RAWS.is_dir(), reason="no ../shared/data/raw (camera raws)")
@pytest.mark.parametrize("name", sorted(p.name for p in CAMERA_RAWS.glob("*")) if CAMERA_RAWS.is_dir() else [])
def test_camera_raw_to_exr(tmp_path: Path, name: str, capsys) -> None:
    out_path = tmp_path / "cam.exr"
    code, _, err = run(["process", CAMERA_RAWS / name, "-o", out_path], capsys)
    assert code == 0, err
    image, is_float = read_image(out_path)
    raw = read_raw(CAMERA_RAWS / name)
    crop = crop_of(raw)                     # the file's crop is applied by default
    assert is_float and image.shape[:2] == (raw.shape if crop is None else crop[2:])
    assert np.all(np.isfinite(image)) and 0.0 < float(image.mean()) < 2.0


def test_compression_option(tmp_path: Path, scene_png: Path, capsys) -> None:
    raw_path = tmp_path / "r.dng"
    run(["simulate", scene_png, "-o", raw_path, "--gain", "4"], capsys)
    plain, zipped = tmp_path / "plain.exr", tmp_path / "zipped.exr"
    assert run(["process", raw_path, "-o", plain], capsys)[0] == 0
    assert run(["process", raw_path, "-o", zipped, "--compression", "zip"], capsys)[0] == 0
    assert np.array_equal(read_image(plain)[0], read_image(zipped)[0])
    assert zipped.stat().st_size < plain.stat().st_size
    code, _, err = run(["process", raw_path, "-o", tmp_path / "bad.exr", "--compression", "bogus"], capsys)
    assert code == 2 and "bogus" in err and not (tmp_path / "bad.exr").exists()


def test_jpeg_output(tmp_path: Path, scene_png: Path, capsys) -> None:
    """-o x.jpg: an 8-bit sRGB JPEG (chroma 4:4:4) with the sRGB ICC profile and the raw's make and
    model, read back by OpenImageIO and Pillow; its pixels are the 16-bit TIFF's to within JPEG's loss;
    --compression jpeg:N sets the quality (larger N, larger file); the many-file form takes
    --format jpg."""
    import OpenImageIO as oiio
    from PIL import Image
    raw_path = tmp_path / "r.dng"
    assert run(["simulate", scene_png, "-o", raw_path, "--gain", "4"], capsys)[0] == 0
    for name, extra in (("o.tif", []), ("o.jpg", []), ("q60.jpg", ["--compression", "jpeg:60"])):
        assert run(["process", raw_path, "-o", tmp_path / name, "--preset", "fast", *extra], capsys)[0] == 0
    spec = oiio.ImageInput.open(str(tmp_path / "o.jpg")).spec()
    assert spec.format == "uint8" and spec.getattribute("Model") and spec.getattribute("Make") == "clisp"
    with Image.open(tmp_path / "o.jpg") as im:
        assert im.format == "JPEG" and im.mode == "RGB" and len(im.info["icc_profile"]) == 588
        assert im.getexif()[272] == spec.getattribute("Model")
        jpeg = np.asarray(im, dtype=np.float64) / 255.0
    tiff = read_image(tmp_path / "o.tif")[0]
    assert np.abs(jpeg - tiff).mean() < 0.02                      # a noisy raw (fast: no denoiser): 0.013
    assert np.abs((jpeg - tiff).mean(axis=(0, 1))).max() < 0.002  # no shift: 16-bit codes to 8 bits rounded
    assert (tmp_path / "q60.jpg").stat().st_size < (tmp_path / "o.jpg").stat().st_size
    assert run(["process", raw_path, "-o", tmp_path / "many", "--format", "jpg", "--preset", "fast"], capsys)[0] == 0
    assert (tmp_path / "many" / "r.jpg").is_file()


@pytest.mark.skipif(not CAMERA_RAWS.is_dir(), reason="no ../shared/data/raw (camera raws)")
def test_thumb_extracts_the_embedded_preview(tmp_path: Path, capsys) -> None:
    """clisp thumb: the D30's JPEG preview copied byte for byte to a .jpg, decoded into a PNG of the
    same size (and linear in an EXR); the DC50's bitmap preview encoded; no preview is an error."""
    import rawpy
    from PIL import Image
    d30 = CAMERA_RAWS / "RAW_CANON_D30_SRGB.CRW"
    with rawpy.imread(str(d30)) as raw:
        stored = bytes(raw.extract_thumb().data)
    code, out, err = run(["thumb", d30, "-o", tmp_path / "t.jpg"], capsys)
    assert code == 0 and (tmp_path / "t.jpg").read_bytes() == stored and "1440x960" in out, err
    assert run(["thumb", d30, "-o", tmp_path / "t.png"], capsys)[0] == 0
    with Image.open(tmp_path / "t.jpg") as jpg:
        decoded = np.asarray(jpg.convert("RGB"), float) / 255.0
    png = read_image(tmp_path / "t.png")[0]
    assert png.shape == decoded.shape == (960, 1440, 3) and np.abs(png - decoded).max() < 1e-4
    assert run(["thumb", d30, "-o", tmp_path / "t.exr"], capsys)[0] == 0
    linear = read_image(tmp_path / "t.exr")[0]
    assert linear.shape == (960, 1440, 3) and 0.0 <= linear.min() and linear.max() <= 1.0
    code, out, _ = run(["thumb", CAMERA_RAWS / "RAW_KODAK_DC50.KDC", "-o", tmp_path / "k.jpg"], capsys)
    assert code == 0 and "bitmap" in out and Image.open(tmp_path / "k.jpg").size == (96, 64)
    code, _, err = run(["thumb", CAMERA_RAWS / "Canon_EOS550D_MagicLantern_colorchart.dng", "-o",
                        tmp_path / "c.jpg"], capsys)
    assert code == 2 and "no embedded preview" in err and not (tmp_path / "c.jpg").exists()


def test_exposure_scales_linear_output_and_is_recorded(tmp_path: Path, scene_png: Path, capsys) -> None:
    """--exposure EV multiplies the linear output by 2^EV (after the colour conversion: the same
    pixels otherwise), says so in the output's description; the batch hashes it only when set."""
    import OpenImageIO as oiio
    from clisp.app.batch import BatchSettings
    raw_path = tmp_path / "r.dng"
    assert run(["simulate", scene_png, "-o", raw_path, "--gain", "4"], capsys)[0] == 0
    images = {}
    for ev in ("0", "1", "-1.5"):
        assert run(["process", raw_path, "-o", tmp_path / f"e{ev}.exr", "--exposure", ev], capsys)[0] == 0
        images[ev] = read_image(tmp_path / f"e{ev}.exr")[0]
    np.testing.assert_allclose(images["1"], 2.0 * images["0"], rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(images["-1.5"], 2.0 ** -1.5 * images["0"], rtol=1e-5, atol=1e-7)
    description = oiio.ImageInput.open(str(tmp_path / "e1.exr")).spec().getattribute("ImageDescription")
    assert description.endswith("exposure +1.00 EV (clisp)")
    assert "exposure" not in (oiio.ImageInput.open(str(tmp_path / "e0.exr")).spec().getattribute("ImageDescription")
                              or "").split(";")[-1]
    assert BatchSettings().digest() == BatchSettings(exposure=0.0).digest() != BatchSettings(exposure=1.0).digest()


def test_process_line_and_profile_read_as_english_and_columns(tmp_path: Path, scene_png: Path, capsys) -> None:
    """One tile is '1 tile', not '1 tiles'; every row of --profile's device table has its columns
    apart (a stage of almost no device time, the download, showed a rate of 1787345.5 MP/s that ran
    into its share: '0.0%1787345.5')."""
    raw_path = tmp_path / "r.dng"
    assert run(["simulate", scene_png, "-o", raw_path, "--gain", "4"], capsys)[0] == 0
    code, out, err = run(["process", raw_path, "-o", tmp_path / "o.tif", "--preset", "fast", "--profile"], capsys)
    assert code == 0, err
    assert "(" in out and " 1 tile of 320x256)" in out.splitlines()[0]
    table = out[out.index("device: stage / kernel"):out.index("host (")].splitlines()[1:]
    assert table and not [line for line in table if re.search(r"%\S", line)]


def test_profile_table_keeps_its_columns_apart() -> None:
    """A stage of a few microseconds of device time (a download of a few bytes) shows '-' for its
    rate, which printed as 1787345.5 ran into the share column; large rates keep a space."""
    from types import SimpleNamespace
    from clisp.engine.profile import Profile

    def event(seconds: float) -> SimpleNamespace:
        return SimpleNamespace(wait=lambda: None, profile=SimpleNamespace(start=0, end=int(seconds * 1e9)))
    profile = Profile(events=[("demosaic", "k", event(0.5)), ("download", "copy", event(0.000014)),
                              ("tone_curve", "t", event(0.0011))])
    lines = profile.report(24.0, 1.0).splitlines()
    rows = {line.split()[0]: line for line in lines if line.startswith("  ") and not line.startswith("    ")}
    assert rows["download"].split()[-1] == "-" and not re.search(r"%\S", rows["download"])
    assert rows["tone_curve"].split()[-1] == "21818.2" and not re.search(r"%\S", rows["tone_curve"])


def test_process_profile_reports_stages_and_host_time(tmp_path: Path, scene_png: Path, capsys, monkeypatch) -> None:
    """``--profile`` prints the device time of the run's stages and kernels and the host activities
    (as a fresh process on a machine that has not calibrated this noise yet: the noise calibration,
    whose upload the profile shows, is neither remembered by an earlier test of this process nor
    kept in the cache folder)."""
    from clisp.modules.chroma_denoise import stage as chroma_stage
    monkeypatch.setattr(chroma_stage, "_CALIBRATIONS", {})
    monkeypatch.setenv("CLISP_CACHE_DIR", str(tmp_path / "cache"))
    raw_path = tmp_path / "r.dng"
    assert run(["simulate", scene_png, "-o", raw_path, "--cfa", "bayer", "--gain", "4"], capsys)[0] == 0
    code, out, err = run(["process", raw_path, "-o", tmp_path / "o.tif", "--profile"], capsys)
    assert code == 0, err
    for expected in ("device: stage / kernel", "demosaic_ri", "ri_green_fit", "chroma_denoise", "joint_bilateral",
                     "upload", "download", "write output", "device total", "start-up",
                     "% of the tile loop", "host per launch_named", "per enqueue", "launches per tile", "bytes moved"):
        assert expected in out, f"{expected!r} missing from the profile:\n{out}"
    busy = int(re.search(r"device busy (\d+) % of the tile loop", out).group(1))
    assert 0 < busy <= 100
    total = float(next(line for line in out.splitlines() if "device total" in line).split()[-1])
    assert total > 0


def test_process_explain_and_no_skip(tmp_path: Path, capsys, monkeypatch: pytest.MonkeyPatch) -> None:
    """``--explain`` prints the analysis, the plan and the time per stage; a flat scene's tiles take
    the flat path, and ``--no-skip`` runs every stage everywhere (issue 13). On the host's CPU, where
    the default skips (clisp.pipeline.skip.why_not_skip), whatever this machine's device."""
    import clisp.pipeline.skip as skip
    monkeypatch.setattr(skip, "on_host_cpu", lambda rt: True)
    from clisp.io.rawfile import write_raw
    from clisp.sim.simulate import simulate
    yy, xx = np.mgrid[0:256, 0:384] / 384.0
    sky = np.stack([0.25 + 0.3 * yy, 0.4 + 0.2 * yy, 0.8 - 0.1 * xx], -1)
    raw_path = tmp_path / "sky.dng"
    write_raw(raw_path, simulate(sky, cfa="lms", gain=1, seed=0).raw)
    code, out, err = run(["process", raw_path, "-o", tmp_path / "a.exr", "--explain", "--tile", "128"], capsys)
    assert code == 0, err
    for expected in ("scene analysis", "noise  L", "skip plan", "flat ", "no detail above the noise",
                     "device time per stage", "demosaic_flat", "time saved"):
        assert expected in out, f"{expected!r} missing from --explain:\n{out}"
    code, out, err = run(["process", raw_path, "-o", tmp_path / "b.exr", "--explain", "--no-skip", "--tile", "128"],
                         capsys)
    assert code == 0, err
    assert "--no-skip" in out and "demosaic_flat" not in out and "demosaic_lms_guided" in out
    a, b = read_image(tmp_path / "a.exr")[0], read_image(tmp_path / "b.exr")[0]
    assert a.shape == b.shape and np.abs(a - b).mean() < 0.01


def test_cli_import_leaves_heavy_libraries_out() -> None:
    """Start-up is part of every command's time (issue 11): importing the CLI must not pull in the
    libraries only some commands or the study code need (scipy.ndimage alone cost 0.16 s)."""
    import subprocess
    import sys
    heavy = ("scipy", "colour", "OpenImageIO", "matplotlib", "rawpy", "exiv2", "PIL")
    code = f"import sys, clisp.app.cli; print(','.join(m for m in {heavy!r} if m in sys.modules))"
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert loaded == "", f"importing clisp.app.cli loads {loaded}"


def test_process_many_inputs_into_a_folder(tmp_path: Path, scene_png: Path, capsys) -> None:
    """Several raws (files and a folder) in one process: OUTDIR/<stem>.<format>, each as a process
    of that file alone would write it; a bad file gets one line naming it and the others go on
    (exit 1); -o a file name with several inputs fails before anything is written."""
    folder = tmp_path / "raws"
    folder.mkdir()
    for name, cfa in (("a", "lms"), ("b", "bayer")):
        assert run(["simulate", scene_png, "-o", folder / f"{name}.dng", "--cfa", cfa, "--gain", "4"], capsys)[0] == 0
    lone = tmp_path / "c.dng"
    assert run(["simulate", scene_png, "-o", lone, "--cfa", "lms", "--gain", "16"], capsys)[0] == 0
    (folder / "bad.dng").write_bytes(b"not a raw")
    (folder / "notes.txt").write_text("skipped: not a raw suffix")
    out = tmp_path / "out"
    code, text, err = run(["process", folder, lone, "-o", out, "--format", "tif"], capsys)
    assert code == 1
    assert sorted(p.name for p in out.iterdir()) == ["a.tif", "b.tif", "c.tif"]
    assert "3 of 4 files written" in text and "1 failed" in text
    assert err.count("\n") == 1 and "bad.dng" in err
    written = [line.split(":")[0] for line in text.splitlines() if ".tif:" in line]
    assert [Path(p).name for p in written] == ["a.tif", "b.tif", "c.tif"]          # in the inputs' order
    for name, path in (("a", folder / "a.dng"), ("c", lone)):
        single = tmp_path / f"{name}-single.tif"
        assert run(["process", path, "-o", single], capsys)[0] == 0
        np.testing.assert_array_equal(read_image(out / f"{name}.tif")[0], read_image(single)[0])
    code, _, err = run(["process", folder / "a.dng", lone, "-o", tmp_path / "x.tif"], capsys)
    assert code == 2 and "output folder" in err and not (tmp_path / "x.tif").exists()


def test_process_one_input_into_an_existing_folder(tmp_path: Path, scene_png: Path, capsys) -> None:
    raw_path = tmp_path / "r.dng"
    assert run(["simulate", scene_png, "-o", raw_path], capsys)[0] == 0
    out = tmp_path / "out"
    out.mkdir()
    code, text, _ = run(["process", raw_path, "-o", out], capsys)
    assert code == 0 and (out / "r.exr").is_file() and "1 of 1 file written" in text
    code, _, _ = run(["process", tmp_path, "-o", tmp_path / "new", "--preset", "fast"], capsys)   # a folder in
    assert code == 0 and (tmp_path / "new" / "r.exr").is_file()


def test_info_device_warm(capsys) -> None:
    code, text, _ = run(["info", "--device", "--warm", "fast"], capsys)
    assert code == 0 and "kernels ready in" in text
    assert [line.split()[:2] for line in text.splitlines() if line.endswith(" s") and "ready" not in line] == \
        [["lms", "fast"], ["bayer", "fast"]]
    code, _, err = run(["info", "--warm"], capsys)
    assert code == 2 and "--device" in err
    code, _, err = run(["info", "--device", "--warm", "fastest"], capsys)
    assert code == 2 and "presets are" in err


def test_console_script_leaves_fast_with_its_status_and_output(tmp_path: Path, scene_png: Path) -> None:
    """``python -m clisp`` (the console entry, clisp.app.cli.console) ends the process without the
    interpreter's teardown: the exit status, the printed line (to a pipe) and the output file are
    all there; a failure still exits 2 with its one line and no file."""
    import subprocess
    import sys
    raw = tmp_path / "r.dng"
    assert main(["simulate", str(scene_png), "-o", str(raw), "--cfa", "bayer", "--optics", "none"]) == 0
    out = tmp_path / "o.tif"
    ok = subprocess.run([sys.executable, "-m", "clisp", "process", str(raw), "-o", str(out), "--preset", "fast"],
                        capture_output=True, text=True)
    assert ok.returncode == 0, ok.stderr
    assert ok.stdout.startswith(f"{out}: ") and ok.stdout.endswith(")\n") and out.is_file()
    bad = subprocess.run([sys.executable, "-m", "clisp", "process", str(tmp_path / "none.dng"), "-o",
                          str(tmp_path / "n.tif")], capture_output=True, text=True)
    assert bad.returncode == 2 and bad.stderr.count("\n") == 1 and "no such file" in bad.stderr
    assert not (tmp_path / "n.tif").exists()
