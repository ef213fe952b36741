"""Tile streaming (issue 6): planner, file windows, streamed output, large simulation.

Every comparison of two pipeline outputs uses the kernels' stated tolerance (as test_tiling.py):

    |a - b| <= TOL * max(1, |b|)
"""
from __future__ import annotations

import argparse
import importlib
import os
from pathlib import Path

import numpy as np
import pytest
import tifffile

import clisp
from clisp.cfa import cfa_from_name
from clisp.app.cli import image_size, main, memory_size
from clisp.sim.colorimetry import B_BAYER, P_LMS, WB_BAYER, WB_LMS
from clisp.errors import ClispError
from clisp.io.imageio import ImageWriter, read_image
import clisp.engine.memory
from clisp.engine.memory import RSS_MARGIN
from clisp.pipeline import PRESETS, build_pipeline, process_file
import clisp.engine.executor
from clisp.engine.runtime import get_runtime
from clisp.io.rawfile import raw_band_writer, read_raw, write_raw
from clisp.io.rawimage import RawImage
from clisp.sim.simulate import mirror_repeat_index, simulate, simulate_large
from clisp.engine.stage import Stage
import clisp.engine.streaming
from clisp.engine.streaming import ArrayWindows, FileWindows, WindowPool, run_tiles, window_source
from clisp.engine.tiling import (MIN_BAND_ROWS, MIN_TILE, DeviceLimits, TileNeeds, TilePlan, gather_window, grid,
                                 make_plan)
from tolerance import TOL, assert_close

simulate_module = importlib.import_module("clisp.sim.simulate")   # clisp.sim.simulate is the function

SHAPE = (1093, 1157)          # not a multiple of any tile size or CFA period; 2 x 2 tiles of 1024




def make_raw(kind: str, shape: tuple[int, int] = SHAPE, dtype: type = np.uint16, seed: int = 3) -> RawImage:
    """Random raw in DN with the camera constants of its CFA kind."""
    cfa = cfa_from_name(kind)
    matrix, wb = (P_LMS, WB_LMS) if cfa.kind == "lms" else (B_BAYER, WB_BAYER)
    rng = np.random.default_rng(seed)
    if dtype == np.uint16:
        data = rng.integers(64, 1024, size=shape, dtype=np.uint16)
    else:
        data = (rng.random(shape) * 1100.0 - 30.0).astype(np.float32)
    return RawImage(data=data, cfa=cfa, black_level=np.array([64.0, 65.0, 66.0]), white_level=1023.0,
                    wb=wb, colour_matrix=matrix, exposure=1.0 / 0.98951)


def band_plan(pipeline, shape: tuple[int, int], rows: int) -> TilePlan:
    """Full-width bands of ``rows`` output rows (a multiple of the CFA period) for an H x W raw: the
    shape of a CPU device's automatic plans, on every device (a discrete GPU plans a small raw as one
    tile whatever the host budget: executor.device_buffers_in_host_memory)."""
    height, width = pipeline.output_shape(shape)
    return TilePlan(grid(height, width, rows, width), rows, width, pipeline.halo, pipeline.downscale)


# ------------------------------------------------------------------------------------------
# tiled == whole image, every preset
# ------------------------------------------------------------------------------------------

SLOW_PRESETS = {("best", "bayer"): ((300, 322), (96, 200), 96 * 2**20)}
"""Presets with a slow, wide demosaic (best's Bayer ARI: about 0.5 MP/s, halo 121): a smaller raw,
tiles and the budget of the automatic plan scaled to its halo (16 MiB cannot hold one of its tiles).
Under the stress marker: ARI's 138 programs take about 4 minutes to compile on 2 cores with an
empty PoCL cache, half the suite's time; tests/modules/test_demosaic_ari_cl.py tests the stage's
own tiling in the fast subset."""


def preset_cases() -> list:
    """(preset, CFA kind) for every preset and kind (every preset serves both); the slow ones under
    the stress marker."""
    return [pytest.param(name, kind, marks=[pytest.mark.stress] if (name, kind) in SLOW_PRESETS else [])
            for name in PRESETS for kind in ("lms", "bayer")]


@pytest.mark.parametrize("name,kind", preset_cases())
def test_every_preset_tiled_equals_whole(name: str, kind: str) -> None:
    shape, tiles, budget = SLOW_PRESETS.get((name, kind), (SHAPE, (64, 256, 1024), 16 * 2**20))
    raw = make_raw(kind, shape)
    pipeline = build_pipeline(raw, preset=name)
    whole = pipeline.run(raw.data, tile=0)
    assert pipeline.stats.tiles == 1
    for tile in tiles:
        tiled = pipeline.run(raw.data, tile=tile)
        assert pipeline.stats.tiles > 1
        assert_close(tiled, whole, f"{name}/{kind} tile {tile}")
    auto = pipeline.run(raw.data, budget=budget)              # tiles chosen from a small budget
    plan = pipeline.plan(raw.shape, raw.data.dtype, budget=budget)
    device = pipeline.metered_tile(pipeline.schedule(), plan.window_shape, raw.data.dtype)[0]
    assert pipeline.stats.tiles == len(plan.tiles)
    if clisp.engine.executor.device_buffers_in_host_memory(get_runtime()):
        assert len(plan.tiles) > 1 and device <= budget      # bands or squares, by the stages' needs
    else:           # a discrete device: the host's budget does not bound its buffers (here: fewer tiles)
        assert device > budget
    assert_close(auto, whole, f"{name}/{kind} automatic tiles")


@pytest.mark.parametrize("kind", ["lms", "bayer"])
@pytest.mark.parametrize("output", ["linear", "srgb16"])
def test_last_stage_writes_into_host_bands(monkeypatch: pytest.MonkeyPatch, kind: str, output: str,
                                           device_kind) -> None:
    """Full-width bands of the fast pipeline: on a device that shares host memory the last kernel
    writes straight into the output where the band's first row is aligned (Runtime.host_image);
    the others, and the last, ragged band, whose window's output would run past the image, are
    downloaded (on a discrete device every band is). The result equals the download path's and
    the reference."""
    raw = make_raw(kind, shape=(301, 517))
    # highlights off: the random raw passes white, and the highlight stage's halo would make squares
    pipeline = build_pipeline(raw, preset="fast", output=output, highlights="off")
    rt = device_kind
    made = []
    host_image = rt.host_image

    def counting(array: np.ndarray):
        image = host_image(array)
        made.append(image is not None)
        return image

    monkeypatch.setattr(rt, "host_image", counting)
    plan = band_plan(pipeline, raw.shape, 52)
    assert len(plan.tiles) > 2 and raw.shape[0] % plan.tile_h != 0
    out = clisp.engine.streaming.aligned_array(raw.shape + (3,), pipeline.out_dtype)
    pipeline.stream(ArrayWindows(raw.data), clisp.engine.streaming.ArraySink(out), plan)
    align = int(rt.device.mem_base_addr_align) // 8                # a band's first row must be aligned
    row = raw.shape[1] * 3 * out.itemsize
    assert made == [rt.host_unified and t.y0 * row % align == 0 for t in plan.tiles[:-1]] and made[0] == rt.host_unified
    monkeypatch.setattr(rt, "host_unified", False)                # the download path
    downloaded = pipeline.run(raw.data, tile=0)
    ref = pipeline.run(raw.data, backend="reference")
    if output == "srgb16":      # one code off where float rounding meets a half code
        for other in (downloaded, ref):
            diff = np.abs(out.astype(np.int32) - other)
            assert diff.max() <= 1 and np.mean(diff > 0) < 0.01
    else:
        assert_close(out, downloaded, "host bands")
        assert_close(out, ref, "host bands vs reference")


@pytest.mark.parametrize("kind", ["lms", "bayer"])
def test_streamed_files_equal_in_memory(tmp_path: Path, kind: str) -> None:
    raw = make_raw(kind, shape=(301, 517), dtype=np.float32)
    write_raw(tmp_path / "r.dng", raw)
    lazy = read_raw(tmp_path / "r.dng", lazy=True)
    assert isinstance(lazy.data, np.memmap)
    linear, encoded = clisp.process(raw), clisp.process(raw, output="srgb")
    for tile in (None, 64, 256):
        _, stats = process_file(lazy, tmp_path / "o.exr", tile=tile)
        assert stats.tiles > 1 or tile is None
        image, is_float = read_image(tmp_path / "o.exr")
        assert is_float
        assert_close(image, linear, f"EXR, tile {tile}")
    process_file(lazy, tmp_path / "o.png", tile=64)
    png, _ = read_image(tmp_path / "o.png")
    assert np.abs(png - encoded).max() <= 1.0 / 65535 + 1e-6


@pytest.mark.parametrize("preset", ["fast", "quality"])
def test_whole_process_budget_plans_counted_bytes(tmp_path: Path, preset: str,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """process_file's budget is the whole process: what it holds when planning, RSS_MARGIN and
    the tiles' counted bytes (device buffers by a metering run, host windows, output bands) fit
    it; below the minimum the error names the file and the minimum."""
    raw = make_raw("lms", shape=(301, 517), dtype=np.float32)
    pipeline = build_pipeline(raw, preset=preset)
    rt = get_runtime()
    limits = DeviceLimits(int(rt.device.global_mem_size), int(rt.device.max_mem_alloc_size))
    cost = pipeline.tile_cost(raw.data.dtype, 517, limits, sink_bands=True)
    assert cost(64, 517) > cost(32, 517) > cost(16, 16) > 0
    monkeypatch.setattr(clisp.engine.memory, "resident_bytes", lambda: 100 * 2**20)   # the process holds 100 MiB
    budget = 100 * 2**20 + RSS_MARGIN + 6 * 2**20
    _, stats = process_file(raw, tmp_path / "o.exr", budget=budget, preset=preset)
    rows, cols = stats.tile_shape
    assert cost(rows, cols) <= 6 * 2**20 and stats.tiles > 1
    with pytest.raises(ClispError, match=r"o2.exr: --mem 64M is below the minimum of \d+"):
        process_file(raw, tmp_path / "o2.exr", budget=64 * 2**20, preset=preset)
    assert not (tmp_path / "o2.exr").exists()


def test_metered_tiles_are_kept_per_pipeline_and_code(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A tile's metered bytes are kept on disk: a later plan of the same pipeline (same stages and
    parameters, device, raw dtype) reads them without a metering run and gets the same costs; other
    parameters, or an edited clisp (its code fingerprint), meter anew."""
    from clisp.engine import disk_cache, executor
    from clisp.engine.executor import Pipeline
    monkeypatch.setenv("CLISP_CACHE_DIR", str(tmp_path))
    executor.METERED.clear()          # what this process metered before (an earlier test's pipeline) is not on this disk
    raw = make_raw("lms", shape=(301, 517))
    rt = get_runtime()
    limits = DeviceLimits(int(rt.device.global_mem_size), int(rt.device.max_mem_alloc_size))
    pipeline = build_pipeline(raw, preset="fast")
    first = pipeline.tile_cost(raw.data.dtype, 517, limits, sink_bands=True)
    costs = [first(64, 517), first(32, 64)]
    assert len(list((tmp_path / "metering").iterdir())) == 1
    metered = []
    real = Pipeline.metered_tile
    monkeypatch.setattr(Pipeline, "metered_tile", lambda self, *a: metered.append(a) or real(self, *a))
    again = build_pipeline(raw, preset="fast").tile_cost(raw.data.dtype, 517, limits, sink_bands=True)
    assert [again(64, 517), again(32, 64)] == costs and not metered
    other = build_pipeline(raw, preset="fast", highlights="off").tile_cost(raw.data.dtype, 517, limits, sink_bands=True)
    other(64, 517)
    assert len(metered) == 1
    monkeypatch.setattr(disk_cache, "_FINGERPRINT", "edited code")
    edited = build_pipeline(raw, preset="fast").tile_cost(raw.data.dtype, 517, limits, sink_bands=True)
    assert edited(64, 517) == costs[0] and len(metered) == 2


def test_metering_run_counts_what_the_tile_creates(device_kind) -> None:
    """A metering run creates nothing and predicts the pool of a real tile exactly, with the
    buffers of the run's input: on a device sharing host memory the metering run reads the window
    in place (not counted), and the run's one window is gathered by the host (not pooled either);
    a discrete device's metering run counts the uploaded window, the run
    gathers that window from the whole mosaic, copied to the device into a pooled buffer."""
    raw = make_raw("lms", shape=(301, 517))
    pipeline = build_pipeline(raw, preset="quality")
    rt = device_kind
    created, largest = pipeline.metered_tile(pipeline.schedule(), (301, 517), raw.data.dtype)
    rt.trim_pool()
    held = rt.pool.created                     # buffers other tests still hold (not in the pool)
    pipeline.run(raw.data, tile=0)             # one tile: window = image + halo
    window = (301 + 2 * pipeline.halo, 517 + 2 * pipeline.halo)
    expected = pipeline.metered_tile(pipeline.schedule(), window, raw.data.dtype)[0]
    from clisp.engine.executor import resident_policy
    if not rt.host_unified:
        assert resident_policy(rt, raw.data.nbytes, tiles=1)
        expected += raw.data.nbytes                                     # the resident mosaic (pooled)
    else:                              # shared memory, one tile: the host gathers the window (not pooled)
        assert not resident_policy(rt, raw.data.nbytes, tiles=1)
    assert expected == rt.pool.created - held
    assert 0 < largest <= created


def test_rotated_camera_raw_to_file(tmp_path: Path) -> None:
    raw = make_raw("bayer", shape=(120, 200))
    raw.metadata["flip"] = 6                                             # 90 degrees clockwise
    shape, _ = process_file(raw, tmp_path / "o.exr", tile=64)
    assert shape == (200, 120)
    assert_close(read_image(tmp_path / "o.exr")[0], clisp.process(raw), "rotated")


def test_cli_streams_silently(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                              monkeypatch: pytest.MonkeyPatch) -> None:
    raw = make_raw("lms", shape=(300, 400))
    write_raw(tmp_path / "r.dng", raw)
    monkeypatch.setattr(clisp.engine.memory, "resident_bytes", lambda: 100 * 2**20)   # the process holds 100 MiB
    mem = f"{(100 * 2**20 + RSS_MARGIN) // 2**20 + 4}M"    # 4 MiB left for tiles: several bands
    code = main(["process", str(tmp_path / "r.dng"), "-o", str(tmp_path / "o.exr"), "--mem", mem,
                 "--preset", "fast"])
    out, err = capsys.readouterr()
    assert code == 0 and err == "", err                   # no progress bar when stderr is no terminal
    assert "tiles of 400x" in out and " 1 tiles" not in out
    assert_close(read_image(tmp_path / "o.exr")[0], clisp.process(raw, preset="fast"), f"CLI --mem {mem}")


# ------------------------------------------------------------------------------------------
# failures leave no file
# ------------------------------------------------------------------------------------------

def test_failed_write_leaves_no_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    raw = make_raw("bayer", shape=(300, 200))
    calls = []

    def failing(self: ImageWriter, y0: int, rows: np.ndarray) -> None:
        calls.append(y0)
        if len(calls) == 2:
            raise ClispError(f"{self.path}: disk full (simulated)")
        real(self, y0, rows)

    real = ImageWriter.write_rows
    monkeypatch.setattr(ImageWriter, "write_rows", failing)
    with pytest.raises(ClispError, match="disk full"):
        process_file(raw, tmp_path / "o.tif", tile=64)
    assert list(tmp_path.iterdir()) == []


def test_truncated_raw_while_streaming(tmp_path: Path) -> None:
    path = tmp_path / "r.dng"
    write_raw(path, make_raw("lms", shape=(256, 128)))
    raw = read_raw(path, lazy=True)
    os.truncate(path, os.path.getsize(path) // 2)
    with pytest.raises(ClispError, match="truncated"):
        process_file(raw, tmp_path / "o.exr", tile=64)
    assert [p.name for p in tmp_path.iterdir()] == ["r.dng"]


def test_image_writer_needs_every_row(tmp_path: Path) -> None:
    with pytest.raises(ClispError, match="only 4 of 8 rows"):
        with ImageWriter(tmp_path / "o.exr", 5, 8) as out:
            out.write_rows(0, np.zeros((4, 5, 3), np.float32))
    with pytest.raises(ClispError, match="does not follow"):
        with ImageWriter(tmp_path / "o.png", 5, 8) as out:
            out.write_rows(4, np.zeros((4, 5, 3), np.float32))
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------------------
# reading windows from the file
# ------------------------------------------------------------------------------------------

WINDOWS = [(0, 0, 37, 53), (-6, -6, 49, 65), (-6, 20, 30, 20), (30, -3, 20, 59), (-40, -50, 120, 160),
           (36, 52, 1, 1), (20, 40, 30, 30)]


@pytest.mark.parametrize("dtype", [np.uint16, np.float32])
def test_file_windows_equal_array_windows(tmp_path: Path, dtype: type) -> None:
    raw = make_raw("lms", shape=(37, 53), dtype=dtype)
    write_raw(tmp_path / "r.dng", raw)
    lazy = read_raw(tmp_path / "r.dng", lazy=True)
    source = window_source(lazy.data)
    assert isinstance(source, FileWindows) and source.shape == (37, 53)
    try:
        for window in WINDOWS:
            got = source.read(*window, 4)
            assert got.dtype == dtype and got.flags.c_contiguous
            np.testing.assert_array_equal(got, gather_window(raw.data, *window, 4), err_msg=str(window))
        for r0, r1 in [(0, 37), (4, 8), (36, 37)]:                    # whole rows, one pread
            rows = source.read_rows(r0, r1)
            assert rows.dtype == dtype and rows.flags.c_contiguous
            np.testing.assert_array_equal(rows, raw.data[r0:r1])
    finally:
        source.close()
    assert isinstance(window_source(lazy.data[1:]), ArrayWindows)      # a slice is not the file
    assert isinstance(window_source(raw.data), ArrayWindows)


def test_windows_read_into_given_arrays(tmp_path: Path) -> None:
    """Both sources fill an ``out`` array (the WindowPool's) with the window they would return,
    reading the same values twice in a row through the file source's reused block; a wrong shape
    or dtype is refused."""
    raw = make_raw("lms", shape=(37, 53), dtype=np.uint16)
    write_raw(tmp_path / "r.dng", raw)
    source = window_source(read_raw(tmp_path / "r.dng", lazy=True).data)
    pool = WindowPool()
    try:
        for src in (source, ArrayWindows(raw.data)):
            for window in WINDOWS:
                out = pool.take(window[2:], src.window_dtype)
                got = src.read(*window, 4, out=out)
                assert got is out
                np.testing.assert_array_equal(got, gather_window(raw.data, *window, 4), err_msg=str(window))
                pool.give(out)
            with pytest.raises(ValueError, match="does not fit"):
                src.read(0, 0, 8, 8, 4, out=np.zeros((8, 9), np.uint16))
    finally:
        source.close()


def test_window_pool_reuses_only_given_back_buffers() -> None:
    """A taken window is never handed out again before it is given back; given back, its buffer
    serves the next window that fits. Buffers are page-aligned (read in place by the device)."""
    pool = WindowPool()
    a = pool.take((10, 20), np.uint16)
    b = pool.take((10, 20), np.uint16)
    assert not np.shares_memory(a, b)
    assert a.ctypes.data % 4096 == 0 and b.ctypes.data % 4096 == 0
    a[:] = 7
    pool.give(a)
    c = pool.take((5, 20), np.float32)                 # 400 bytes fit a's 400
    assert np.shares_memory(c, a) and c.shape == (5, 20) and c.dtype == np.float32
    d = pool.take((10, 20), np.uint16)                 # a is taken again (as c): a new buffer
    assert not np.shares_memory(d, a) and not np.shares_memory(d, b)
    pool.give(np.zeros(3))                             # not from the pool: ignored
    pool.give(b)
    assert np.shares_memory(pool.take((10, 20), np.uint16), b)


def test_run_tiles_releases_a_window_after_its_tile_finished() -> None:
    """run_tiles hands a window back only after the wait on its tile's event, reads at most
    READ_AHEAD windows ahead, and so never holds more than READ_AHEAD + 2 windows."""
    plan = make_plan(64, 40, TileNeeds(halo=0, align=2, device_bytes=1, host_bytes=1, largest_bytes=1), tile=8)
    log: list[tuple[str, int]] = []
    held: set[int] = set()
    most = 0

    class Event:
        def __init__(self, i: int) -> None:
            self.i = i

        def wait(self) -> None:
            log.append(("wait", self.i))

    def read(t):
        nonlocal most
        i = plan.tiles.index(t)
        held.add(i)
        most = max(most, len(held))
        return np.full((1, 1), i)

    def compute(t, window, target):
        return Event(int(window[0, 0]))

    def release(window):
        i = int(window[0, 0])
        assert ("wait", i) in log, f"window {i} released before its tile's event was waited on"
        held.discard(i)
        log.append(("release", i))

    run_tiles(plan, read, compute, clisp.engine.streaming.ArraySink(np.zeros((64, 40, 3))), release=release)
    assert [i for kind, i in log if kind == "release"] == list(range(len(plan.tiles)))
    assert 2 < len(plan.tiles) and most <= clisp.engine.streaming.READ_AHEAD + 2


def test_window_read_in_place_on_host_memory_devices(monkeypatch: pytest.MonkeyPatch, device_kind) -> None:
    """Windows the host reads (a mosaic that does not stay on the device): on a device sharing host
    memory the first stage reads each pooled window in place (no upload), a discrete device gets
    each uploaded; the result equals the upload path's."""
    raw = make_raw("bayer", shape=(301, 517))
    raw.data = unaligned(raw.data)                  # else a shared-memory device gathers from the whole mosaic
    monkeypatch.setattr(clisp.engine.executor, "RESIDENT_SHARE", 0.0)    # and a discrete one from its copy
    pipeline = build_pipeline(raw, preset="fast")
    rt = device_kind
    uploads, in_place = [], []
    upload, host_input = rt.upload, rt.host_input
    monkeypatch.setattr(rt, "upload", lambda a: uploads.append(a.shape) or upload(a))
    monkeypatch.setattr(rt, "host_input", lambda a: (lambda i: in_place.append(i is not None) or i)(host_input(a)))
    plan = band_plan(pipeline, raw.shape, 52)
    out = np.zeros(raw.shape + (3,), pipeline.out_dtype)
    pipeline.stream(ArrayWindows(raw.data), clisp.engine.streaming.ArraySink(out), plan)
    assert len(plan.tiles) > 2 and in_place == [rt.host_unified] * len(plan.tiles)
    assert len(uploads) == (0 if rt.host_unified else len(plan.tiles))
    monkeypatch.setattr(rt, "host_unified", False)
    assert_close(out, pipeline.run(raw.data, tile=0), "in place vs upload")


def unaligned(data: np.ndarray) -> np.ndarray:
    """A copy of ``data`` starting 2 bytes past a page boundary: never read in place by the device."""
    out = clisp.engine.streaming.aligned_empty(data.nbytes + 2)[2:].view(data.dtype).reshape(data.shape)
    out[...] = data
    return out


@pytest.mark.parametrize("kind", ["bayer", "lms"])
@pytest.mark.parametrize("dtype", [np.uint16, np.float32])
@pytest.mark.parametrize("one_launch", [True, False])
def test_device_gather_equals_host_gather(kind: str, dtype: type, one_launch: bool,
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    """Runtime.gather_window (clisp/engine/gather.cl) equals tiling.gather_window, the CFA mirror included:
    windows inside, across every edge, wider and taller than the image; gathered in one launch (a
    small window) or in the vectorised launch over the inside columns and one per mirrored side."""
    import clisp.engine.runtime as runtime
    monkeypatch.setattr(runtime, "GATHER_ONE_LAUNCH", 1 << 20 if one_launch else 0)
    rt = get_runtime()
    data = make_raw(kind, shape=(37, 45), dtype=dtype).data
    whole = rt.upload(data)
    period = cfa_from_name(kind).period
    try:
        for y0, x0, h, w in [(4, 8, 12, 16), (-6, -9, 20, 30), (25, 30, 20, 24), (-8, -12, 53, 69),
                             (0, -5, 37, 5), (-3, 44, 9, 7)]:
            got = rt.download(rt.gather_window(whole, y0, x0, h, w, period))
            np.testing.assert_array_equal(got.reshape(h, w), gather_window(data, y0, x0, h, w, period),
                                          err_msg=f"window {(y0, x0, h, w)}")
    finally:
        rt.release(whole)


@pytest.mark.parametrize("preset, tile", [("fast", None), ("quality", 104)])
def test_pipeline_gathers_windows_on_the_device(preset: str, tile: int | None, monkeypatch: pytest.MonkeyPatch,
                                                device_kind) -> None:
    """An aligned in-memory mosaic, read in place by a device sharing host memory, copied once to a
    discrete one (Runtime.resident_mosaic): no host window per tile, the device gathers each one
    from the whole mosaic; the output equals the host-gather path's. ``tile``: squares of that
    side, None bands of 52 rows."""
    raw = make_raw("bayer", shape=(301, 517))
    pipeline = build_pipeline(raw, preset=preset)
    rt = device_kind
    gathered = []
    gather = rt.gather_window
    monkeypatch.setattr(rt, "gather_window", lambda *a: gathered.append(a[1:]) or gather(*a))
    plan = band_plan(pipeline, raw.shape, 52) if tile is None else pipeline.plan(raw.shape, raw.data.dtype, tile)
    out = np.zeros(raw.shape + (3,), pipeline.out_dtype)
    pipeline.stream(ArrayWindows(clisp.engine.streaming.aligned_copy(raw.data)), clisp.engine.streaming.ArraySink(out), plan)
    assert len(gathered) == len(plan.tiles) > 2
    monkeypatch.setattr(clisp.engine.executor, "RESIDENT_SHARE", 0.0)    # a discrete device: no copy either
    host = np.zeros_like(out)
    pipeline.stream(ArrayWindows(unaligned(raw.data)), clisp.engine.streaming.ArraySink(host), plan)
    assert len(gathered) == len(plan.tiles)                              # the host gathered these
    np.testing.assert_array_equal(out, host)


def test_file_windows_big_endian(tmp_path: Path) -> None:
    data = np.arange(20 * 30, dtype=np.uint16).reshape(20, 30)
    path = tmp_path / "be.bin"
    path.write_bytes(b"x" * 100 + data.astype(">u2").tobytes())
    source = FileWindows(path, 100, data.shape, ">u2")
    try:
        got = source.read(-2, 5, 24, 10, 2)
        assert got.dtype == np.uint16
        np.testing.assert_array_equal(got, gather_window(data, -2, 5, 24, 10, 2))
        rows = source.read_rows(3, 7)
        assert rows.dtype == np.uint16
        np.testing.assert_array_equal(rows, data[3:7])
    finally:
        source.close()


# ------------------------------------------------------------------------------------------
# the planner
# ------------------------------------------------------------------------------------------

NEEDS = TileNeeds(halo=3, align=4, device_bytes=80.0, host_bytes=40.0, largest_bytes=24.0)


def check_plan(plan, height: int, width: int, align: int) -> None:
    count = np.zeros((height, width), np.int32)
    for t in plan.tiles:
        assert t.y0 % align == 0 and t.x0 % align == 0
        assert 0 < t.h <= plan.tile_h and 0 < t.w <= plan.tile_w
        count[t.y0:t.y0 + t.h, t.x0:t.x0 + t.w] += 1
    assert np.all(count == 1)


@pytest.mark.parametrize("budget", [2**30, 64 * 2**20, 4 * 2**20, 2**20])
def test_auto_plan_fits_budget(budget: int) -> None:
    height, width = 3001, 4005
    plan = make_plan(height, width, NEEDS, None, budget)
    check_plan(plan, height, width, NEEDS.align)
    win_h, win_w = plan.window_shape
    assert win_h * win_w * (NEEDS.device_bytes + NEEDS.host_bytes) <= budget
    if plan.tile_w == width and plan.tile_h < height:
        assert plan.tile_h >= MIN_TILE                                # bands are never slivers
    last_row = max(t.y0 for t in plan.tiles)
    assert height - last_row > plan.tile_h - 2 * NEEDS.align * len(plan.tiles)   # split evenly


def test_auto_plan_shapes() -> None:
    assert make_plan(300, 400, NEEDS).tiles == make_plan(300, 400, NEEDS, 0).tiles      # fits: one tile
    bands = make_plan(3000, 4000, NEEDS, None, 2**30)
    assert bands.tile_w == 4000 and len(bands.tiles) > 1                # target size: bands
    tall = make_plan(3000, 100_000, NEEDS, None, 2**30)
    assert tall.tile_w == 100_000 and tall.tile_h >= MIN_BAND_ROWS     # past the target, within budget
    squares = make_plan(3000, 40000, NEEDS, None, 2**20)
    assert squares.tile_w < 40000 and squares.tile_h == squares.tile_w  # no 16-row band fits 1 MiB
    capped = make_plan(3000, 4000, NEEDS, None, 2**30, DeviceLimits(global_mem=2**36, max_alloc=2**20))
    assert capped.window_shape[0] * capped.window_shape[1] * NEEDS.largest_bytes <= 2**20
    with pytest.raises(ClispError, match="too small"):
        make_plan(3000, 4000, NEEDS, None, 2**14)


class Shift8(Stage):
    """Identity that needs tiles aligned to 8 px (as a 2x pyramid over a 4x4 CFA would)."""

    name = "shift8"

    @property
    def align(self) -> int:
        return 8

    def reference(self, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
        return x

    def enqueue(self, rt, src, origin):  # pragma: no cover - reference only
        raise NotImplementedError


def test_stage_alignment_and_bytes_reach_the_plan() -> None:
    raw = make_raw("bayer", shape=(300, 500))
    pipeline = build_pipeline(raw)
    pipeline.stages.insert(2, Shift8())
    assert pipeline.align == 8
    needs = pipeline.needs(np.uint16)
    assert needs.device_bytes >= sum(s.bytes_per_pixel for s in pipeline.stages) + 2
    plan = pipeline.plan(raw.shape, np.uint16, tile=70, backend="reference")
    assert plan.tile_h == 64
    check_plan(plan, 300, 500, 8)


# ------------------------------------------------------------------------------------------
# simulate --size
# ------------------------------------------------------------------------------------------

def repeated(scene: np.ndarray, height: int, width: int) -> np.ndarray:
    rows = mirror_repeat_index(np.arange(height), scene.shape[0])
    cols = mirror_repeat_index(np.arange(width), scene.shape[1])
    return scene[rows][:, cols]


def test_mirror_repeat_index() -> None:
    np.testing.assert_array_equal(mirror_repeat_index(np.arange(10), 3), [0, 1, 2, 2, 1, 0, 0, 1, 2, 2])


@pytest.mark.parametrize("optics", ["airy", "none"])
def test_large_simulation_equals_whole_noiseless(monkeypatch: pytest.MonkeyPatch, optics: str) -> None:
    monkeypatch.setattr(simulate_module, "BAND_PIXELS", 16 * 130)      # 16-row bands
    scene = np.random.default_rng(0).random((40, 52, 3))
    sim = simulate_large(scene, (100, 130), cfa="lms", gain=None, optics=optics)
    assert len(sim.bands) == 7 and sim.header.shape == (100, 130)
    whole = simulate(repeated(scene, 100, 130), cfa="lms", gain=None, optics=optics)
    raw = np.concatenate([sim.band(b)[0] for b in sim.bands])
    truth = np.concatenate([sim.band(b)[1] for b in sim.bands])
    assert raw.dtype == np.float32 and truth.dtype == np.float32
    np.testing.assert_allclose(raw, whole.raw.data, rtol=1e-6, atol=1e-3)
    np.testing.assert_allclose(truth, whole.truth, rtol=1e-6, atol=1e-6)


def test_large_simulation_noise_seeded_per_band(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(simulate_module, "BAND_PIXELS", 16 * 64)
    scene = np.full((8, 8, 3), 0.4)
    a = simulate_large(scene, (64, 64), gain=8, seed=5)
    b = simulate_large(scene, (64, 64), gain=8, seed=5)
    c = simulate_large(scene, (64, 64), gain=8, seed=6)
    bands = [a.band(t)[0] for t in a.bands]
    assert all(x.dtype == np.uint16 for x in bands)
    assert np.array_equal(bands[2], b.band(b.bands[2])[0])              # reproducible, in any order
    assert not np.array_equal(bands[2], c.band(c.bands[2])[0])
    assert not np.array_equal(bands[0], bands[1])                       # each band its own stream


def test_cli_simulate_size(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from clisp.io.imageio import write_image
    scene = np.random.default_rng(1).random((30, 40, 3))
    write_image(tmp_path / "s.exr", scene)
    args = ["simulate", str(tmp_path / "s.exr"), "--size", "90x70", "-o", str(tmp_path / "r.dng"),
            "--truth", str(tmp_path / "t.exr"), "--noiseless", "--cfa", "bayer"]
    assert main(args) == 0, capsys.readouterr().err
    raw = read_raw(tmp_path / "r.dng")
    whole = simulate(repeated(scene.astype(np.float32).astype(np.float64), 70, 90), cfa="bayer", gain=None)
    assert raw.shape == (70, 90) and raw.cfa.name == "bayer-rggb"
    assert raw.metadata["repeat"]["mode"] == "mirror" and raw.metadata["scene"] == "s.exr"
    np.testing.assert_allclose(raw.data, whole.raw.data, rtol=1e-6, atol=1e-3)
    np.testing.assert_allclose(read_image(tmp_path / "t.exr")[0], whole.truth, rtol=1e-6, atol=1e-6)
    with tifffile.TiffFile(tmp_path / "r.dng") as tif:
        page = tif.pages[0]
        assert page.rowsperstrip == 16 and int(page.compression) == 1 and page.is_contiguous


def test_band_writer_needs_every_row(tmp_path: Path) -> None:
    header = make_raw("lms", shape=(40, 24))
    header.data = np.broadcast_to(np.zeros((), np.uint16), (40, 24))
    with pytest.raises(ClispError, match="never written"):
        with raw_band_writer(tmp_path / "r.dng", header) as write:
            write(0, np.zeros((16, 24), np.uint16))
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------------------
# option parsing
# ------------------------------------------------------------------------------------------

def test_option_parsing() -> None:
    assert memory_size("512M") == 512 * 2**20 and memory_size("2G") == 2 * 2**30
    assert memory_size("1.5GiB") == 3 * 2**29 and memory_size("800MB") == 800 * 2**20
    assert memory_size("1073741824") == 2**30
    for bad in ("lots", "12K", "-1G", "inf", "G"):
        with pytest.raises(argparse.ArgumentTypeError):
            memory_size(bad)
    assert image_size("23040x17280") == (23040, 17280)
    for bad in ("100", "0x5", "ax3", "1x2x3"):
        with pytest.raises(argparse.ArgumentTypeError):
            image_size(bad)


def test_threads_share_the_device_safely() -> None:
    """clisp.process from several threads at once (DEVICE_LOCK lets one at a time build and launch):
    every result equals the same call made alone."""
    from concurrent.futures import ThreadPoolExecutor
    raws = [make_raw(kind, shape=(150, 190), seed=seed) for kind in ("lms", "bayer") for seed in (1, 2)]
    alone = [clisp.process(raw, preset=preset, output="srgb16") for raw in raws for preset in ("fast", "quality")]
    with ThreadPoolExecutor(4) as pool:
        together = list(pool.map(lambda rp: clisp.process(rp[0], preset=rp[1], output="srgb16"),
                                 [(raw, preset) for raw in raws for preset in ("fast", "quality")]))
    for a, b in zip(alone, together):
        np.testing.assert_array_equal(a, b)


def test_staged_sink_touches_the_callers_array_and_copies_every_tile(monkeypatch):
    """A discrete device's in-memory sink (streaming.StagedSink): the caller's new array is faulted in
    by row bands on the host's threads from the first tile on (host_threads.touch), and every tile's
    staged result then lands in its place, nothing of the zeros left."""
    from clisp.engine import host_threads
    from clisp.engine.streaming import StagedSink
    from clisp.engine.tiling import Tile
    monkeypatch.setattr(host_threads, "MIN_BAND_BYTES", 1)
    monkeypatch.setattr(host_threads, "usable_cores", lambda: 4)
    started = []
    touch = host_threads.touch
    monkeypatch.setattr(host_threads, "touch", lambda a: started.append(touch(a)) or started[-1])

    class Staging:                       # HostStaging's interface, plain memory
        def take(self, nbytes):
            return np.empty(nbytes, np.uint8)

        def give(self, buffer):
            pass

    out = np.full((8, 6, 3), 7, dtype=np.uint16)
    sink = StagedSink(out, Staging())
    tiles = [Tile(0, 0, 8, 3), Tile(0, 3, 8, 3)]
    for i, tile in enumerate(tiles):
        view, _, _ = sink.target(tile)
        view[...] = 100 + i
        sink.done(tile)
    sink.close()
    assert len(started) == 1 and len(started[0]) == 4              # once, one band per core
    assert (out[:, :3] == 100).all() and (out[:, 3:] == 101).all()
