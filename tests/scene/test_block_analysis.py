"""clisp.scene.block_analysis.analyse against a plain per-block reference written from the definitions.

The analysis is vectorised (bands of block rows, Laplacians of integer cell sums, the noise strips'
kernels as scaled products); the reference here loops over blocks, cells and CFA phases in float64,
so a slip in the vectorisation (an off-by-one at a block edge, a phase mapped to the wrong
channel, a partial last block) shows as a difference.
"""
from __future__ import annotations

import dataclasses
import subprocess
import sys

import numpy as np
import pytest

from clisp.scene import noise as noise_estimate
from clisp.scene.block_analysis import BLOCK, CELL, FLAT_FRACTION, LAPLACIAN_NOISE_GAIN, NOISE_STRIPS, analyse
from clisp.io.rawimage import RawImage
from clisp.modules.chroma_denoise.stage import space_for
from clisp.scene.noise import CLIP_FRACTION, IMMERKAER, MAD_TO_STD, SOBEL, fit_affine_variance
from clisp.sim.simulate import simulate


def scene(h: int, w: int) -> np.ndarray:
    """A gradient, a clipped patch covering whole blocks (uniform there) and a textured patch."""
    yy, xx = np.mgrid[0:h, 0:w] / float(max(h, w))
    img = np.stack([0.1 + 0.5 * xx, 0.15 + 0.4 * yy, 0.3 + 0.2 * xx * yy], -1)
    img[0:70, 56:140] = 4.0
    img[140:190, 200:300] = np.random.default_rng(0).random((50, 100, 3))
    return img


def small_raw(cfa: str, gain: float) -> RawImage:
    """264 x 325 px: a partial last block row (8 px) and column (5 px), width not a multiple of
    the CFA period; block (1, 2) at the white level (uniform, beside blocks that are not), blocks
    (2, 4) and (3, 0) constant along rows and along columns only, and some samples just at and below
    the clip threshold."""
    raw = simulate(scene(272, 336), cfa=cfa, gain=gain, seed=4).raw
    data = np.array(raw.data[:264, :325])
    threshold = float(raw.black_level[0]) + CLIP_FRACTION * (float(raw.white_level) - float(raw.black_level[0]))
    data[64:128, 128:192] = raw.white_level
    data[128:192, 256:320] = 300 + np.arange(64)[:, None]
    data[192:256, 0:64] = 300 + np.arange(64)[None, :]
    data[230:240, 70:320:3] = np.ceil(threshold)
    data[240:250, 70:320:3] = np.floor(threshold)
    return dataclasses.replace(raw, data=data)


def _row3(lat: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """The 3 x 3 correlation of a 3-row strip, tap by tap: one row of width W - 2."""
    n = lat.shape[1] - 2
    out = np.zeros(n)
    for dy in range(3):
        for dx in range(3):
            if kernel[dy, dx] != 0:
                out += kernel[dy, dx] * lat[dy, dx:dx + n]
    return out


def reference(raw: RawImage, block: int = BLOCK) -> dict[str, np.ndarray]:
    """The analysis, block by block. Weights and scales are rounded to float32 as the analysis
    rounds them; the Laplacian centred on cell column j counts in the block of column j - 1 (the
    analysis's block edges laid on the Laplacian's own columns)."""
    cfa, data = raw.cfa, np.asarray(raw.data, dtype=np.float64)
    p, pat, nch = cfa.period, cfa.pattern, cfa.n_channels
    h, w = data.shape
    black, white, gains = np.asarray(raw.black_level, dtype=np.float64), float(raw.white_level), raw.pass1_gains()
    scale = gains / (white - black)
    chan = pat[np.arange(h)[:, None] % p, np.arange(w)[None, :] % p]
    clip_dn = (black + CLIP_FRACTION * (white - black))[chan]
    space = space_for(cfa.spectral, raw.colour_matrix)
    f32 = lambda a: np.asarray(a, dtype=np.float32).astype(np.float64)   # noqa: E731
    luma_w, chroma_w, black32, scale32 = f32(space.luma), f32(space.chroma), f32(black), f32(scale)
    rows, cols, cb, wc = -(-h // block), -(-w // block), block // CELL, w // CELL
    counts = np.array([np.count_nonzero(pat == c) for c in range(nch)]) * (CELL // p) ** 2
    out = {k: np.zeros((rows, cols)) for k in ("clipped", "lap_y")}
    out["uniform"] = np.zeros((rows, cols), dtype=bool)
    out["means"] = np.zeros((nch, rows, cols))
    out["lap_c"] = np.zeros((len(chroma_w), rows, cols))
    for r in range(rows):
        y0, y1 = r * block, min(h, (r + 1) * block)
        hc = (y1 - y0) // CELL
        cells = np.zeros((nch, hc, wc))                             # WB'd cell means
        for i in range(hc):
            for j in range(wc):
                ys, xs = slice(y0 + i * CELL, y0 + (i + 1) * CELL), slice(j * CELL, (j + 1) * CELL)
                for c in range(nch):
                    mean_dn = data[ys, xs][chan[ys, xs] == c].mean()
                    cells[c, i, j] = (mean_dn - black32[c]) * scale32[c]
        planes = np.concatenate([np.tensordot(luma_w, cells, axes=1)[None], np.tensordot(chroma_w, cells, axes=1)])
        for k in range(cols):
            x0, x1 = k * block, min(w, (k + 1) * block)
            blk = data[y0:y1, x0:x1]
            out["clipped"][r, k] = np.mean(blk >= clip_dn[y0:y1, x0:x1])
            out["uniform"][r, k] = all(np.all(blk[py::p, px::p] == blk[py, px])
                                       for py in range(min(p, y1 - y0)) for px in range(min(p, x1 - x0)))
            in_block = cells[:, :, k * cb:min((k + 1) * cb, wc)]
            if in_block.size:
                out["means"][:, r, k] = in_block.mean(axis=(1, 2))
            energy = np.zeros(len(planes))
            centres = [(i, j) for i in range(1, hc - 1) for j in range(k * cb + 1, min((k + 1) * cb, wc - 2) + 1)]
            for i, j in centres:
                lap = (planes[:, i - 1, j] + planes[:, i + 1, j] + planes[:, i, j - 1] + planes[:, i, j + 1]
                       - 4 * planes[:, i, j])
                energy += lap ** 2
            if centres:
                out["lap_y"][r, k], out["lap_c"][:, r, k] = energy[0] / len(centres), energy[1:] / len(centres)
    # noise: residuals on the first 3 lattice rows of every block row's strip, phase by phase
    samples: list[list[tuple[np.ndarray, ...]]] = [[] for _ in range(nch)]
    for r in range(0, rows, max(1, rows // NOISE_STRIPS)):
        if min(block, h - r * block) < max(3 * p, CELL):
            continue
        for py in range(p):
            for px in range(p):
                c = pat[py, px]
                lat = (data[r * block + py:r * block + 3 * p:p, px::p] - black[c]) * scale[c]
                if lat.shape[1] < 3:
                    continue
                bad = lat >= CLIP_FRACTION * gains[c]
                keep = ~(bad[:, :-2] | bad[:, 1:-1] | bad[:, 2:]).any(axis=0)
                samples[c].append((_row3(lat, np.full((3, 3), 1.0 / 9.0))[keep], _row3(lat, IMMERKAER)[keep],
                                   (_row3(lat, SOBEL) ** 2 + _row3(lat, SOBEL.T) ** 2)[keep]))
    out["samples"] = [tuple(np.concatenate(part) for part in zip(*s)) for s in samples]  # type: ignore[assignment]
    out["counts"] = counts
    return out


@pytest.mark.parametrize("cfa", ["lms", "bayer"])
@pytest.mark.parametrize("gain", [1, 64])
def test_analysis_matches_the_per_block_reference(cfa: str, gain: float) -> None:
    raw = small_raw(cfa, gain)
    a, ref = analyse(raw), reference(raw)
    assert a.grid == (5, 6)
    assert ref["uniform"].any() and not ref["uniform"].all() and (ref["clipped"] > 0).any()
    np.testing.assert_array_equal(a.uniform, ref["uniform"])
    np.testing.assert_array_equal(a.clipped, ref["clipped"])
    np.testing.assert_allclose(a.means, ref["means"], rtol=1e-12)
    model, counts = a.model, ref["counts"]
    assert model is not None
    space = space_for(raw.cfa.spectral, raw.colour_matrix)
    var = np.stack([model.variance(c, ref["means"][c]) / counts[c] for c in range(raw.cfa.n_channels)])
    detail = ref["lap_y"] / (LAPLACIAN_NOISE_GAIN * np.tensordot(space.luma ** 2, var, axes=1) + 1e-12)
    chroma = (ref["lap_c"] / (LAPLACIAN_NOISE_GAIN * np.tensordot(space.chroma ** 2, var, axes=1) + 1e-12)).max(axis=0)
    np.testing.assert_allclose(a.detail, detail, rtol=1e-9)
    np.testing.assert_allclose(a.chroma, chroma, rtol=1e-9)
    assert (a.detail > 2.0).any() and (a.detail < 2.0).any()
    # the noise: the same samples, in the same order, so the same fit bit for bit
    for c, (lvl, res, tex) in enumerate(ref["samples"]):  # type: ignore[arg-type]
        assert a.levels[c] == np.median(lvl)
        assert a.noise is not None
        assert (a.noise.shot[c], a.noise.floor[c]) == fit_affine_variance(lvl, res, tex, 8, 150, FLAT_FRACTION)
        v = model.variance(c, lvl)
        flat = np.argpartition(tex / v, int(FLAT_FRACTION * v.size) - 1)[:int(FLAT_FRACTION * v.size)]
        ratio = MAD_TO_STD * np.median(np.abs(res[flat] / np.sqrt(v[flat])))
        assert a.sigma[c] == ratio * np.sqrt(model.variance(c, a.levels[c]))


def test_median_is_numpys_without_numpy_ma() -> None:
    rng = np.random.default_rng(0)
    for n in (1, 2, 3, 10, 11, 1000, 1001):
        for values in (rng.normal(size=n), np.round(rng.normal(size=n) * 3) / 7):   # ties in the second
            assert noise_estimate.median(values) == float(np.median(values))
    code = ("import sys, numpy as np; from clisp.scene.noise import median; median(np.arange(5.0)); "
            "print('numpy.ma' in sys.modules)")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert loaded.strip() == "False"


@pytest.mark.parametrize("cfa", ["lms", "bayer"])
def test_clipped_and_uniform_of_a_float_raw(cfa: str) -> None:
    """A noiseless (float32) raw: samples at the float32 values on either side of the clip
    threshold count as the float64 comparison says."""
    raw = simulate(scene(272, 336), cfa=cfa, gain=None, seed=4).raw
    data = np.array(raw.data[:264, :325])
    assert data.dtype == np.float32
    black = float(raw.black_level[0])
    # a white level whose clip threshold float32 rounds down (the harder case)
    white = next(v for v in float(raw.white_level) + np.arange(1, 100) / 7
                 if np.float32(black + CLIP_FRACTION * (v - black)) < black + CLIP_FRACTION * (v - black))
    threshold = black + CLIP_FRACTION * (white - black)
    near = np.float32(threshold)
    data[64:128, 128:192] = white
    for i, value in enumerate((np.nextafter(near, np.float32(-np.inf)), near, np.nextafter(near, np.float32(np.inf)))):
        data[200 + 10 * i:210 + 10 * i, 70:320:3] = value
    raw = dataclasses.replace(raw, data=data, white_level=white)
    a, ref = analyse(raw), reference(raw)
    assert ref["uniform"].any() and (ref["clipped"][3] > 0).any()
    np.testing.assert_array_equal(a.uniform, ref["uniform"])
    np.testing.assert_array_equal(a.clipped, ref["clipped"])
