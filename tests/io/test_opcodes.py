"""DNG opcode lists (clisp.io.opcodes): a GainMap written by hand from the DNG specification's layout
(not by our writer) read from a camera-style DNG through rawpy, its coordinates through the
ActiveArea; our writer's round trip; opcodes clisp does not apply, named."""
from __future__ import annotations

import struct

import numpy as np
import pytest
import tifffile

from clisp.errors import ClispError
from clisp.io import opcodes as oc
from clisp.io.rawfile import TAG_DNG_PRIVATE_DATA, dng_tags, read_raw, write_raw
from clisp.modules.sensor.stage import GainTerms, SensorCorrect
from clisp.sim.defects import SensorDefects, bad_pixel_list_opcode, gain_map_opcodes
from clisp.sim.simulate import simulate
from tolerance import assert_close

H, W = 48, 64
MARGIN = (4, 8)            # the stored raw's rows and columns above and left of the ActiveArea


def spec_gain_map(top, left, bottom, right, pitch, points_v, points_h, spacing, origin, gains) -> bytes:
    """A GainMap opcode's bytes as the DNG 1.4 specification lays them out (section 6: big-endian
    LONG Top, Left, Bottom, Right, Plane, Planes, RowPitch, ColPitch, MapPointsV, MapPointsH; DOUBLE
    MapSpacingV, MapSpacingH, MapOriginV, MapOriginH; LONG MapPlanes; FLOAT gains, rows of columns of
    planes), behind the opcode header (LONG id 9, 4-byte DNG version, LONG flags, LONG size)."""
    params = struct.pack(">10L", top, left, bottom, right, 0, 1, pitch, pitch, points_v, points_h)
    params += struct.pack(">4d", spacing[0], spacing[1], origin[0], origin[1]) + struct.pack(">L", 1)
    params += struct.pack(f">{len(gains)}f", *gains)
    return struct.pack(">L", 9) + bytes((1, 3, 0, 0)) + struct.pack(">LL", 0, len(params)) + params


def camera_dng(path, raw, opcode_lists: dict[int, bytes]) -> None:
    """``raw``'s mosaic as a camera would store it: not ours (no clisp metadata), inside an
    ActiveArea with MARGIN rows and columns of black around it, with the given OpcodeList tags."""
    tags = [t for t in dng_tags(raw) if t[0] != TAG_DNG_PRIVATE_DATA]
    full = np.full((H + 2 * MARGIN[0], W + 2 * MARGIN[1]), 64, np.uint16)
    full[MARGIN[0]:MARGIN[0] + H, MARGIN[1]:MARGIN[1] + W] = raw.data
    tags.append((50829, 4, 4, (MARGIN[0], MARGIN[1], MARGIN[0] + H, MARGIN[1] + W), True))   # ActiveArea
    for list_no, blob in opcode_lists.items():
        tags.append((oc.TAG_OPCODE_LIST[list_no], 7, len(blob), blob, True))
    tifffile.imwrite(path, full, extratags=tags, photometric=32803, subfiletype=0, compression=None,
                     metadata=None, software="test")


def spec_gain(y: np.ndarray, x: np.ndarray, gains: np.ndarray, spacing, origin, shape) -> np.ndarray:
    """The specification's interpolation, written out here: relative pixel centres, the map index
    clamped to the map, bilinear."""
    v = ((y + 0.5) / shape[0] - origin[0]) / spacing[0]
    h = ((x + 0.5) / shape[1] - origin[1]) / spacing[1]
    pv, ph = gains.shape
    v, h = np.clip(v, 0, pv - 1), np.clip(h, 0, ph - 1)
    i0 = np.minimum(np.floor(v).astype(int), pv - 2)
    j0 = np.minimum(np.floor(h).astype(int), ph - 2)
    fv, fh = v - i0, h - j0
    return ((gains[i0, j0] * (1 - fh) + gains[i0, j0 + 1] * fh) * (1 - fv)
            + (gains[i0 + 1, j0] * (1 - fh) + gains[i0 + 1, j0 + 1] * fh) * fv)


def test_hand_made_gain_map_in_a_camera_dng(tmp_path):
    raw = simulate(np.full((H, W, 3), 0.3), cfa="bayer", gain=1, optics="none", seed=3).raw
    gains = np.array([[1.0, 1.5, 2.0], [1.25, 1.75, 3.0]])
    blob = struct.pack(">L", 1) + spec_gain_map(0, 0, H, W, 1, 2, 3, (1.0, 0.5), (0.0, 0.0), gains.ravel())
    bad = struct.pack(">L", 1) + struct.pack(">L", 5) + bytes((1, 3, 0, 0)) + struct.pack(">LL", 0, 20) \
        + struct.pack(">LLLll", 0, 1, 0, MARGIN[0] + 10, MARGIN[1] + 12)     # FixBadPixelsList: one point
    path = tmp_path / "camera.dng"
    camera_dng(path, raw, {1: bad, 2: blob})
    read = read_raw(path)
    assert read.source == str(path) and "clisp" not in read.metadata.get("format", "")
    ops = read.metadata["opcodes"]
    gm = next(op for op in ops if isinstance(op, oc.GainMap))
    assert (gm.list_no, gm.area, gm.spacing, gm.origin_rel, gm.image) == (2, (0, 0, H, W), (1.0, 0.5), (0.0, 0.0), (H, W))
    np.testing.assert_array_equal(gm.gains[..., 0], gains.astype(np.float32))
    fix = next(op for op in ops if isinstance(op, oc.FixBadPixelsList))
    mask = oc.bad_pixel_mask([fix], read.data, read.shape)           # list 1: stored-raw coordinates
    assert np.argwhere(mask).tolist() == [[10, 12]]
    y, x = np.mgrid[0:H, 0:W]
    expected = spec_gain(y, x, gains, (1.0, 0.5), (0.0, 0.0), (H, W))
    assert_close(oc.gain_map_at(gm, y, x), expected, "GainMap interpolation")
    stage = SensorCorrect(read.cfa, read.black_level, read.white_level, terms=GainTerms([gm]))
    from clisp.engine.stage import Origin
    from clisp.engine.tiling import gather_window
    from clisp.modules.sensor.stage import HALO
    window = gather_window(read.data, -HALO, -HALO, H + 2 * HALO, W + 2 * HALO, 2)
    black = read.black_level[read.cfa.channel_map(H, W)]
    corrected = black + (read.data - black) * expected
    assert_close(stage.reference(window, Origin(-HALO, -HALO, (H, W))), corrected, "GainMap on the mosaic, reference")
    from clisp.engine.runtime import get_runtime
    rt = get_runtime()
    out = rt.download(stage.enqueue(rt, rt.upload(window), Origin(-HALO, -HALO, (H, W)))).reshape(H, W)
    assert_close(out, corrected, "GainMap on the mosaic, sensor.cl")


def test_writer_round_trip(tmp_path):
    d = SensorDefects(hot=0.002, dead=0.001, shading=0.6, seed=5)
    sim = simulate(np.full((H, W, 3), 0.3), cfa="lms", gain=2, defects=d)
    ops = gain_map_opcodes(d, sim.raw.cfa, sim.raw.shape) + [bad_pixel_list_opcode(d, sim.raw.shape)]
    ops.append(oc.OtherOpcode(8, bytes(range(20)), list_no=3))                # MapPolynomial: kept, not applied
    sim.raw.metadata["opcodes"] = ops
    write_raw(tmp_path / "r.dng", sim.raw)
    back = read_raw(tmp_path / "r.dng")
    got = back.metadata["opcodes"]
    ops = sorted(ops, key=lambda o: o.list_no)                                # the tags come list by list
    assert [(o.name, o.list_no) for o in got] == [(o.name, o.list_no) for o in ops]
    for a, b in zip(ops, got):
        assert oc.encode_opcode_list([a]) == oc.encode_opcode_list([b])
    assert oc.unapplied(got) == ["MapPolynomial (OpcodeList3)"]
    with tifffile.TiffFile(tmp_path / "r.dng") as tif:                       # tags, not our JSON
        assert {51008, 51009, 51022} <= set(tif.pages[0].tags.keys())
        assert b"opcodes" not in bytes(tif.pages[0].tags[TAG_DNG_PRIVATE_DATA].value)


def test_corrupt_list_is_one_line():
    blob = struct.pack(">L", 1) + spec_gain_map(0, 0, 4, 4, 1, 2, 2, (1.0, 1.0), (0.0, 0.0), [1.0] * 4)
    with pytest.raises(ClispError, match=r"x.dng: corrupt DNG OpcodeList2 \(GainMap needs \d+ bytes\)"):
        oc.parse_opcode_list(blob[:-3], 2, "x.dng")
    bad = bytearray(blob)
    bad[4 + 16 + 40:4 + 16 + 48] = struct.pack(">d", 0.0)                   # count, header, MapSpacingV 0
    with pytest.raises(ClispError, match="map spacing"):
        oc.parse_opcode_list(bytes(bad), 2, "x.dng")


def test_vignette_radial_as_the_sdk():
    op = oc.FixVignetteRadial((0.5, 0.25, 0.0, 0.0, 0.0), (0.5, 0.5), list_no=3, image=(H, W))
    y, x = np.mgrid[0:H, 0:W]
    r2 = ((y + 0.5 - H / 2) ** 2 + (x + 0.5 - W / 2) ** 2) / ((H / 2) ** 2 + (W / 2) ** 2)
    assert_close(oc.vignette_at(op, y, x), 1 + 0.5 * r2 + 0.25 * r2 ** 2, "FixVignetteRadial")
