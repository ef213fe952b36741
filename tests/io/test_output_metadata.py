"""What outputs say about themselves (issue 14): camera EXIF and simulated settings in TIFF, PNG and
EXR, the sRGB ICC profile of TIFF/PNG, EXR's chromaticities, and the DNG's declared crop.

The fixtures are made here: a small DNG that is not ours (so LibRaw reads it, as any camera's)
with Make, Model, exposure tags, an ActiveArea and a DefaultCrop, and our own simulated raws.
The camera raws of ../shared/data/raw are checked too where they are present.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import tifffile

from paths import CAMERA_RAWS
import clisp
from clisp.io import rawfile
from clisp.io.camera import visible_crop
from clisp.cfa import bayer_cfa
from clisp.sim.charts import demo_chart
from clisp.app.cli import main
from clisp.sim.colorimetry import B_BAYER, WB_BAYER
from clisp.io.exif import read_exif
from clisp.io.imageio import SRGB_CHROMATICITIES, read_image, write_image
from clisp.pipeline import crop_of, process_file
from clisp.io.rawfile import read_raw, write_raw
from clisp.io.rawimage import RawImage


RAW_SHAPE = (40, 64)
ACTIVE_AREA = (2, 4, 38, 60)            # top, left, bottom, right: a 36 x 56 visible mosaic
CROP_ORIGIN, CROP_SIZE = (6, 2), (40, 30)   # DNG order: (x, y) and (width, height)
CROP = [2, 6, 30, 40]                   # top, left, height, width in the visible mosaic
SHOT = {"Make": "Acme", "Model": "Tiny 1", "ExposureTime": 1 / 125, "FNumber": 5.6,
        "Exif:DateTimeOriginal": "2024:05:06 07:08:09"}


@pytest.fixture(scope="module")
def camera_dng(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 64 x 40 RGGB DNG as a camera writes one: no clisp metadata, an ActiveArea, a DefaultCrop,
    Make/Model/DateTime in IFD0 and the TIFF/EP exposure tags."""
    y, x = np.mgrid[:RAW_SHAPE[0], :RAW_SHAPE[1]]
    data = (200 + 6 * x + 4 * y + 50 * ((x + y) % 2)).astype(np.uint16)    # smooth, no clipping
    raw = RawImage(data=data, cfa=bayer_cfa("rggb"), black_level=[64.0] * 3, white_level=1023.0,
                   wb=WB_BAYER, colour_matrix=B_BAYER)
    ours = (rawfile.TAG_DNG_PRIVATE_DATA, rawfile.TAG_MAKE, rawfile.TAG_MODEL)
    tags = [t for t in rawfile.dng_tags(raw) if t[0] not in ours]
    tags += [(271, 2, 0, SHOT["Make"], True), (272, 2, 0, SHOT["Model"], True),
             (306, 2, 0, SHOT["Exif:DateTimeOriginal"], True),
             (33434, 5, 1, (1, 125), True), (33437, 5, 1, (56, 10), True),           # ExposureTime, FNumber
             (50829, 4, 4, ACTIVE_AREA, True),
             (rawfile.TAG_DEFAULT_CROP_ORIGIN, 4, 2, CROP_ORIGIN, True),
             (rawfile.TAG_DEFAULT_CROP_SIZE, 4, 2, CROP_SIZE, True)]
    path = tmp_path_factory.mktemp("dng") / "camera.dng"
    tifffile.imwrite(path, data, extratags=tags, **rawfile._TIFF_LAYOUT)
    return path


def run(args: list[object], capsys: pytest.CaptureFixture[str]) -> None:
    code = main([str(a) for a in args])
    _, err = capsys.readouterr()
    assert code == 0, err


def header(path: Path) -> dict[str, object]:
    """The output's attributes as OpenImageIO reads them back."""
    import OpenImageIO as oiio
    inp = oiio.ImageInput.open(str(path))
    assert inp is not None, oiio.geterror()
    try:
        spec = inp.spec()
        attrs = {a.name: a.value for a in spec.extra_attribs}
        attrs["size"] = (spec.width, spec.height)
    finally:
        inp.close()
    return attrs


def assert_colour_space(path: Path, attrs: dict[str, object]) -> None:
    """TIFF/PNG: an embedded ICC profile (a valid header: its size, 'acsp'); EXR: sRGB's xy."""
    if path.suffix == ".exr":
        assert np.allclose(attrs["chromaticities"], SRGB_CHROMATICITIES, atol=1e-6)
    else:
        icc = bytes(np.asarray(attrs["ICCProfile"], dtype=np.uint8))
        assert int.from_bytes(icc[:4], "big") == len(icc) > 128 and icc[36:40] == b"acsp"
        assert icc[16:20] == b"RGB "


def test_dng_exif_and_crop_are_read(camera_dng: Path) -> None:
    raw = read_raw(camera_dng)
    assert raw.shape == (36, 56)                               # ActiveArea removed by LibRaw
    assert raw.metadata["crop"] == CROP and crop_of(raw) == tuple(CROP)
    exif = raw.metadata["exif"]
    assert exif["Make"] == "Acme" and exif["Model"] == "Tiny 1"
    assert exif["ExposureTime"] == pytest.approx(1 / 125) and exif["FNumber"] == pytest.approx(5.6)
    assert exif["Exif:DateTimeOriginal"] == SHOT["Exif:DateTimeOriginal"]


@pytest.mark.parametrize("ext", [".tif", ".png", ".exr"])
def test_outputs_carry_exif_colour_space_and_crop(camera_dng: Path, tmp_path: Path, ext: str, capsys) -> None:
    out = tmp_path / f"o{ext}"
    run(["process", camera_dng, "-o", out, "--preset", "fast"], capsys)
    attrs = header(out)
    assert attrs["size"] == (CROP[3], CROP[2])                 # DefaultCrop applied by default
    for name, value in SHOT.items():
        assert attrs[name] == pytest.approx(value), name
    assert attrs["Orientation"] == 1 and str(attrs["Software"]).startswith("clisp")
    assert_colour_space(out, attrs)


def test_crop_is_the_whole_frame_cropped(camera_dng: Path, tmp_path: Path, capsys) -> None:
    """--no-crop keeps the visible mosaic; the default output is exactly its crop, also when tiled."""
    full, cropped = tmp_path / "full.exr", tmp_path / "crop.exr"
    run(["process", camera_dng, "-o", full, "--preset", "fast", "--no-crop"], capsys)
    run(["process", camera_dng, "-o", cropped, "--preset", "fast", "--tile", "16"], capsys)
    whole, _ = read_image(full)
    part, _ = read_image(cropped)
    top, left, h, w = CROP
    assert whole.shape[:2] == (36, 56) and part.shape[:2] == (h, w)
    assert np.array_equal(part, whole[top:top + h, left:left + w])
    raw = read_raw(camera_dng)
    assert np.array_equal(clisp.process(raw, preset="fast"), clisp.process(raw, preset="fast", crop=False)[
        top:top + h, left:left + w])


def test_visible_crop() -> None:
    assert visible_crop([8, 16, 2160, 4096], (0, 0), (2176, 4128)) == [8, 16, 2160, 4096]
    assert visible_crop([26, 152, 1156, 1734], (26, 152), (1156, 1734)) is None    # the whole area
    assert visible_crop([12, 56, 1440, 2160], (6, 48), (1448, 2176)) == [6, 8, 1440, 2160]
    assert visible_crop([0, 0, 10, 10], (20, 20), (50, 50)) is None                 # outside


def test_our_raws_carry_make_model_and_settings(tmp_path: Path) -> None:
    """A simulated raw names clisp and its sensor and carries its settings; a camera's EXIF kept
    in our DNG (Make/Model tags too) reaches the output."""
    sim = clisp.simulate(demo_chart().image[:48, :64], cfa="bayer", gain=4, seed=2, optics="none")
    write_raw(tmp_path / "sim.dng", sim.raw)
    process_file(read_raw(tmp_path / "sim.dng", lazy=True), tmp_path / "sim.tif", preset="fast")
    attrs = header(tmp_path / "sim.tif")
    assert attrs["Make"] == "clisp" and attrs["Model"] == "clisp Bayer simulated"
    assert '"gain": 4' in attrs["ImageDescription"] and '"seed": 2' in attrs["ImageDescription"]
    assert_colour_space(tmp_path / "sim.tif", attrs)

    sim.raw.metadata["exif"] = {"Make": "Canon", "Model": "Canon EOS D30", "Exif:PhotographicSensitivity": 200}
    write_raw(tmp_path / "cam.dng", sim.raw)
    with tifffile.TiffFile(tmp_path / "cam.dng") as tif:
        tags = tif.pages[0].tags
        assert tags[271].value == "Canon" and tags[272].value == "Canon EOS D30"
    assert read_exif(tmp_path / "cam.dng")["Model"] == "Canon EOS D30"
    process_file(read_raw(tmp_path / "cam.dng", lazy=True), tmp_path / "cam.exr", preset="fast")
    attrs = header(tmp_path / "cam.exr")
    assert attrs["Make"] == "Canon" and attrs["Model"] == "Canon EOS D30"
    assert attrs["Exif:PhotographicSensitivity"] == 200
    assert_colour_space(tmp_path / "cam.exr", attrs)


# ------------------------------------------------------------------------------------------
# real camera raws (skipped when ../shared/data/raw is absent)
# ------------------------------------------------------------------------------------------

def camera_raw(name: str) -> Path:
    path = CAMERA_RAWS / name
    if not path.is_file():
        pytest.skip(f"camera raw {path} not available")
    return path


@pytest.mark.parametrize("name", ["Canon_EOS550D_MagicLantern_colorchart.dng", "RAW_KODAK_DC50.KDC"])
def test_camera_make_model_in_tiff_and_exr(name: str, tmp_path: Path, capsys) -> None:
    path = camera_raw(name)
    with tifffile.TiffFile(path) as tif:                       # the raw's own IFD0, another reader
        make, model = tif.pages[0].tags[271].value, tif.pages[0].tags[272].value
    for ext in (".tif", ".exr"):
        out = tmp_path / f"o{ext}"
        run(["process", path, "-o", out, "--preset", "fast"], capsys)
        attrs = header(out)
        assert (attrs["Make"], attrs["Model"]) == (make.strip("\0 "), model.strip("\0 "))
        assert_colour_space(out, attrs)


def test_blackmagic_default_crop(tmp_path: Path, capsys) -> None:
    path = camera_raw("Blackmagic_PocketCinema4K.dng")
    raw = read_raw(path, lazy=True)
    assert raw.shape == (2176, 4128) and crop_of(raw) == (8, 16, 2160, 4096)
    run(["process", path, "-o", tmp_path / "bm.tif", "--preset", "fast"], capsys)
    assert header(tmp_path / "bm.tif")["size"] == (4096, 2160)


def test_srgb_profile_kept_in_the_cache_folder(tmp_path, monkeypatch):
    """The sRGB ICC profile is made by Pillow once and then read from the cache folder, without
    importing Pillow; a damaged copy is made again."""
    import sys
    from clisp.io import imageio
    monkeypatch.setenv("CLISP_CACHE_DIR", str(tmp_path))
    imageio.srgb_icc_profile.cache_clear()
    made = imageio.srgb_icc_profile()
    (kept,) = (tmp_path / "icc").iterdir()
    assert kept.read_bytes() == made and made[36:40] == b"acsp"
    imageio.srgb_icc_profile.cache_clear()
    monkeypatch.setitem(sys.modules, "PIL", None)                    # importing Pillow would fail
    assert imageio.srgb_icc_profile() == made
    kept.write_bytes(b"damaged")
    imageio.srgb_icc_profile.cache_clear()
    monkeypatch.delitem(sys.modules, "PIL")
    assert imageio.srgb_icc_profile() == made and kept.read_bytes() == made
    imageio.srgb_icc_profile.cache_clear()


@pytest.mark.parametrize("ext", [".tif", ".jpg"])
@pytest.mark.parametrize("seconds, f_number, expected", [(1 / 203.2, 11.3, ((1, 203), (113, 10))),
                                                         (1 / 8000, 1.4, ((1, 8000), (14, 10))),
                                                         (2.5, 22.0, ((5, 2), (220, 10)))])
def test_exposure_as_a_camera_writes_it(tmp_path: Path, ext: str, seconds: float, f_number: float, expected) -> None:
    """A TIFF's or JPEG's ExposureTime and FNumber are the fractions a camera writes (1/203, 113/10),
    not the conversions of OpenImageIO's floats (1/203 s was 10578737/2147483648 in a TIFF,
    4926/1000000 in a JPEG); Pillow and OpenImageIO read the same values back."""
    import OpenImageIO as oiio
    from PIL import Image
    out = tmp_path / f"o{ext}"
    write_image(out, np.full((8, 8, 3), 0.5), encoded=False,
                attributes={"Make": "Acme", "Model": "Tiny 1", "ExposureTime": seconds, "FNumber": f_number})
    with Image.open(out) as im:
        exif = im.getexif()
        shot = exif.get_ifd(0x8769)
        got = tuple((r.numerator, r.denominator) for r in (shot[0x829A], shot[0x829D]))
        assert got == expected and (exif[271], exif[272]) == ("Acme", "Tiny 1")
    spec = oiio.ImageInput.open(str(out)).spec()
    assert spec.getattribute("ExposureTime") == pytest.approx(expected[0][0] / expected[0][1], rel=1e-6)
    assert (spec.getattribute("Make"), spec.getattribute("Model")) == ("Acme", "Tiny 1")
