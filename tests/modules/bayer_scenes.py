"""Test scenes and shared checks of the Bayer demosaics' device tests (test_demosaic_ari_cl.py,
test_demosaic_ri.py): small linear RGB scenes with the hard cases, their Bayer mosaics, and the
device-memory check of a stage's declared bytes_per_pixel and the tiling check in a pipeline."""
from __future__ import annotations

import numpy as np
from scipy import ndimage

from clisp.cfa import CFA, bayer_cfa
from clisp.modules.colour.stage import ColourMatrix
from clisp.modules.raw_scale.stage import normalize, white_balance1
from clisp.pipeline import Pipeline
from clisp.sim.colorimetry import B_BAYER, P_LMS, WB_BAYER, WB_LMS


def scene(kind: str, size: int, seed: int = 0) -> np.ndarray:
    """size x size x 3 linear RGB test scenes, nominally [0, 1] with some values outside."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64) / size
    if kind == "ramps":                       # smooth colour ramps, a highlight above 1
        rgb = np.stack([0.1 + 0.8 * xx, 0.2 + 0.6 * yy, 0.9 - 0.7 * (xx + yy) / 2], axis=-1)
        rgb += 0.6 * np.exp(-((xx - 0.5) ** 2 + (yy - 0.5) ** 2) / 0.002)[..., None]
    elif kind == "edges":                     # sharp colour edges at several angles, values below 0
        rgb = np.full((size, size, 3), 0.3)
        rgb[xx + 0.3 * yy > 0.5] = (0.9, 0.5, 0.1)
        rgb[(yy - 0.6 * xx > 0.4)] = (0.05, 0.2, 0.8)
        rgb[np.abs(xx - yy) < 0.02] = (1.1, 1.0, -0.02)
    elif kind == "discs":                     # a small dead-leaves pattern
        rgb = np.full((size, size, 3), 0.5)
        for _ in range(60):
            cy, cx, r = rng.random(), rng.random(), 0.02 + 0.15 * rng.random() ** 2
            rgb[(yy - cy) ** 2 + (xx - cx) ** 2 < r * r] = rng.random(3)
    elif kind == "noise":                     # white noise mosaic, [-0.1, 1.2]
        rgb = rng.uniform(-0.1, 1.2, (size, size, 3))
    elif kind == "clipped":                   # white-balanced lights clipped flat at each channel's white
        rgb = np.stack([0.3 + 0.4 * xx, 0.35 + 0.3 * yy, 0.25 + 0.2 * (xx + yy)], axis=-1) * CLIPPED_WHITE
        for _ in range(4):
            cy, cx, r = rng.uniform(0.2, 0.8), rng.uniform(0.2, 0.8), rng.uniform(0.05, 0.12)
            rgb += 3.0 * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / r ** 2)[..., None] * rng.uniform(0.5, 1, 3)
        return np.minimum(rgb, CLIPPED_WHITE)
    else:
        raise ValueError(kind)
    if kind != "noise":
        rgb += rng.normal(0, 0.005, rgb.shape)
    return rgb


CLIPPED_WHITE = np.array([1.9, 1.0, 1.5])
"""The ``clipped`` scene's white per channel: a raw's white level times white-balance gains (R, G, B)."""


def mosaic(rgb: np.ndarray, phase: str | CFA, origin: tuple[int, int] = (0, 0)) -> np.ndarray:
    """The mosaic of ``rgb`` (channels in the CFA's order) for a Bayer phase name or a CFA."""
    cfa = bayer_cfa(phase) if isinstance(phase, str) else phase
    ch = cfa.channel_map(rgb.shape[0], rgb.shape[1], origin)
    return np.take_along_axis(rgb, ch[..., None].astype(np.intp), axis=-1)[..., 0].astype(np.float32)


def assert_memory_within_declared(rt, stage, shapes: tuple[tuple[int, int], ...]) -> None:
    """bytes_per_pixel covers what one enqueue creates from an empty pool (Runtime.metering), on a
    zero mosaic of every (h, w) of ``shapes``."""
    for h, w in shapes:
        src = rt.upload(np.zeros((h, w), dtype=np.float32))
        with rt.metering() as pool:
            stage.enqueue(rt, src, (0, 0))
        rt.release(src)
        assert pool.created <= stage.bytes_per_pixel * h * w, (h, w, pool.created / (h * w))


def assert_tiled_equals_whole(make_stage, shape: tuple[int, int], cfa: CFA | None = None) -> None:
    """A pipeline (normalise, WB pass 1, ``make_stage(cfa)``, colour matrix) on a smooth noisy uint16
    raw of ``shape``, ``cfa`` GBRG Bayer unless given (an LMS CFA takes the LMS white balance and
    matrix): tiles of 48 and 96 px give exactly the whole image's output."""
    cfa = cfa or bayer_cfa("GBRG")
    wb, matrix = (WB_LMS, P_LMS) if cfa.spectral == "lms" else (WB_BAYER, B_BAYER)
    pipeline = Pipeline(cfa, [normalize(cfa, np.full(3, 64.0), 1023.0), white_balance1(cfa, wb),
                              make_stage(cfa), ColourMatrix(matrix)])
    rng = np.random.default_rng(5)
    sc = ndimage.gaussian_filter(rng.random(shape), 2.0) * 600 + 100
    raw = np.clip(sc + rng.normal(0, 8, sc.shape), 0, 1023).astype(np.uint16)
    whole = pipeline.run(raw, tile=0)
    assert whole.shape == shape + (3,)
    for tile in (48, 96):
        np.testing.assert_array_equal(pipeline.run(raw, tile=tile), whole, err_msg=f"tile {tile}")
