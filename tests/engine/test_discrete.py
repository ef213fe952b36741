"""The path a discrete GPU takes, run on this machine's device with its shared memory switched off
(Runtime.host_unified False) and its buffers not counted as host memory (conftest.discrete_gpu; on
a GPU, the device's own path): the whole mosaic uploaded once from a pinned staging buffer and the
windows gathered on the device, uploads and downloads on a second queue beside the kernels, a
download's buffer reused only after it (issue 41, items 2 and 5). Every output equals the
shared-memory path's, bit for bit: the same kernels run on the same pixels."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clisp.engine.executor import Pipeline, RESIDENT_SHARE, resident_policy
from clisp.engine.runtime import get_runtime
from clisp.engine.streaming import ArraySink, ArrayWindows
from clisp.pipeline import build_pipeline, process_file

from conftest import discrete_gpu
from test_streaming import band_plan, make_raw, unaligned


@pytest.fixture()
def discrete(monkeypatch: pytest.MonkeyPatch):
    """The runtime as a discrete GPU sees it (conftest.discrete_gpu): its second queue and staging
    buffers made anew and dropped after the test."""
    with discrete_gpu(monkeypatch, get_runtime()) as rt:
        yield rt


@pytest.mark.parametrize("kind, preset, tile", [("bayer", "fast", None), ("lms", "quality", 104),
                                                ("bayer", "quality", 152)])
def test_discrete_path_equals_shared_memory(kind: str, preset: str, tile: int | None, discrete) -> None:
    """Tiles of a given size (a discrete device's automatic plan of so small a raw is one tile):
    ``tile`` x ``tile`` squares, None bands of 52 rows."""
    raw = make_raw(kind, shape=(301, 517))
    pipeline = build_pipeline(raw, preset=preset, output="srgb16")
    plan = band_plan(pipeline, raw.shape, 52) if tile is None else pipeline.plan(raw.shape, raw.data.dtype, tile)
    assert len(plan.tiles) > 2
    rt = discrete
    uploads, gathers = [], []
    resident, gather = rt.resident_mosaic, rt.gather_window
    rt.resident_mosaic = lambda a: uploads.append(a.shape) or resident(a)
    rt.gather_window = lambda *a: gathers.append(a[1:3]) or gather(*a)
    try:
        out = np.zeros(raw.shape + (3,), pipeline.out_dtype)
        pipeline.stream(ArrayWindows(unaligned(raw.data)), ArraySink(out), plan)
    finally:
        del rt.resident_mosaic, rt.gather_window
    assert uploads == [raw.shape] and len(gathers) == len(plan.tiles)        # one upload, windows on the device
    assert rt.transfer_queue is not rt.queue
    rt.host_unified = True
    shared = np.zeros_like(out)
    pipeline.stream(ArrayWindows(unaligned(raw.data)), ArraySink(shared), plan)
    np.testing.assert_array_equal(out, shared)


def test_staging_is_reused_and_never_handed_out(discrete) -> None:
    """Three calls stage their mosaics and download their tiles through staging buffers: each buffer
    is pageable when first made (the mosaic's, one per tile in flight: StagedSink) and replaced by a
    pinned one when asked for again (HostStaging: pinned once reused, by the first call's later
    tiles or the second call); the third call makes none; the arrays returned are the caller's own
    (a later call never writes into an earlier result)."""
    raw = make_raw("bayer", shape=(200, 240))
    pipeline = build_pipeline(raw, preset="fast")
    rt = discrete
    made: list[tuple[int, bool]] = []
    new = rt.staging._new
    rt.staging._new = lambda n, pinned=False: made.append((n, pinned)) or new(n, pinned)
    try:
        first = pipeline.run(unaligned(raw.data), tile=64)
        by_first = len(made)
        kept = first.copy()
        second = pipeline.run(unaligned(raw.data[::-1].copy()), tile=64)
        by_second = len(made)
        pipeline.run(unaligned(raw.data), tile=64)
    finally:
        del rt.staging._new
    assert made[0] == (raw.data.nbytes, False)                 # the mosaic's: pageable the first time
    pinned = [n for n, p in made if p]
    assert pinned and len(made) == by_second and by_second - by_first <= 3   # the third call makes none
    assert sum(n for n, p in made if not p) <= raw.data.nbytes + 2 * made[1][0]   # one pageable set at most
    np.testing.assert_array_equal(first, kept)
    assert not np.array_equal(first, second)


def test_download_buffer_waits_for_its_copy(discrete) -> None:
    """A result buffer released after its download (on the transfer queue) makes the next
    acquirer's commands wait for that copy on the device: no host wait, no torn result."""
    rt = discrete
    src = rt.acquire(3, 64, 48)
    rt.cl.enqueue_copy(rt.queue, src.buffer, np.arange(64 * 48 * 3, dtype=np.float32))
    src.interleaved = True
    host = np.zeros((64, 48, 3), np.float32)
    event = rt.download_region(src, host, 0, 0, 64, 48)
    rt.release(src, after=event)
    assert id(src.buffer) in rt.pool.pending
    again = rt.acquire(3, 64, 48)
    assert again.buffer is src.buffer and id(src.buffer) not in rt.pool.pending
    event.wait()
    np.testing.assert_array_equal(host.ravel(), np.arange(64 * 48 * 3, dtype=np.float32))
    rt.release(again)


def test_uploads_wait_for_the_compute_queue(discrete, monkeypatch: pytest.MonkeyPatch) -> None:
    """An upload of the transfer queue, a table's or the resident mosaic's, waits for a marker of
    the compute queue: the pool hands a buffer out again once its kernels are enqueued, not done,
    and a copy beside them would overwrite what a kernel still reads."""
    rt = discrete
    cl = rt.cl
    seen = []
    copy = cl.enqueue_copy
    monkeypatch.setattr(cl, "enqueue_copy", lambda queue, *a, **k: seen.append((queue, k.get("wait_for"))) or
                        copy(queue, *a, **k))
    table = rt.upload(np.ones((4, 8), np.float32))
    mosaic = rt.resident_mosaic(unaligned(np.arange(64 * 48, dtype=np.uint16).reshape(64, 48)))
    assert [q for q, _ in seen] == [rt.transfer_queue] * 2
    for _, wait in seen:
        assert wait and wait[0].get_info(cl.event_info.COMMAND_QUEUE) == rt.queue
    rt.release(table)
    rt.release(mosaic)


def test_whole_process_on_the_discrete_path(tmp_path: Path, discrete) -> None:
    """process_file of an in-memory camera-style raw writes the same TIFF on both paths."""
    import tifffile
    raw = make_raw("lms", shape=(180, 260))
    raw.data = unaligned(raw.data)
    process_file(raw, tmp_path / "d.tif", tile=64, preset="quality")
    discrete.host_unified = True
    process_file(raw, tmp_path / "s.tif", tile=64, preset="quality")
    np.testing.assert_array_equal(tifffile.imread(tmp_path / "d.tif"), tifffile.imread(tmp_path / "s.tif"))


def test_resident_policy() -> None:
    """Shared memory: never staged (the reader thread, or for one tile the calling thread, gathers
    the windows); discrete: whenever the mosaic fits RESIDENT_SHARE of the device's memory."""
    from types import SimpleNamespace
    shared = SimpleNamespace(host_unified=True, device=SimpleNamespace(global_mem_size=2**34))
    gpu = SimpleNamespace(host_unified=False, device=SimpleNamespace(global_mem_size=2**34))
    assert not resident_policy(shared, 48 << 20, 1) and not resident_policy(shared, 48 << 20, 13)
    assert resident_policy(gpu, 48 << 20, 13) and not resident_policy(gpu, int(RESIDENT_SHARE * 2**34) + 1, 1)


def test_plans_per_device_kind(discrete) -> None:
    """A discrete device plans a 24 MP raw of the quality path as one window (GPU_TARGET_TILE_PIXELS,
    its memory permitting); a device sharing host memory as bands (TARGET_TILE_PIXELS, or more
    rows where the halo asks for them: tiling.HALO_ROWS_FACTOR)."""
    from clisp.engine.tiling import halo_target_pixels
    raw = make_raw("lms", shape=(64, 64))
    pipeline = build_pipeline(raw, preset="quality")
    gpu = pipeline.plan((4000, 6000), np.uint16, budget=8 * 2**30)
    discrete.host_unified = True
    cpu = pipeline.plan((4000, 6000), np.uint16, budget=8 * 2**30)
    assert len(gpu.tiles) == 1
    assert len(cpu.tiles) > 4 and np.prod(cpu.window_shape) <= 1.1 * halo_target_pixels(6000, pipeline.halo)


def test_band_buffers_are_pinned_and_reused_across_files(tmp_path: Path, discrete) -> None:
    """On a discrete device process_file's output bands come from the runtime's staging buffers and
    go back to them: a second file asks for the same ones again, which pins them (HostStaging), and a
    third takes them as they are (pinned memory is allocated once)."""
    first, second, third = staging_made_by_three_files(discrete, make_raw("bayer", shape=(160, 200)), tmp_path)
    assert first >= 2 and second == first and third == 0     # pageable, then pinned once reused, then reused


def test_file_windows_read_into_pinned_staging(tmp_path: Path, discrete) -> None:
    """A raw read from its file (FileWindows) on a discrete device: the windows are read into
    staging buffers (pinned), given back when the run ends, and a second file reuses them."""
    from clisp.io.rawfile import read_raw, write_raw
    write_raw(tmp_path / "r.dng", make_raw("bayer", shape=(200, 300)))
    raw = read_raw(tmp_path / "r.dng", lazy=True)
    first, second, third = staging_made_by_three_files(discrete, raw, tmp_path)
    # windows and bands: made once, pinned when asked for again, then reused. The reader thread's
    # windows come back when their tile finishes, so a file whose device ran late can hold one
    # window more than the one before (WindowPool.take never blocks): one new buffer, not a new set
    assert first > 2 and first <= second <= first + 1 and third <= 1
    discrete.host_unified = True
    process_file(raw, tmp_path / "s.tif", tile=64, preset="fast")
    import tifffile
    np.testing.assert_array_equal(tifffile.imread(tmp_path / "a.tif"), tifffile.imread(tmp_path / "s.tif"))


def staging_made_by_three_files(rt, raw, folder: Path) -> tuple[int, int, int]:
    """Staging buffers made while process_file writes ``raw`` three times (fast preset, 64 px tiles):
    (during the first file, during the second, during the third)."""
    made = []
    new = rt.staging._new
    rt.staging._new = lambda n, pinned=False: made.append(n) or new(n, pinned)
    counts = []
    try:
        for name in ("a.tif", "b.tif", "c.tif"):
            before = len(made)
            process_file(raw, folder / name, tile=64, preset="fast")
            counts.append(len(made) - before)
    finally:
        del rt.staging._new
    return counts[0], counts[1], counts[2]
