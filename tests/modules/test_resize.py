"""--resize (clisp.modules.resize): the kernels against the NumPy reference, band splits bit for bit,
the sizes (never enlarged) and the refusal, aliasing on a small zone plate (ours against nearest and
bilinear), and through ``clisp process`` / ``clisp batch``: tiled equals whole, the crop and the
camera's orientation, every output format, the metadata. Scenes are made in code.

Tolerance of the kernel-reference comparison: tests/tolerance.py (float32 sums of up to 2 ceil(3 s)
+ 1 taps against float64, weights rounded to float32: a few 1e-7 in practice); 16-bit codes within
one code (the device's polynomial sRGB curve against the reference's pow, float32 against float64).
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from paths import TOOLS
from tolerance import assert_close
import clisp
from clisp.app.cli import build_parser, main
from clisp.errors import ClispError
from clisp.io.imageio import read_image
from clisp.io.rawfile import write_raw
from clisp.modules.colour.stage import ToneCurve
from clisp.modules.resize.stage import (check_long_edge, filter_taps, resize_image, resize_reference,
                                        resized_size)
from clisp.pipeline import process_file
from clisp.sim.charts import demo_chart
from clisp.sim.simulate import simulate

sys.path.insert(0, str(TOOLS))
import bench_resize  # noqa: E402  (tools/ is not a package)

TARGETS = [(18, 26), (40, 58), (53, 77), (5, 7), (53, 20)]
"""Of a 53 x 77 image: scale 3, mild (1.3), the identity, strong (11), one axis only."""


@pytest.fixture(scope="module")
def image() -> np.ndarray:
    """53 x 77 x 3 linear values, unclipped (a pipeline's output may leave [0, 1])."""
    return np.random.default_rng(0).uniform(-0.1, 1.2, (53, 77, 3))


@pytest.mark.parametrize("target", TARGETS)
def test_kernels_match_reference(image: np.ndarray, target: tuple[int, int]) -> None:
    reference = resize_reference(image, *target)
    assert_close(resize_image(image.astype(np.float32), *target, band=16), reference, f"linear {target}")
    codes = resize_image(image.astype(np.float32), *target, output="srgb16", band=16)
    expected = ToneCurve(quantize=True).reference(reference, (0, 0))
    assert codes.dtype == np.uint16 and np.abs(codes.astype(int) - expected).max() <= 1


def test_taps_are_a_stretched_normalised_lanczos() -> None:
    taps = filter_taps(6000, 2048)
    assert np.allclose(taps.weights.sum(axis=1), 1.0)
    assert taps.count == 2 * 9 + 1                          # support 3 x 2.93 input pixels each side
    assert taps.starts.min() == 0 and taps.starts.max() + taps.count == 6000
    same = filter_taps(77, 77)                              # no resampling: the identity
    assert np.allclose(same.weights[np.arange(77), np.arange(77) - same.starts], 1.0)


def test_band_splits_are_bit_identical(image: np.ndarray) -> None:
    """An output row does not depend on how its input rows arrived: the whole image at once, 1, 13,
    64 rows. 301 rows pass a window of 2 x 21 taps + CHUNK_ROWS = 106 rows: it moves its rows up
    on the way, and the result is still the reference's."""
    pixels = np.tile(image, (6, 2, 1))[:301, :130].astype(np.float32)
    whole = resize_image(pixels, 97, 42, band=301)
    assert_close(whole, resize_reference(pixels, 97, 42), "through the rolling window")
    for band in (1, 13, 64):
        assert np.array_equal(resize_image(pixels, 97, 42, band=band), whole), band


def test_uploaded_rows_as_on_a_discrete_gpu(image: np.ndarray, rt, monkeypatch) -> None:
    """A device that does not share host memory gets each band uploaded (PoCL reads it in place):
    the same pixels."""
    pixels = np.tile(image, (6, 2, 1))[:301, :130].astype(np.float32)
    in_place = resize_image(pixels, 97, 42, band=64)
    monkeypatch.setattr(rt, "host_unified", False)
    assert np.array_equal(resize_image(pixels, 97, 42, band=64), in_place)


def test_sizes_never_enlarge_and_refusals() -> None:
    assert resized_size(4000, 6000, 2048) == (1365, 2048)
    assert resized_size(6000, 4000, 2048) == (2048, 1365)
    assert resized_size(10, 20, 15) == (8, 15)                      # 7.5 rounds up
    assert resized_size(100, 200, 200) == resized_size(100, 200, 4000) == (100, 200)
    assert check_long_edge("16") == 16 and check_long_edge(2048) == 2048
    for bad in ("8", "2048.5", "2k", "-5", ""):
        with pytest.raises(ClispError, match="the long edge must be a whole number of pixels, at least 16"):
            check_long_edge(bad)


def test_zone_plate_alias_below_what_nearest_leaves() -> None:
    """360 x 240 zone plate (input Nyquist at the corners) to long edge 120: where an ideal output
    is flat (local frequency past 1.25 x the output's Nyquist) ours leaves -31 dB of the pattern,
    nearest and bilinear interpolation about 0 dB (tools/bench_resize.py, docs/RESULTS.md)."""
    plate = bench_resize.zone_plate(240, 360)
    alias = {name: bench_resize.figures(fn(plate, 80, 120), (240, 360))["alias"]
             for name, fn in bench_resize.RESAMPLERS.items()}
    assert alias["clisp --resize (Lanczos-3, device)"] < -25.0, alias
    assert alias["nearest"] > -5.0 and alias["bilinear (no low-pass)"] > -5.0, alias


# ---------------------------------------------------------------------------------- the commands

@pytest.fixture(scope="module")
def raw_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 240 x 160 Bayer raw of the demo chart at gain 4."""
    path = tmp_path_factory.mktemp("resize") / "r.dng"
    write_raw(path, simulate(demo_chart().image[:160, :240], cfa="bayer", gain=4, optics="none").raw)
    return path


def run(args: list, capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def test_process_tiled_equals_whole_every_format(raw_path: Path, tmp_path: Path, capsys) -> None:
    """--resize 64 of 240 x 160: 64 x 43 in every format, the line says so, tiles of 32 give the
    same pixels as one tile (--no-skip: with skipping, tiles may take other paths than the whole)."""
    outputs = {}
    for name, extra in (("whole.tif", []), ("tiled.tif", ["--tile", "32"]), ("o.exr", []), ("o.png", []),
                        ("o.jpg", [])):
        code, out, err = run(["process", raw_path, "-o", tmp_path / name, "--preset", "fast", "--no-skip",
                              "--resize", "64", *extra], capsys)
        assert code == 0, err
        assert out.startswith(f"{tmp_path / name}: 64x43 (resized from 240x160) from"), out
        outputs[name] = read_image(tmp_path / name)[0]
        assert outputs[name].shape == (43, 64, 3)
    assert np.array_equal(outputs["whole.tif"], outputs["tiled.tif"])
    assert np.array_equal(outputs["whole.tif"], outputs["o.png"])
    linear = clisp.process(raw_path, preset="fast")
    assert_close(outputs["o.exr"], resize_reference(linear, 43, 64), "EXR against the reference")
    assert np.abs(outputs["o.jpg"] - outputs["whole.tif"]).mean() < 0.02     # JPEG: 8 bits, compressed


def test_process_never_enlarges(raw_path: Path, tmp_path: Path, capsys) -> None:
    code, out, err = run(["process", raw_path, "-o", tmp_path / "o.tif", "--preset", "fast", "--resize", "500"],
                         capsys)
    assert code == 0, err
    assert "240x160 (--resize 500: long edge 240 kept, never enlarged)" in out
    assert read_image(tmp_path / "o.tif")[0].shape == (160, 240, 3)


@pytest.mark.parametrize("flip", [0, 6])
def test_crop_and_orientation_come_before_the_resize(raw_path: Path, tmp_path: Path, flip: int) -> None:
    """The long edge is the final output's: after the declared crop and the camera's rotation (6:
    90 degrees clockwise, oriented in memory); the pixels are the reference's resize of that image.
    The metadata says what was done and claims no other size."""
    import OpenImageIO as oiio
    raw = clisp.read_raw(raw_path)
    raw.metadata["crop"] = [10, 20, 120, 200]
    raw.metadata["flip"] = flip
    upright = clisp.process(raw, preset="fast")                  # cropped and oriented
    h, w = upright.shape[:2]
    target = resized_size(h, w, 50)
    size, _ = process_file(raw, tmp_path / "o.exr", resize=50, preset="fast")
    assert size == target == ((30, 50) if flip == 0 else (50, 30))
    assert_close(read_image(tmp_path / "o.exr")[0], resize_reference(upright, *target), f"flip {flip}")
    process_file(raw, tmp_path / "o.jpg", resize=50, preset="fast")
    spec = oiio.ImageInput.open(str(tmp_path / "o.jpg")).spec()
    assert (spec.height, spec.width) == target
    assert spec.getattribute("ImageDescription").endswith(
        f"resized from {w}x{h} to {target[1]}x{target[0]} (clisp, Lanczos-3 in linear light)")
    assert spec.getattribute("Exif:PixelXDimension") in (None, target[1])


def test_reference_backend_resizes_too(raw_path: Path, tmp_path: Path) -> None:
    process_file(clisp.read_raw(raw_path), tmp_path / "o.exr", resize=64, preset="fast", backend="reference")
    linear = clisp.process(raw_path, preset="fast", backend="reference")
    assert_close(read_image(tmp_path / "o.exr")[0], resize_reference(linear, 43, 64), "reference backend")


def test_batch_takes_resize(raw_path: Path, tmp_path: Path, capsys) -> None:
    """clisp batch --resize: parsed, checked before any cluster starts, hashed when set, applied."""
    from clisp.app.batch import BatchSettings, Job, process_one
    assert build_parser().parse_args(["batch", "in", "-o", "out", "--resize", "64"]).resize == "64"
    code, _, err = run(["batch", raw_path, "-o", tmp_path / "out", "--resize", "8"], capsys)
    assert code == 2 and "--resize 8: the long edge must be" in err and not (tmp_path / "out").exists()
    assert BatchSettings().digest() == BatchSettings(resize=None).digest() != BatchSettings(resize=64).digest()
    settings = BatchSettings(preset="fast", format="tif", resize=64)
    record = process_one(Job(str(raw_path), str(tmp_path / "r.tif")), settings, settings.digest(), "run")
    assert record["status"] == "ok", record
    assert (record["height"], record["width"]) == (43, 64) == read_image(tmp_path / "r.tif")[0].shape[:2]


def test_half_size_then_resize(raw_path: Path, tmp_path: Path, capsys) -> None:
    """--half-size --resize: the long edge is measured on the half-size image (120 x 80 here), which is
    then resized (64 x 43) or kept (--resize 500); tiled equals whole."""
    code, out, err = run(["process", raw_path, "-o", tmp_path / "h.tif", "--half-size", "--resize", "64"], capsys)
    assert code == 0, err
    assert "64x43 (resized from 120x80)" in out
    code, out, err = run(["process", raw_path, "-o", tmp_path / "t.tif", "--half-size", "--resize", "64",
                          "--tile", "16"], capsys)
    assert code == 0, err
    assert np.array_equal(read_image(tmp_path / "h.tif")[0], read_image(tmp_path / "t.tif")[0])
    code, out, err = run(["process", raw_path, "-o", tmp_path / "k.tif", "--half-size", "--resize", "500"], capsys)
    assert code == 0, err
    assert "120x80 (--resize 500: long edge 120 kept, never enlarged)" in out
    assert read_image(tmp_path / "k.tif")[0].shape == (80, 120, 3)
