"""Tile planning, CFA-preserving padding, and tiled == whole-image output.

Tolerance for every comparison of two pipeline outputs (the same rule as test_kernels.py):

    |a - b| <= TOL * max(1, |b|)
"""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clisp.cfa import cfa_from_name
from clisp.sim.colorimetry import B_BAYER, P_LMS, WB_BAYER, WB_LMS
from clisp.pipeline import build_pipeline
from clisp.io.rawimage import RawImage
from clisp.engine.tiling import Tile, cfa_mirror_index, gather, gather_window, plan_tiles
from tolerance import TOL, assert_close

"""|a - b| <= TOL * max(1, |b|) for every output comparison in this file."""

IMAGE_SHAPE = (301, 517)              # not a multiple of any tile size or CFA period




# ------------------------------------------------------------------------------------------
# plan_tiles
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("height, width, tile, align", [
    (301, 517, 64, 4), (301, 517, 256, 4), (301, 517, 64, 2), (301, 517, 63, 4), (301, 517, 63, 2),
    (37, 53, 8, 4), (37, 53, 5, 2), (8, 8, 4, 4), (17, 9, 16, 4), (9, 17, 16, 2), (100, 100, 3, 4),
    (64, 128, 64, 4), (128, 64, 64, 2),
])
def test_plan_tiles_covers_once_and_aligned(height, width, tile, align):
    tiles = plan_tiles(height, width, tile, align=align)
    count = np.zeros((height, width), dtype=np.int32)
    for t in tiles:
        assert isinstance(t, Tile)
        assert t.h > 0 and t.w > 0
        assert 0 <= t.y0 and t.y0 + t.h <= height and 0 <= t.x0 and t.x0 + t.w <= width
        assert t.y0 % align == 0 and t.x0 % align == 0, "tiles must start on the same CFA phase"
        count[t.y0:t.y0 + t.h, t.x0:t.x0 + t.w] += 1
    assert np.all(count == 1), "every pixel exactly once"
    step = max(align, tile // align * align)
    assert all(t.h <= step and t.w <= step for t in tiles)
    assert len(tiles) == -(-height // step) * -(-width // step)


@pytest.mark.parametrize("tile", [None, 0, 517, 600])
def test_plan_tiles_single_tile(tile):
    assert plan_tiles(301, 517, tile, align=4) == [Tile(0, 0, 301, 517)]


# ------------------------------------------------------------------------------------------
# cfa_mirror_index
# ------------------------------------------------------------------------------------------

def plain_mirror(idx: np.ndarray, n: int) -> np.ndarray:
    """Whole-sample symmetric reflection (-1 -> 1, n -> n - 2), repeated: via numpy's 'reflect' pad."""
    pad = int(np.max(np.abs(idx))) + n
    padded = np.pad(np.arange(n), pad, mode="reflect")
    return padded[idx + pad]


@pytest.mark.parametrize("period", [2, 4])
def test_cfa_mirror_index_properties(period):
    checked = 0
    for n in range(period, 70):
        idx = np.arange(-3 * n - 9, 4 * n + 9)
        out = cfa_mirror_index(idx, n, period)
        assert out.shape == idx.shape and out.dtype.kind == "i"
        assert out.min() >= 0 and out.max() < n, f"out of range for n={n}"
        inside = (idx >= 0) & (idx < n)
        np.testing.assert_array_equal(out[inside], idx[inside], err_msg=f"identity inside, n={n}")
        np.testing.assert_array_equal(out % period, idx % period, err_msg=f"phase lost, n={n}")
        # the nearest in-range index of the right phase to the plain mirror position
        mirrored = plain_mirror(idx, n)
        candidates = np.arange(n)
        for i, m in zip(idx, mirrored):
            same_phase = candidates[candidates % period == i % period]
            best = np.min(np.abs(same_phase - m))
            assert abs(int(cfa_mirror_index(np.array([i]), n, period)[0]) - m) == best, (n, i)
        checked += 1
    assert checked == 70 - period


def test_cfa_mirror_index_examples():
    # n = 10, period 2: the plain mirror already keeps the phase for even offsets (-2 -> 2)
    np.testing.assert_array_equal(cfa_mirror_index(np.array([-2, -1, 10, 11]), 10, 2), [2, 1, 8, 7])
    # period 4: -1 (phase 3) cannot map to 1 (phase 1): nearest phase-3 index to 1 is 3
    assert cfa_mirror_index(np.array([-1]), 10, 4)[0] == 3
    np.testing.assert_array_equal(cfa_mirror_index(np.arange(10), 10, 4), np.arange(10))


def test_cfa_mirror_index_rejects_small_images():
    with pytest.raises(ValueError, match="smaller than the CFA period"):
        cfa_mirror_index(np.arange(-2, 5), 3, 4)


# ------------------------------------------------------------------------------------------
# gather_window
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("dtype", [np.uint16, np.float32])
@pytest.mark.parametrize("period", [2, 4])
def test_gather_window_equals_fancy_indexing(dtype, period):
    rng = np.random.default_rng(period)
    data = (rng.random((23, 31)) * 1000).astype(dtype)
    windows = [(0, 0, 23, 31), (-5, -7, 33, 45), (-2, 3, 8, 9), (20, 28, 10, 12), (-40, -50, 100, 120),
               (5, 6, 1, 1), (22, -3, 4, 40), (-9, 30, 13, 2)]
    for y0, x0, h, w in windows:
        window = gather_window(data, y0, x0, h, w, period)
        rows = cfa_mirror_index(np.arange(y0, y0 + h), data.shape[0], period)
        cols = cfa_mirror_index(np.arange(x0, x0 + w), data.shape[1], period)
        expected = data[np.ix_(rows, cols)]
        assert window.dtype == data.dtype and window.shape == (h, w) and window.flags.c_contiguous
        np.testing.assert_array_equal(window, expected, err_msg=str((y0, x0, h, w)))


@settings(max_examples=300, deadline=None)
@given(period=st.sampled_from([1, 2, 3, 4, 6]), height=st.integers(6, 30), width=st.integers(6, 30),
       y0=st.integers(-40, 35), x0=st.integers(-40, 35), h=st.integers(1, 90), w=st.integers(1, 90))
def test_gather_copies_every_window_as_fancy_indexing_does(period, height, width, y0, x0, h, w):
    """The interior, the border slices per mirror phase and the rows copied from the window itself
    (tiling.WindowLayout) give data[rows][:, cols] for any window, far past the image included."""
    data = np.arange(height * width, dtype=np.uint16).reshape(height, width)
    rows = cfa_mirror_index(np.arange(y0, y0 + h), height, period)
    cols = cfa_mirror_index(np.arange(x0, x0 + w), width, period)
    expected = data[np.ix_(rows, cols)]
    np.testing.assert_array_equal(gather_window(data, y0, x0, h, w, period), expected)
    np.testing.assert_array_equal(gather(data, rows, cols, period=period), expected)


def test_gather_window_preserves_cfa():
    """Every padded pixel has the CFA channel of the position it stands for."""
    for name in ("lms", "lms@1,2", "bayer-gbrg"):
        cfa = cfa_from_name(name)
        ch = cfa.channel_map(21, 26).astype(np.float32)
        origin = (-7, -9)
        window = gather_window(ch, origin[0], origin[1], 40, 45, cfa.period)
        np.testing.assert_array_equal(window, cfa.channel_map(40, 45, origin))


# ------------------------------------------------------------------------------------------
# tiled == untiled, through the whole pipeline
# ------------------------------------------------------------------------------------------

def make_raw(kind: str, dtype) -> RawImage:
    """Random raw in DN with realistic metadata (wb2 on for float32 data, identity for uint16)."""
    cfa = cfa_from_name(kind)
    matrix, wb = (P_LMS, WB_LMS) if cfa.kind == "lms" else (B_BAYER, WB_BAYER)
    rng = np.random.default_rng(11 if kind == "lms" else 12)
    if dtype == np.uint16:
        data = rng.integers(0, 1024, size=IMAGE_SHAPE, dtype=np.uint16)
        wb2 = np.ones(3)
    else:
        data = (rng.random(IMAGE_SHAPE) * 1100.0 - 30.0).astype(np.float32)
        wb2 = np.array([1.0, 1.0101, 1.0753])
    return RawImage(data=data, cfa=cfa, black_level=np.array([64.0, 65.0, 66.0]), white_level=1023.0,
                    wb=wb, colour_matrix=matrix, exposure=1.0 / 0.98951, wb2=wb2)


_UNTILED: dict = {}


def untiled(kind: str, dtype, output: str, backend: str) -> np.ndarray:
    """Whole-image output, computed once per configuration for the module."""
    key = (kind, dtype, output, backend)
    if key not in _UNTILED:
        raw = make_raw(kind, dtype)
        pipeline = build_pipeline(raw, demosaic="bilinear", output=output, denoise=False, bad_pixels="off")
        _UNTILED[key] = pipeline.run(raw.data, tile=None, backend=backend)
        assert pipeline.stats.tiles == 1
    return _UNTILED[key]


CASES = [(kind, dtype, output) for kind in ("lms", "bayer") for dtype in (np.uint16, np.float32)
         for output in ("linear", "srgb")]


@pytest.mark.parametrize("tile", [64, 256])
@pytest.mark.parametrize("backend", ["opencl", "reference"])
@pytest.mark.parametrize("kind, dtype, output", CASES,
                         ids=[f"{k}-{d.__name__}-{o}" for k, d, o in CASES])
def test_tiled_equals_untiled(kind, dtype, output, backend, tile):
    raw = make_raw(kind, dtype)
    # bad_pixels off: on uniform noise the search replaces about 7 % of the pixels, each along the
    # same-channel pair that differs least, and pairs that tie on integer data can be chosen
    # differently in float32 and float64 (1e-5 off the reference); the sensor stage's own tests
    # (tests/modules/test_sensor.py) cover its tiling on raws with sparse defects
    pipeline = build_pipeline(raw, demosaic="bilinear", output=output, denoise=False, bad_pixels="off")
    tiled = pipeline.run(raw.data, tile=tile, backend=backend)
    assert tiled.shape == IMAGE_SHAPE + (3,) and tiled.dtype == np.float32
    step = tile // raw.cfa.period * raw.cfa.period
    assert pipeline.stats.tiles == -(-IMAGE_SHAPE[0] // step) * -(-IMAGE_SHAPE[1] // step) > 1
    assert_close(tiled, untiled(kind, dtype, output, backend), f"tiled {backend} vs untiled {backend}")
    if backend == "opencl":
        assert_close(tiled, untiled(kind, dtype, output, "reference"), "tiled opencl vs untiled reference")


@pytest.mark.parametrize("kind", ["lms", "bayer"])
def test_untiled_opencl_matches_reference(kind):
    for dtype in (np.uint16, np.float32):
        for output in ("linear", "srgb"):
            assert_close(untiled(kind, dtype, output, "opencl"), untiled(kind, dtype, output, "reference"),
                         f"untiled {kind} {dtype.__name__} {output}")


def test_unaligned_tile_size_reference():
    """A tile size that is not a multiple of the CFA period is rounded down, output unchanged."""
    raw = make_raw("lms", np.float32)
    pipeline = build_pipeline(raw, demosaic="bilinear", output="linear", denoise=False, bad_pixels="off")
    tiled = pipeline.run(raw.data, tile=70, backend="reference")       # step 68
    assert pipeline.stats.tiles == -(-301 // 68) * -(-517 // 68)
    assert_close(tiled, untiled("lms", np.float32, "linear", "reference"), "tile 70")
