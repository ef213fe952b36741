"""The block blend (clisp.modules.block_blend): its weight rule, kernel and rectangles (issue 30)."""
from __future__ import annotations

import numpy as np
import pytest

from clisp.modules.block_blend.blend import BlockBlend, rectangles


def brute_weight(mask: np.ndarray, block: int, reach: int, ramp: int, h: int, w: int) -> np.ndarray:
    """w(p) by the definition: the Chebyshev distance to every texture block's pixels."""
    yy, xx = np.mgrid[0:h, 0:w]
    d = np.full((h, w), np.inf)
    for by, bx in zip(*np.nonzero(mask)):
        dy = np.maximum(np.maximum(by * block - yy, yy - (by * block + block - 1)), 0)
        dx = np.maximum(np.maximum(bx * block - xx, xx - (bx * block + block - 1)), 0)
        d = np.minimum(d, np.maximum(dy, dx))
    return np.clip((reach + ramp - d) / ramp, 0.0, 1.0)


@pytest.mark.parametrize("reach,ramp", [(32, 32), (52, 32), (10, 8)])
def test_weight_is_the_distance_rule_and_the_support_holds_it(reach: int, ramp: int) -> None:
    rng = np.random.default_rng(reach)
    mask = rng.random((5, 7)) < 0.15
    mask[2, 3] = True
    b = BlockBlend(mask, block=16, reach=reach, ramp=ramp)
    w = b.weight(0, 0, 80, 112)
    np.testing.assert_allclose(w, brute_weight(mask, 16, reach, ramp, 80, 112), atol=1e-12)
    np.testing.assert_allclose(b.weight(20, 36, 30, 40), w[20:50, 36:76], atol=0)
    blocks_with_weight = (w.reshape(5, 16, 7, 16) > 0).any(axis=(1, 3))
    assert not (blocks_with_weight & ~b.support()).any()
    assert (w[mask.repeat(16, 0).repeat(16, 1)] == 1.0).all()


def test_blend_kernel_matches_the_reference() -> None:
    """Odd sizes, so the launch has ragged strips, and a long ramp, so most pixels are mixed: the
    kernel joins in place, each pixel exactly once (a pixel joined twice would show here)."""
    from clisp.engine.runtime import get_runtime
    rt = get_runtime()
    rng = np.random.default_rng(3)
    mask = np.zeros((6, 6), dtype=bool)
    mask[3, 1] = True
    b = BlockBlend(mask, block=16, reach=4, ramp=40)
    flat = rng.random((53, 71, 3)).astype(np.float32)
    detail = rng.random((37, 53, 3)).astype(np.float32)
    weight = b.weight(40, 24, 37, 53)
    assert ((weight > 0) & (weight < 1)).mean() > 0.5
    expected = flat.astype(np.float64)
    b.reference(expected, detail.astype(np.float64), (8, 16), (40, 24))   # the tile sits at image (32, 8)
    f = rt.upload(np.ascontiguousarray(flat.transpose(2, 0, 1)))
    d = rt.upload(np.ascontiguousarray(detail.transpose(2, 0, 1)))
    b.enqueue(rt, f, d, (8, 16), (40, 24))
    got = rt.download(f).reshape(3, 53, 71).transpose(1, 2, 0)
    np.testing.assert_allclose(got, expected, atol=1e-6, rtol=0)
    assert not np.allclose(got, flat), "the rectangle holds blended pixels"


def test_rectangles_cover_the_support_inside_the_tile() -> None:
    rng = np.random.default_rng(0)
    for trial in range(20):
        support = rng.random((9, 12)) < rng.uniform(0.02, 0.3)
        tile = (int(rng.integers(0, 4)) * 16, int(rng.integers(0, 4)) * 16, 96, 128)
        rects = rectangles(support, int(rng.integers(0, 40)), 16, tile, (144, 192))
        covered = np.zeros((144, 192), dtype=bool)
        for y0, x0, h, w in rects:
            assert tile[0] <= y0 and y0 + h <= tile[0] + tile[2] and tile[1] <= x0 and x0 + w <= tile[1] + tile[3]
            assert not covered[y0:y0 + h, x0:x0 + w].any(), "rectangles overlap"
            covered[y0:y0 + h, x0:x0 + w] = True
        need = support.repeat(16, 0).repeat(16, 1)
        inside = np.zeros_like(need)
        inside[tile[0]:tile[0] + tile[2], tile[1]:tile[1] + tile[3]] = True
        assert not (need & inside & ~covered).any(), trial
