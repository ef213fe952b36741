"""The flat-tile demosaic (clisp.modules.demosaic_flat.stage): kernel against reference, what it must
reproduce exactly, and tiled-equals-whole.

Tolerance: tolerance.TOL (|opencl - reference| <= 1e-5 max(1, |reference|)), inputs white ~ 1.
"""
from __future__ import annotations

import numpy as np
import pytest

from clisp.cfa import cfa_from_name
from clisp.pipeline import Pipeline
from clisp.engine.stage import Origin
from clisp.modules.demosaic_flat.stage import CELL_PX, DemosaicFlat, detail_channels
from test_kernels import run_stage
from tolerance import assert_close

ORIGINS = [(0, 0), (3, -2), (-7, 5)]


def mosaic(shape: tuple[int, int], seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return (0.3 + 0.05 * rng.standard_normal(shape)).astype(np.float32)


@pytest.mark.parametrize("name", ["lms", "lms@1,2", "bayer-rggb", "bayer-gbrg", "lms-bayer", "LM/SL"])
@pytest.mark.parametrize("cells", [1, 6])
@pytest.mark.parametrize("edges", [False, True])
def test_kernel_matches_reference(rt, name: str, cells: int, edges: bool) -> None:
    stage = DemosaicFlat(cfa_from_name(name), cells)
    x = mosaic((2 * stage.halo + 21, 2 * stage.halo + 37), seed=cells)
    for origin in ORIGINS:
        if edges:        # an image that ends inside the window on every side
            origin = Origin(*origin, image=(x.shape[0] + origin[0] - 9, x.shape[1] + origin[1] - 6))
        assert_close(run_stage(rt, stage, x, origin), stage.reference(x, origin), f"{name} cells {cells} {origin}")


def test_gradient_is_continued_past_the_image_edges(rt) -> None:
    """With the image's shape, a coloured gradient stays exact up to the image's edges, where the
    tiler's mirror padding alone would bias the wide means (R / 2 px times the gradient: a colour
    shift, since the residual cancels it only where every channel has the same gradient)."""
    from clisp.engine.tiling import gather_window
    cfa = cfa_from_name("bayer-rggb")
    yy, xx = np.mgrid[0:96, 0:80]
    slope = np.array([0.004, 0.002, 0.001])
    ramps = 0.1 + slope[:, None, None] * yy + 0.5 * slope[:, None, None] * xx     # (3, H, W)
    mosaic_ = np.take_along_axis(ramps, cfa.channel_map(96, 80)[None].astype(np.intp), 0)[0]
    stage = DemosaicFlat(cfa)
    h = stage.halo
    padded = gather_window(mosaic_.astype(np.float32), -h, -h, 96 + 2 * h, 80 + 2 * h, cfa.period)
    origin = Origin(-h, -h, image=mosaic_.shape)
    out = stage.reference(padded, origin)
    exact = np.moveaxis(ramps, 0, -1)
    np.testing.assert_allclose(out[1:-1, 1:-1], exact[1:-1, 1:-1], atol=1e-6)
    # the outermost pixels' 3 x 3 residual reads mirrored samples: at most half a pixel's step
    assert np.abs(out - exact).max() <= 0.5 * 0.004 + 1e-6
    assert_close(run_stage(rt, stage, padded, origin), out, "kernel at the edges")
    biased = stage.reference(padded, (-h, -h))           # a bare origin: no image edges
    assert np.abs(biased - exact).max() > 0.01


@pytest.mark.parametrize("name", ["lms", "bayer-rggb", "lms-bayer-grbg", "LM/SL"])
def test_constant_colour_is_reproduced(name: str) -> None:
    """A field of one colour (each channel constant) comes out as that colour exactly."""
    cfa = cfa_from_name(name)
    stage = DemosaicFlat(cfa)
    colour = np.array([0.2, 0.5, 0.9])
    x = colour[cfa.channel_map(2 * stage.halo + 9, 2 * stage.halo + 11, (1, 2))]
    out = stage.reference(x, (1, 2))
    np.testing.assert_allclose(out, np.broadcast_to(colour, out.shape), atol=1e-12)


def test_gradient_is_reproduced() -> None:
    """Means on cells and bilinear interpolation are exact on a linear gradient (Bayer; LMS's
    residual has no S taps, an error of at most 0.2 px times the gradient)."""
    for name, tol in (("bayer-rggb", 1e-12), ("lms", 0.2 * 0.003)):
        stage = DemosaicFlat(cfa_from_name(name))
        yy, xx = np.mgrid[0:2 * stage.halo + 8, 0:2 * stage.halo + 12]
        ramp = 0.1 + 0.002 * yy + 0.001 * xx
        out = stage.reference(ramp, (0, 4))
        h = stage.halo
        np.testing.assert_allclose(out, np.broadcast_to(ramp[h:-h, h:-h, None], out.shape), atol=tol)


def test_fine_luminance_kept_chroma_averaged() -> None:
    """Noise on the luminance channels stays (the residual keeps fine texture: no plastic look);
    the chroma (channel differences) is a wide mean: far less noisy than the samples."""
    cfa = cfa_from_name("lms")
    stage = DemosaicFlat(cfa)
    x = mosaic((2 * stage.halo + 64, 2 * stage.halo + 64), seed=3).astype(np.float64)
    out = stage.reference(x, (0, 0))
    lum = out[..., :2].mean(-1)
    assert 0.15 < lum.std() / 0.05 < 0.8                      # fine texture kept, a little smoothed
    assert (out[..., 0] - out[..., 1]).std() < 0.05 * 0.05    # chroma: mean of ~600 samples
    assert detail_channels(cfa).tolist() == [1, 1, 0]


@pytest.mark.parametrize("tile", [64, 96])
def test_tiled_equals_whole(rt, tile: int) -> None:
    """With the image's edges (the planner's Origin), on tiles whose windows hold at least
    min_inside_px of image where they meet an edge."""
    cfa = cfa_from_name("lms")
    pipeline = Pipeline(cfa, [DemosaicFlat(cfa)])
    x = mosaic((120, 152), seed=5)
    whole = pipeline.run(x, tile=0)
    tiled = pipeline.run(x, tile=tile)
    assert_close(tiled, whole, f"tile {tile} vs whole")


def test_narrow_edge_window_reads_only_its_cells(rt) -> None:
    """A window that holds less image than min_inside_px at an edge (a last tile keeping 8 px):
    the reflections are clamped to the window's cells inside the image, identically in the kernel
    and the reference (no index past the grid), and the skip planner sends no such tile to the
    flat path."""
    from clisp.engine.tiling import Tile
    from clisp.pipeline.skip import PATH_FLAT, Skipper
    cfa = cfa_from_name("lms")
    stage = DemosaicFlat(cfa)
    x = mosaic((2 * stage.halo + 48, 2 * stage.halo + 48), seed=7)
    origin = Origin(144 - stage.halo, 144 - stage.halo, image=(152, 152))     # 8 px inside at the far edge
    assert 152 - origin[1] < stage.min_inside_px
    assert_close(run_stage(rt, stage, x, origin), stage.reference(x, origin), "narrow edge window")
    skipper = Skipper(None, [stage], {PATH_FLAT: [stage]}, image=(152, 152))
    assert not skipper.flat_window_fits(Tile(144, 144, 8, 8), 48, 48)
    assert skipper.flat_window_fits(Tile(96, 96, 48, 48), 48, 48)


def test_cell_fits_every_cfa() -> None:
    for name in ("lms", "bayer-rggb"):
        assert CELL_PX % cfa_from_name(name).period == 0


@pytest.mark.parametrize("name", ["lms", "bayer-rggb"])
def test_unread_blocks_are_zero_and_the_rest_unchanged(rt, name: str) -> None:
    """A mixed tile's texture blocks (``unread``) are written 0, not computed; every other pixel is
    what the stage without the mask gives, on the device and in the reference."""
    plain = DemosaicFlat(cfa_from_name(name), 2)
    unread = np.zeros((4, 5), dtype=bool)
    unread[1, 2] = unread[3, 0] = True
    masked = DemosaicFlat(cfa_from_name(name), 2, unread=unread, block=16)
    x = mosaic((2 * plain.halo + 40, 2 * plain.halo + 60), seed=5)
    origin = Origin(-plain.halo + 4, -plain.halo + 8)              # output pixel (0, 0) is image (4, 8)
    zero = masked.unread_pixels(4, 8, 40, 60)
    assert zero.sum() == 16 * 16 and zero[12:28, 24:40].all()     # block (1, 2); (3, 0) lies below the window
    expected = plain.reference(x, origin)
    expected[zero] = 0.0
    for got in (masked.reference(x, origin), run_stage(rt, masked, x, origin)):
        assert_close(got, expected, f"{name} masked")
        assert (got[zero] == 0).all() and (got[~zero] != 0).all()
