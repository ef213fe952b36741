"""clisp.scene.statistics: the block table against a plain per-block loop written from its
definition, the device's kernels against the NumPy reference, and the estimates that read the
tables (the camera-raw noise from the strips, white balance from the thumbnail)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import clisp
from clisp.io.rawimage import RawImage
from clisp.scene.noise import raw_noise
from clisp.scene.statistics import (BLOCK, CELL, CLIP_FRACTION, PEAK, reference_statistics, strip_height, strip_rows,
                                    thumbnail_step)
from clisp.scene.statistics_device import device_statistics
from clisp.sim.simulate import simulate


def make_raw(cfa: str, dtype: type = np.uint16) -> RawImage:
    """270 x 333 px (a partial last block row and column, an odd width): noise over a gradient,
    a clipped patch, a constant block and samples just at and below each channel's clip level."""
    yy, xx = np.mgrid[0:272, 0:336] / 336.0
    img = np.stack([0.1 + 0.5 * xx, 0.15 + 0.4 * yy, 0.3 + 0.2 * xx * yy], -1)
    img[0:40, 150:260] = 4.0
    raw = simulate(img, cfa=cfa, gain=4, seed=2).raw
    data = np.array(raw.data[:270, :333])
    level = float(raw.black_level[0]) + CLIP_FRACTION * (float(raw.white_level) - float(raw.black_level[0]))
    data[64:128, 64:128] = 700
    data[200:210, 10:300:3] = np.ceil(level)
    data[210:220, 10:300:3] = np.floor(level)
    return dataclasses.replace(raw, data=data.astype(dtype))


def per_block(raw: RawImage) -> dict[str, np.ndarray]:
    """The block table by loops over blocks, cells and samples, in float64 and Python integers."""
    cfa, data = raw.cfa, np.asarray(raw.data, dtype=np.float64)
    p, nch = cfa.period, cfa.n_channels
    h, w = data.shape
    black = np.broadcast_to(np.asarray(raw.black_level, dtype=np.float64), (nch,))
    level = black + CLIP_FRACTION * (float(raw.white_level) - black)
    rows, cols, cb, wc = -(-h // BLOCK), -(-w // BLOCK), BLOCK // CELL, w // CELL
    chan = cfa.pattern[np.arange(h)[:, None] % p, np.arange(w)[None, :] % p]
    out = {"sums": np.zeros((nch, rows, cols)), "clipped": np.zeros((nch, rows, cols)),
           "uniform": np.zeros((rows, cols), bool), "lap": np.zeros((nch * (nch + 1) // 2, rows, cols))}
    for r in range(rows):
        y0, y1 = r * BLOCK, min(h, (r + 1) * BLOCK)
        hc = (y1 - y0) // CELL
        cells = np.zeros((nch, hc, wc))                  # this block row's cell sums
        for i in range(hc):
            for j in range(wc):
                for py in range(CELL):
                    for px in range(CELL):
                        y, x = y0 + i * CELL + py, j * CELL + px
                        cells[chan[y, x], i, j] += data[y, x]
        for c_ in range(cols):
            x0, x1 = c_ * BLOCK, min(w, (c_ + 1) * BLOCK)
            blk, ch = data[y0:y1, x0:x1], chan[y0:y1, x0:x1]
            for c in range(nch):
                out["clipped"][c, r, c_] = np.count_nonzero((blk >= level[c]) & (ch == c))
                out["sums"][c, r, c_] = cells[c, :, c_ * cb:min(wc, (c_ + 1) * cb)].sum()
            out["uniform"][r, c_] = all(len(np.unique(blk[py::p, px::p])) <= 1 for py in range(p) for px in range(p))
            for i in range(1, hc - 1):
                for j in range(c_ * cb + 1, min(c_ * cb + cb, wc - 2) + 1):
                    lap = (cells[:, i - 1, j] + cells[:, i + 1, j] + cells[:, i, j - 1] + cells[:, i, j + 1]
                           - 4 * cells[:, i, j])
                    out["lap"][:, r, c_] += [lap[a] * lap[b] for a, b in zip(*np.triu_indices(nch))]
    return out


@pytest.mark.parametrize("cfa", ["bayer", "lms"])
def test_block_table_is_its_definition(cfa: str) -> None:
    raw = make_raw(cfa)
    stats = reference_statistics(raw)
    table = stats.table
    expect = per_block(raw)
    h, w = raw.data.shape                                # the block maxima the clip map reads
    assert stats.peaks.shape == (-(-h // PEAK), -(-w // PEAK)) and stats.peaks.dtype == raw.data.dtype
    assert all(stats.peaks[i, j] == raw.data[i * PEAK:(i + 1) * PEAK, j * PEAK:(j + 1) * PEAK].max()
               for i in range(stats.peaks.shape[0]) for j in range(stats.peaks.shape[1]))
    for name, value in expect.items():
        assert np.array_equal(getattr(table, name), value), name
    assert expect["uniform"][1, 1] and not expect["uniform"][0, 0]
    assert expect["clipped"].sum() > 0 and expect["clipped"][:, 3].sum() > 0


@pytest.mark.parametrize("cfa", ["bayer", "lms"])
def test_device_equals_the_reference(rt, cfa: str) -> None:
    """Integer raws bit for bit; a float32 raw's Laplacian products (float32 sums on the device,
    float64 in the reference) within float32 rounding."""
    raw = make_raw(cfa)
    ref, dev = reference_statistics(raw), device_statistics(raw, rt)
    for name in ("sums", "clipped", "uniform", "lap"):
        assert np.array_equal(getattr(ref.table, name), getattr(dev.table, name)), name
    cells, clipped = ref.thumbnail()
    assert np.array_equal(cells, dev.cells) and np.array_equal(clipped, dev.cells_clipped)
    assert dev.strips.keys() == ref.strips.keys()
    assert all(np.array_equal(ref.strips[r], dev.strips[r]) for r in ref.strips)
    floats = dataclasses.replace(raw, data=raw.data.astype(np.float32))
    ref, dev = reference_statistics(floats), device_statistics(floats, rt)
    for name in ("sums", "clipped", "uniform"):
        assert np.array_equal(getattr(ref.table, name), getattr(dev.table, name)), name
    scale = np.abs(ref.table.lap).max()
    assert np.allclose(dev.table.lap, ref.table.lap, rtol=1e-5, atol=1e-6 * scale)
    assert np.array_equal(ref.thumbnail()[0], dev.cells)


@pytest.mark.parametrize("cfa", ["bayer", "lms"])
def test_a_raw_file_reads_as_the_array(tmp_path, cfa: str) -> None:
    """The pass over a raw file mapped in memory (whole rows by pread) equals the pass over the
    same mosaic in memory: the table, the strips, and a subsampled thumbnail (about every 3rd cell)."""
    from clisp.io.rawfile import read_raw, write_raw
    raw = make_raw(cfa)
    write_raw(tmp_path / "r.dng", raw)
    lazy = read_raw(tmp_path / "r.dng", lazy=True)
    assert isinstance(lazy.data, np.memmap)
    cells = (raw.data.shape[0] // raw.cfa.period) * (raw.data.shape[1] // raw.cfa.period)
    mem, fil = reference_statistics(raw, max_cells=cells // 9), reference_statistics(lazy, max_cells=cells // 9)
    assert mem.step == fil.step > 1
    for name in ("sums", "clipped", "uniform", "lap"):
        assert np.array_equal(getattr(mem.table, name), getattr(fil.table, name)), name
    assert all(np.array_equal(mem.strips[r], fil.strips[r]) for r in mem.strips)
    for a, b in zip(mem.thumbnail(), fil.thumbnail()):
        assert np.array_equal(a, b)
    for source in (raw, lazy):                         # the thumbnail from the pass's own bands
        fused = reference_statistics(source, max_cells=cells // 9, cells=True)
        assert fused.raw is None and fused.cells is not None
        for a, b in zip(mem.thumbnail(), (fused.cells, fused.cells_clipped)):
            assert np.array_equal(a, b)


def test_the_grid_and_its_subsamples() -> None:
    assert thumbnail_step((512, 768), 2) == 1 and thumbnail_step((4000, 6000), 2) == 4
    assert strip_rows((100, 64), 2) == [0, 1]                        # a 36-row last block row has its strip
    assert strip_rows((68, 64), 2) == [0]                            # a 4-row last block row has no strip
    assert strip_height((512, 768), 2) == BLOCK and strip_height((4000, 6000), 2) == 6


def test_noise_from_the_strips_follows_the_model() -> None:
    """On a smooth scene at gain 16 the strips' estimate is within 10 % of the sensor model's
    sigma in every channel (texture inflates it on busy scenes: docs/RESULTS.md)."""
    yy, xx = np.mgrid[0:384, 0:512] / 512.0
    img = np.stack([0.2 + 0.3 * xx, 0.25 + 0.2 * yy, 0.3 + 0.1 * xx], -1)
    raw = simulate(img, cfa="bayer", gain=16, seed=5).raw
    stats = reference_statistics(raw)
    model, est = raw_noise(raw, estimate=False), raw_noise(raw, estimate=True, statistics=stats)
    for c in range(3):
        level = float(np.median(stats.thumbnail()[0][..., c])) * raw.pass1_gains()[c]
        assert abs(np.sqrt(est.variance(c, level) / model.variance(c, level)) - 1) < 0.1


@pytest.mark.parametrize("cfa", ["lms", "bayer"])
def test_a_raw_under_three_cfa_tiles_wide_is_processed(cfa: str) -> None:
    """A 300 x 4 raw has no 3 x 3 window on its LMS lattices (one lattice column): the strips give no
    noise samples (the estimate falls back) instead of a ValueError from a negative array size."""
    rng = np.random.default_rng(0)
    raw = simulate(rng.random((300, 4, 3)), cfa=cfa, gain=4, seed=1).raw
    raw = dataclasses.replace(raw, metadata={})                 # a camera raw's: the noise is estimated
    out = clisp.process(raw, preset="quality")
    assert out.shape == (300, 4, 3) and np.all(np.isfinite(out))
