"""Raw file reading and writing: clisp DNG round trips, rawpy interoperability, errors, camera raws."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rawpy
import tifffile

from paths import CAMERA_RAWS
from clisp.io import rawfile
from clisp.io.camera import channel_values, pick_colour_matrix, pick_wb, rgb_cam_from_cam_xyz, visible_pattern
from clisp.cfa import BAYER_PHASES, CFA, bayer_cfa, cfa_from_pattern, lms_cfa
from clisp.sim.colorimetry import B_BAYER, P_LMS, WB_BAYER, WB_LMS, XYZ_TO_SRGB
from clisp.errors import ClispError
from clisp.io.rawfile import raw_info, read_raw, write_raw
from clisp.io.rawimage import NO_CAMERA_WB
from clisp.scene.measure import measure_scene
from clisp.io.rawimage import RawImage

CAMERA_DIR = CAMERA_RAWS

# name -> (cfa name, visible (H, W), black level, white level)
CAMERA_FILES = {
    "Blackmagic_PocketCinema4K.dng": ("bayer-rggb", (2176, 4128), 512, 65535),
    "Canon_EOS550D_MagicLantern_colorchart.dng": ("bayer-rggb", (1156, 1734), 2056, 15000),
    "RAW_CANON_D30_SRGB.CRW": ("bayer-rggb", (1448, 2176), 126, 4095),
    "RAW_KODAK_DC50.KDC": ("bayer-grbg", (512, 768), 0, 16383),
}


# ------------------------------------------------------------------------------------------
# helpers
# ------------------------------------------------------------------------------------------

def make_raw(cfa: CFA, dtype: type = np.uint16, shape: tuple[int, int] = (37, 53), seed: int = 0) -> RawImage:
    """A RawImage with random data (odd sizes on purpose) and non-trivial metadata."""
    rng = np.random.default_rng(seed)
    if dtype == np.uint16:
        data = rng.integers(0, 1024, size=shape, dtype=np.uint16)
        black = [64.0, 65.0, 66.0]
    else:
        data = (rng.random(shape, dtype=np.float32) * 1100.0 - 30.0).astype(np.float32)  # negatives kept
        black = [64.25, 64.5, 63.75]
    matrix, wb = (P_LMS, WB_LMS) if cfa.kind == "lms" else (B_BAYER, WB_BAYER)
    return RawImage(
        data=data, cfa=cfa, black_level=np.array(black), white_level=1023.0, wb=wb.copy(),
        colour_matrix=matrix.copy(), exposure=1.0 / 0.98951, wb2=np.array([1.0, 1.0101, 1.0753]),
        metadata={"gain": 8, "noise": {"read_e": 1.5, "dn_per_e": 0.14}, "seed": seed, "note": "ünïcode",
                  "tuple_free": [1, 2.5, None, True]},
        source="simulated")


def assert_same_raw(a: RawImage, b: RawImage) -> None:
    """Data (dtype and values) and all metadata identical."""
    assert a.data.dtype == b.data.dtype
    assert a.data.shape == b.data.shape
    assert np.array_equal(a.data, b.data, equal_nan=a.data.dtype.kind == "f")
    assert a.cfa == b.cfa
    assert np.array_equal(a.cfa.pattern, b.cfa.pattern)
    assert np.array_equal(a.black_level, b.black_level)
    assert a.white_level == b.white_level
    assert np.array_equal(a.wb, b.wb)
    assert a.exposure == b.exposure
    assert np.array_equal(a.colour_matrix, b.colour_matrix)
    assert np.array_equal(a.wb2, b.wb2)
    assert a.metadata == b.metadata


# ------------------------------------------------------------------------------------------
# round trips
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("dtype", [np.uint16, np.float32])
@pytest.mark.parametrize("phase", [(0, 0), (1, 2)])
def test_round_trip_lms(tmp_path: Path, dtype: type, phase: tuple[int, int]) -> None:
    raw = make_raw(lms_cfa(phase), dtype)
    path = tmp_path / "lms.dng"
    write_raw(path, raw)
    back = read_raw(path)
    assert_same_raw(raw, back)
    assert back.source == str(path)


@pytest.mark.parametrize("phase", BAYER_PHASES)
@pytest.mark.parametrize("dtype", [np.uint16, np.float32])
def test_round_trip_bayer(tmp_path: Path, phase: str, dtype: type) -> None:
    raw = make_raw(bayer_cfa(phase), dtype, seed=3)
    path = tmp_path / f"bayer_{phase}.dng"
    write_raw(path, raw)
    assert_same_raw(raw, read_raw(path))


def test_round_trip_accepts_str_path_and_overwrites(tmp_path: Path) -> None:
    path = tmp_path / "x.dng"
    write_raw(str(path), make_raw(bayer_cfa(), seed=1))
    raw = make_raw(bayer_cfa("GBRG"), seed=2)
    write_raw(str(path), raw)
    assert_same_raw(raw, read_raw(str(path)))
    assert [p.name for p in tmp_path.iterdir()] == ["x.dng"]


def test_numpy_metadata_is_serialised(tmp_path: Path) -> None:
    raw = make_raw(lms_cfa())
    raw.metadata = {"gain": np.int64(4), "k": np.float32(0.5), "arr": np.arange(3)}
    write_raw(tmp_path / "n.dng", raw)
    assert read_raw(tmp_path / "n.dng").metadata == {"gain": 4, "k": 0.5, "arr": [0, 1, 2]}


# ------------------------------------------------------------------------------------------
# file layout (DNG tags)
# ------------------------------------------------------------------------------------------

def _tags(path: Path) -> tuple[dict[int, object], object]:
    with tifffile.TiffFile(path) as tif:
        page = tif.pages[0]
        return {code: tag.value for code, tag in page.tags.items()}, (
            page.photometric, page.rowsperstrip, page.compression, page.subfiletype,
            page.is_contiguous, page.sampleformat, len(page.dataoffsets))


@pytest.mark.parametrize("cfa,dtype", [(lms_cfa(), np.uint16), (lms_cfa(), np.float32),
                                       (bayer_cfa("GRBG"), np.uint16)])
def test_dng_tags(tmp_path: Path, cfa: CFA, dtype: type) -> None:
    raw = make_raw(cfa, dtype, shape=(40, 24))
    path = tmp_path / "t.dng"
    write_raw(path, raw)
    tags, (photometric, rps, compression, subfiletype, contiguous, sampleformat, nstrips) = _tags(path)
    p = cfa.period
    assert int(photometric) == 32803 and rps == 16 and int(compression) == 1 and int(subfiletype) == 0
    assert contiguous and nstrips == 3
    assert int(sampleformat) == (3 if dtype == np.float32 else 1)
    assert tuple(tags[50706]) == (1, 4, 0, 0)
    assert tuple(tags[50707]) == ((1, 4, 0, 0) if dtype == np.float32 else (1, 1, 0, 0))
    assert tags[50708] == ("clisp LMS simulated" if cfa.kind == "lms" else "clisp Bayer simulated")
    assert tuple(tags[33421]) == (p, p)
    assert bytes(tags[33422]) == cfa.dng_pattern
    assert bytes(tags[50710]) == b"\0\1\2"
    assert tags[50711] == 1
    assert tuple(tags[50713]) == (p, p)
    black = np.array(tags[50714], dtype=float).reshape(-1, 2)
    assert np.allclose(black[:, 0] / black[:, 1], raw.black_level[cfa.pattern.ravel()])
    assert tags[50717] == 1023
    assert tags[50778] == 21
    cm = np.array(tags[50721], dtype=float).reshape(9, 2)
    cm = (cm[:, 0] / cm[:, 1]).reshape(3, 3)
    expect = np.diag(1 / raw.wb) @ np.linalg.inv(raw.colour_matrix) @ XYZ_TO_SRGB
    expect /= (expect @ rawfile.D65_XYZ).max()
    assert np.allclose(cm, expect, atol=1e-6)
    assert np.isclose((cm @ rawfile.D65_XYZ).max(), 1.0, atol=1e-6)
    neutral = np.array(tags[50728], dtype=float).reshape(3, 2)
    neutral = neutral[:, 0] / neutral[:, 1]
    assert np.allclose(neutral, (1 / raw.wb) / (1 / raw.wb).max(), atol=1e-6)
    be = np.array(tags[50730], dtype=float).reshape(-1)
    assert np.isclose(be[0] / be[1], np.log2(raw.exposure), atol=1e-6)
    assert bytes(tags[50740]).startswith(b"clisp\0")


# ------------------------------------------------------------------------------------------
# rawpy reads our Bayer files
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("phase", BAYER_PHASES)
def test_bayer_file_opens_in_rawpy(tmp_path: Path, phase: str) -> None:
    raw = make_raw(bayer_cfa(phase), shape=(32, 48), seed=5)
    raw.black_level = np.array([60.0, 64.0, 70.0])
    path = tmp_path / f"{phase}.dng"
    write_raw(path, raw)
    with rawpy.imread(str(path)) as rp:
        assert rp.color_desc == b"RGBG"
        pattern = visible_pattern(rp.raw_pattern, rp.sizes.top_margin, rp.sizes.left_margin)
        assert "".join("RGBG"[i] for i in pattern.ravel()) == phase
        assert cfa_from_pattern(pattern, "RGBG") == raw.cfa
        by_index = {"R": 60, "G": 64, "B": 70}
        assert list(rp.black_level_per_channel) == [by_index[c] for c in "RGBG"]
        assert rp.white_level == 1023
        assert np.array_equal(rp.raw_image, raw.data)
        assert np.array_equal(rp.raw_image_visible, raw.data)


# ------------------------------------------------------------------------------------------
# atomic write
# ------------------------------------------------------------------------------------------

def test_write_is_atomic(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    real = tifffile.imwrite
    seen: list[str] = []

    def failing(name: str, *args: object, **kwargs: object) -> None:
        real(name, *args, **kwargs)             # the temporary file now exists, complete
        seen.append(str(name))
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(tifffile, "imwrite", failing)
    target = tmp_path / "out.dng"
    with pytest.raises(ClispError, match="out.dng"):
        write_raw(target, make_raw(lms_cfa()))
    assert seen and Path(seen[0]).parent == tmp_path
    assert list(tmp_path.iterdir()) == []


def test_failed_write_keeps_existing_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    target = tmp_path / "out.dng"
    old = make_raw(bayer_cfa(), seed=7)
    write_raw(target, old)

    def failing(name: str, *args: object, **kwargs: object) -> None:
        Path(name).write_bytes(b"partial")
        raise RuntimeError("boom")

    monkeypatch.setattr(tifffile, "imwrite", failing)
    with pytest.raises(ClispError):
        write_raw(target, make_raw(lms_cfa()))
    assert [p.name for p in tmp_path.iterdir()] == ["out.dng"]
    assert_same_raw(old, read_raw(target))


def test_write_rejects_unsupported_dtype(tmp_path: Path) -> None:
    raw = make_raw(lms_cfa())
    raw.data = raw.data.astype(np.float64)
    with pytest.raises(ClispError, match="float64"):
        write_raw(tmp_path / "f64.dng", raw)
    assert list(tmp_path.iterdir()) == []


def test_write_into_missing_folder(tmp_path: Path) -> None:
    with pytest.raises(ClispError, match="nope.dng"):
        write_raw(tmp_path / "missing" / "nope.dng", make_raw(lms_cfa()))


# ------------------------------------------------------------------------------------------
# read errors
# ------------------------------------------------------------------------------------------

def _expect_error(path: Path, *words: str) -> str:
    with pytest.raises(ClispError) as info:
        read_raw(path)
    msg = str(info.value)
    assert path.name in msg
    assert "\n" not in msg
    for w in words:
        assert w in msg.lower()
    return msg


def test_missing_file(tmp_path: Path) -> None:
    _expect_error(tmp_path / "missing.dng", "no such file")


def test_empty_file(tmp_path: Path) -> None:
    path = tmp_path / "empty.dng"
    path.write_bytes(b"")
    _expect_error(path, "empty")


def test_folder(tmp_path: Path) -> None:
    path = tmp_path / "dir.dng"
    path.mkdir()
    _expect_error(path, "folder")


@pytest.mark.parametrize("fraction", [0.5, 0.9])
def test_truncated_file(tmp_path: Path, fraction: float) -> None:
    full = tmp_path / "full.dng"
    write_raw(full, make_raw(lms_cfa(), shape=(64, 64)))
    blob = full.read_bytes()
    path = tmp_path / "half.dng"
    path.write_bytes(blob[: int(len(blob) * fraction)])
    _expect_error(path, "truncated")


def test_truncated_header(tmp_path: Path) -> None:
    full = tmp_path / "full.dng"
    write_raw(full, make_raw(lms_cfa(), shape=(64, 64)))
    path = tmp_path / "stub.dng"
    path.write_bytes(full.read_bytes()[:20])
    _expect_error(path)


def test_text_file(tmp_path: Path) -> None:
    path = tmp_path / "notes.txt"
    path.write_text("shopping list: milk, eggs\n" * 20)
    _expect_error(path, "text file", "not a raw file")


def test_png_file(tmp_path: Path) -> None:
    import OpenImageIO as oiio

    path = tmp_path / "image.png"
    pixels = (np.arange(16 * 16 * 3) % 256).astype(np.uint8).reshape(16, 16, 3)
    out = oiio.ImageOutput.create(str(path))
    assert out is not None
    out.open(str(path), oiio.ImageSpec(16, 16, 3, "uint8"))
    out.write_image(pixels)
    out.close()
    _expect_error(path, "png image", "not a raw file")


def test_plain_tiff_is_not_a_raw(tmp_path: Path) -> None:
    path = tmp_path / "rgb.tif"
    tifffile.imwrite(path, np.zeros((16, 16, 3), np.uint8), photometric="rgb")
    _expect_error(path)


def test_unsupported_cfa(tmp_path: Path) -> None:
    raw = make_raw(lms_cfa())
    path = tmp_path / "weird.dng"
    write_raw(path, raw)
    blob = path.read_bytes().replace(b'"name": "lms"', b'"name": "xtr"')
    path.write_bytes(blob)
    _expect_error(path, "unsupported cfa", "xtr")


def test_corrupt_metadata(tmp_path: Path) -> None:
    raw = make_raw(lms_cfa())
    path = tmp_path / "corrupt.dng"
    write_raw(path, raw)
    blob = path.read_bytes().replace(b'"format": "clisp-raw"', b'"format"! "clisp-raw"')
    path.write_bytes(blob)
    _expect_error(path, "metadata")


# ------------------------------------------------------------------------------------------
# raw_info
# ------------------------------------------------------------------------------------------

def test_raw_info_for_our_file(tmp_path: Path) -> None:
    path = tmp_path / "i.dng"
    raw = make_raw(lms_cfa(), shape=(20, 28))
    write_raw(path, raw)
    info = raw_info(path)
    assert info["source_kind"] == "clisp-dng"
    assert (info["width"], info["height"]) == (28, 20)
    assert info["cfa"] == "lms" and info["cfa_kind"] == "lms"
    assert info["black_level"] == [64.0, 65.0, 66.0] and info["white_level"] == 1023.0
    assert info["gain"] == 8
    assert info["model"] == "clisp LMS simulated"
    assert np.allclose(info["colour_matrix"], P_LMS)


# ------------------------------------------------------------------------------------------
# camera helpers (no files needed)
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("top,left", [(0, 0), (1, 0), (0, 1), (1, 1), (26, 152), (7, 49)])
def test_visible_pattern_matches_rawpy_raw_colors_visible(top: int, left: int) -> None:
    raw_pattern = np.array([[0, 1], [3, 2]], dtype=np.uint8)
    full = np.pad(raw_pattern, ((0, 60), (0, 200)), mode="wrap")      # what rawpy's raw_colors does
    assert np.array_equal(visible_pattern(raw_pattern, top, left), full[top:top + 2, left:left + 2])
    four = np.tile(raw_pattern, (2, 2))
    assert visible_pattern(four, top, left).shape == (2, 2)


def test_non_bayer_patterns_are_rejected() -> None:
    with pytest.raises(ClispError, match="no CFA pattern"):
        visible_pattern(None, 0, 0, "linear.dng")
    xtrans = np.array([[1, 1, 0, 1, 1, 2], [1, 1, 2, 1, 1, 0], [2, 0, 1, 0, 2, 1],
                       [1, 1, 2, 1, 1, 0], [1, 1, 0, 1, 1, 2], [0, 2, 1, 2, 0, 1]])
    with pytest.raises(ClispError, match="6x6"):
        cfa_from_pattern(visible_pattern(xtrans, 0, 0), "RGBG")


def test_wb_fallbacks() -> None:
    pattern = np.array([[0, 1], [3, 2]])
    cfa = bayer_cfa()
    wb, src = pick_wb([2.0, 1.0, 1.5, 0.0], pattern, "RGBG", cfa)
    assert src == "camera" and np.allclose(wb, [2.0, 1.0, 1.5])
    wb, src = pick_wb([1.0, 0.5, 0.75, 0.0], pattern, "RGBG", cfa)
    assert src == "camera" and np.allclose(wb, [2.0, 1.0, 1.5])
    for unusable in ([-1.0, 1.03, 2.69, 0.0], [0, 0, 0, 0], None):
        wb, src = pick_wb(unusable, pattern, "RGBG", cfa)
        assert wb is None and src == "none"
    assert np.allclose(channel_values([60, 64, 70, 66], pattern, "RGBG", cfa), [60, 65, 70])


def test_colour_matrix_sources() -> None:
    rgb_cam = np.hstack([B_BAYER, np.zeros((3, 1))])
    m, src = pick_colour_matrix(rgb_cam, np.zeros((4, 3)))
    assert src.startswith("file") and np.array_equal(m, B_BAYER)
    cam_xyz = np.vstack([np.linalg.inv(B_BAYER) @ XYZ_TO_SRGB, np.zeros((1, 3))])
    m, src = pick_colour_matrix(np.zeros((3, 4)), cam_xyz)
    assert src.startswith("derived")
    assert np.allclose(m.sum(axis=1), 1.0)                  # WB-balanced white -> sRGB white
    assert np.allclose(m, rgb_cam_from_cam_xyz(cam_xyz[:3]))
    m, src = pick_colour_matrix(np.zeros((3, 4)), np.zeros((4, 3)))
    assert src == "identity (file has none)" and np.array_equal(m, np.eye(3))


# ------------------------------------------------------------------------------------------
# real camera raws (skipped when ../shared/data/raw is absent)
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name", sorted(CAMERA_FILES))
def test_camera_raws(name: str, tmp_path: Path) -> None:
    path = CAMERA_DIR / name
    if not path.is_file():
        pytest.skip(f"camera raw {path} not available")
    cfa_name, shape, black, white = CAMERA_FILES[name]
    raw = read_raw(path)
    assert raw.cfa.name == cfa_name and raw.cfa.kind == "bayer"
    assert raw.shape == shape and raw.data.dtype == np.uint16
    assert np.array_equal(raw.black_level, [black] * 3) and raw.white_level == white
    assert raw.exposure == 1.0 and raw.source == str(path)
    assert raw.wb[1] == 1.0 and np.all(raw.wb > 0)
    assert raw.colour_matrix.shape == (3, 3)
    assert np.allclose(raw.colour_matrix.sum(axis=1), 1.0, atol=1e-3)
    assert raw.metadata["flip"] == 0
    assert raw.metadata["wb_source"] in ("camera", NO_CAMERA_WB)
    with rawpy.imread(str(path)) as rp:
        assert np.array_equal(raw.data, rp.raw_image_visible)
    if name.endswith(".CRW"):
        assert raw.metadata["wb_source"] == NO_CAMERA_WB            # camera WB has R = -1: reading decides nothing
        assert np.allclose(raw.wb, raw.metadata["daylight_multipliers"])
        run = measure_scene(raw).raw                                   # the run's --wb camera: the scene's grey pixels
        assert run.metadata["wb_source"] == "auto (grey pixels), file has no camera WB"
        assert run.wb[1] == 1.0 and 1.5 < run.wb[0] < 2.1 and not np.allclose(run.wb, raw.wb, rtol=0.05)
        assert raw.metadata["colour_matrix_source"].startswith("derived")
    if name.endswith(".KDC"):
        # LibRaw keeps the DC50's matrix internally; clisp measures it (white-preserving rows).
        assert raw.metadata["colour_matrix_source"].startswith("probed from LibRaw")
    info = raw_info(path)
    assert info["source_kind"] == "camera (rawpy)" and info["cfa"] == cfa_name
    # a camera raw survives our own file format unchanged
    write_raw(tmp_path / "copy.dng", raw)
    back = read_raw(tmp_path / "copy.dng")
    assert_same_raw(raw, back)
