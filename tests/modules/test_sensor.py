"""The sensor corrections stage (clisp/modules/sensor: sensor.cl's sensor_screen, sensor_edges and
sensor_fix, sensor_shade.cl's sensor_shade) against their NumPy reference, tiled against whole, and
what they do to raws with and without defects (clisp.pipeline.corrections, the pipeline)."""
from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

from clisp.cfa import bayer_cfa, lms_cfa
from clisp.pipeline.corrections import only_isolated_clips, sensor_corrections
from clisp.engine.runtime import get_runtime
from clisp.engine.stage import Origin
from clisp.engine.tiling import gather_window
from clisp.io.opcodes import FixVignetteRadial, GainMap
from clisp.modules.sensor.stage import (FOUND, HALO, DefectTest, GainTerms, SensorCorrect, SensorShade, SmoothGain,
                                        cold_at_level, neighbour_tables)
from clisp.pipeline import build_pipeline
from clisp.sim import defects as sd
from clisp.sim.simulate import simulate
from tolerance import assert_close

H, W = 56, 72


def scene(h: int = H, w: int = W, seed: int = 0) -> np.ndarray:
    """A textured scene made in code: smooth gradients, stripes and a few sharp dots."""
    y, x = np.mgrid[0:h, 0:w] / np.array([h, w])[:, None, None]
    img = np.stack([0.2 + 0.5 * x, 0.3 + 0.2 * np.sin(9 * y), 0.25 + 0.2 * (x * y)], axis=-1)
    img[:, w // 3:w // 3 + 2] *= 1.8
    rng = np.random.default_rng(seed)
    img += 0.05 * rng.random((h, w, 1))
    return img


def stage_with_everything(cfa, raw_dtype=np.uint16, rng=np.random.default_rng(1)) -> tuple[SensorCorrect, np.ndarray]:
    x = (300 + 40 * rng.standard_normal((H, W))).clip(0, 1023)
    x[10, 11], x[30, 40], x[20, 20], x[1, 5] = 1000, 64, 900, 1010         # hot, dead, hot, hot at the edge
    x = x.astype(raw_dtype) if raw_dtype == np.float32 else np.round(x).astype(np.uint16)
    mask = np.zeros((H, W), np.uint16)
    mask[5, 5] = mask[40, 41] = 1
    dark = (64 + rng.uniform(0, 5, (H, W))).astype(np.float32)
    flat = (1 + 0.02 * rng.standard_normal((H, W))).astype(np.float32)
    gm = GainMap((1, 0, H, W), 0, 1, 2, 1, (0.5, 0.5), (0.0, 0.0), (1 + rng.uniform(0, 0.5, (3, 3, 1))).astype(np.float32),
                 list_no=2, image=(H, W))
    vr = FixVignetteRadial((0.3, 0.1, 0, 0, 0), (0.5, 0.5), list_no=1, image=(H, W))
    ny, nx = SmoothGain.nodes((H, W))
    grid = (1 + 0.1 * rng.random((3, len(ny), len(nx)))).astype(np.float32)
    test = DefectTest((1e-3,) * 3, (1e-5,) * 3, (1.0, 1.2, 2.0))
    return SensorCorrect(cfa, np.full(3, 64.0), 1023.0, test, mask, dark, flat, GainTerms([gm, vr]),
                         SmoothGain(grid)), x


@pytest.mark.parametrize("cfa", [bayer_cfa(), bayer_cfa("GBRG"), lms_cfa()], ids=lambda c: c.name)
@pytest.mark.parametrize("dtype", [np.uint16, np.float32], ids=["uint16", "float32"])
def test_sensor_correct_kernel_equals_reference(cfa, dtype):
    """sensor.cl (screen, compact, edges, fix) against the reference: every step on (the screen's
    scalar path), then without the gain terms (its vector path, with the dark frame, flat and mask);
    whole image and a window."""
    rt = get_runtime()
    everything, x = stage_with_everything(cfa, dtype)
    total = 0
    for stage, origin, shape in ((stage, origin, shape)
                                 for stage in (everything, dataclasses.replace(everything, terms=None, smooth=None))
                                 for origin, shape in ((Origin(-HALO, -HALO, (H, W)), (H + 2 * HALO, W + 2 * HALO)),
                                                       (Origin(8 - HALO, 12 - HALO, (H, W)), (30, 36)))):
        window = gather_window(x, origin[0], origin[1], shape[0], shape[1], cfa.period)
        before = rt.read_counters().get(FOUND, 0)
        expected, found = stage.correct(window, origin)
        got = rt.download(stage.enqueue(rt, rt.upload(window), origin)).reshape(expected.shape)
        assert_close(got, expected, f"sensor_correct {cfa.name} at {tuple(origin)}")
        assert rt.read_counters()[FOUND] - before == int(found.sum())
        total += int(found.sum())
    assert total >= 1


def test_reference_quiet_outside_the_image():
    """A window wholly outside the image (a tile's margin past the edge): no neighbour is inside, so
    nothing is tested, and NumPy warns of nothing (an All-NaN slice before)."""
    stage, _ = stage_with_everything(bayer_cfa())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = stage.reference(np.full((12, 14), 300.0), Origin(H + 4, W + 4, (H, W)))
    assert out.shape == (6, 8) and np.isfinite(out).all()


def test_screen_misses_nothing_the_test_finds():
    """A noisy textured raw at gain 1 (many candidates): the screened kernel equals the full test, with
    the raw's noise model and with one whose floor dominates (the screen's cold test then takes the
    noise at its lowest neighbour's level: cold_at_level)."""
    rt = get_runtime()
    for cfa in ("bayer", "lms"):
        sim = simulate(scene(96, 128), cfa=cfa, gain=1, seed=4, defects=sd.SensorDefects(hot=0.003, dead=0.003, seed=2))
        pre = sensor_corrections(sim.raw).pre
        a = np.asarray(pre.test.noise_a)
        floor = dataclasses.replace(pre.test, noise_b=tuple(np.maximum(pre.test.noise_b, (3.5 * a) ** 2)))
        assert not cold_at_level(a[0], pre.test.noise_b[0]) and cold_at_level(a[0], floor.noise_b[0])
        h, w = sim.raw.shape
        origin = Origin(-HALO, -HALO, (h, w))
        window = gather_window(sim.raw.data, -HALO, -HALO, h + 2 * HALO, w + 2 * HALO, sim.raw.cfa.period)
        for stage in (pre, dataclasses.replace(pre, test=floor)):
            expected, found = stage.correct(window, origin)
            got = rt.download(stage.enqueue(rt, rt.upload(window), origin)).reshape(expected.shape)
            assert_close(got, expected, f"screened sensor_correct, {cfa}")
            assert found.sum() > 0.5 * sd.bad_sites(sd.SensorDefects(hot=0.003, dead=0.003, seed=2), (h, w)).sum()


def test_sensor_shade_kernel_equals_reference():
    rt = get_runtime()
    ny, nx = SmoothGain.nodes((40, 60))
    grid = (1 + np.random.default_rng(2).random((3, len(ny), len(nx)))).astype(np.float32)
    m = np.array([[1.8, -0.5, -0.3], [-0.3, 1.4, -0.1], [-0.1, -0.3, 1.4]])
    for scale in (1, 2):
        stage = SensorShade(SmoothGain(grid), m, scale)
        x = np.random.default_rng(3).random((3, 20, 30)).astype(np.float32)
        ref = stage.reference(np.moveaxis(x, 0, -1), (5, 7))
        got = rt.download(stage.enqueue(rt, rt.upload(x), (5, 7)))
        assert_close(np.moveaxis(got.reshape(3, 20, 30), 0, -1), ref, f"sensor_shade scale {scale}")


def test_neighbour_tables_are_same_channel():
    for cfa in (bayer_cfa(), lms_cfa(), lms_cfa((1, 2))):
        nb, n, pairs, pn = neighbour_tables(cfa)
        p = cfa.period
        for k in range(p * p):
            ky, kx = divmod(k, p)
            for dy, dx in nb[k, :n[k]]:
                assert cfa.pattern[(ky + dy) % p, (kx + dx) % p] == cfa.pattern[ky, kx]
            for a, b in pairs[k, :pn[k]]:
                assert tuple(nb[k, a]) == tuple(-nb[k, b])


@pytest.fixture(scope="module")
def defective():
    """A Bayer raw with every defect, its frames, and the defect-free raw of the same scene."""
    d = sd.SensorDefects(hot=0.002, dead=0.001, dark_current=50.0, exposure_time=1.0, shading=0.6, prnu=0.01, seed=3)
    sim = simulate(scene(64, 96), cfa="bayer", gain=4, seed=5, defects=d)
    sim.raw.metadata["opcodes"] = sd.gain_map_opcodes(d, sim.raw.cfa, sim.raw.shape)
    clean = simulate(scene(64, 96), cfa="bayer", gain=4, seed=5)
    return d, sim, clean


def test_tiled_equals_whole(defective):
    """Every correction on (search, dark, flat, GainMap smooth gain, highlights and denoiser between):
    tiles of 32 px give the whole image's output."""
    d, sim, _ = defective
    dark = sd.frames(sim.raw, d, "dark", 2, 4.0, 10)
    for options in ({"dark": dark}, {"flat": sd.frames(sim.raw, d, "flat", 2, 4.0, 20)}, {}):
        pipe = build_pipeline(sim.raw, preset="balanced", **options)
        names = [s.name for s in pipe.stages]
        assert names[0] == "sensor" and "sensor_shade" in names
        whole = pipe.run(sim.raw.data)
        tiled = pipe.run(sim.raw.data, tile=32)
        assert_close(tiled, whole, f"tiled = whole with {list(options) or 'the GainMap'}")


def test_corrections_bring_the_raw_back(defective):
    """Dark frames, flats and the search: the corrected output is closer to the truth than the raw
    left alone, and the auto search found most of the hot and dead pixels."""
    from clisp.metrics import psnr
    d, sim, clean = defective
    off = build_pipeline(sim.raw, preset="fast", bad_pixels="off", opcodes=False).run(sim.raw.data)
    pipe = build_pipeline(sim.raw, preset="fast", bad_pixels="auto", dark=sd.frames(sim.raw, d, "dark", 4, 4.0, 10),
                          flat=sd.frames(sim.raw, d, "flat", 4, 4.0, 20))
    fixed = pipe.run(sim.raw.data)
    assert psnr(fixed, clean.truth) > psnr(off, clean.truth) + 3
    text = pipe.corrections.explain(pipe.stats)
    assert "dark: 4 frames averaged, scaled by the exposure times" in text
    assert "the flat replaces the DNG's 4 gain opcodes" in text
    assert "the auto test found and replaced" in text


def test_explain_counts_each_run_its_own_pixels():
    """Two raws of one camera and settings in one process share the memoised schedule (and its
    sensor stage object): each run's --explain count is its own, the count a fresh process gives."""
    from clisp.engine.executor import SCHEDULES

    def found_in(raw) -> str:
        pipe = build_pipeline(raw, preset="balanced")
        pipe.run(raw.data)
        return [line for line in pipe.corrections.explain(pipe.stats).splitlines() if "found" in line][0]

    raws = [simulate(scene(48, 64), cfa="bayer", gain=2, seed=5, defects=sd.SensorDefects(hot=hot, seed=s)).raw
            for hot, s in ((0.004, 1), (0.01, 2))]
    SCHEDULES.clear()
    alone = found_in(raws[1])
    SCHEDULES.clear()
    first, second = found_in(raws[0]), found_in(raws[1])
    assert second == alone and first != second, (first, second, alone)


def test_no_false_corrections_on_a_smooth_raw_at_gain_64():
    """A defect-free raw of a smooth scene at the highest gain: the search changes nothing."""
    raw = simulate(scene(64, 96) * 0 + np.linspace(0.05, 0.8, 96)[None, :, None], cfa="lms", gain=64, seed=8).raw
    on = build_pipeline(raw, preset="fast", bad_pixels="auto").run(raw.data)
    off = build_pipeline(raw, preset="fast", bad_pixels="off").run(raw.data)
    assert_close(on, off, "the search on a defect-free gain-64 raw")


@pytest.mark.parametrize("cfa", ["bayer", "lms"])
def test_an_edge_beside_the_border_is_no_defect(cfa):
    """A defect-free raw whose last two rows are dark under a bright area: the mirrored margin below
    the image puts bright copies two rows under the dark ones, which, tested with only the dark
    neighbours inside, were taken for hot pixels, and the demosaic and denoiser carried the change
    40 rows up (Kodak 7, Bayer gain 64: 0.087). Only pixels of the image are tested; the margin is the
    corrected image, padded: the search changes nothing, whole or tiled."""
    img = np.full((64, 96, 3), 0.7)
    img[-2:] = 0.04
    img[:, :3] = 0.04                                    # and the same at the left edge
    raw = simulate(img, cfa=cfa, gain=1, seed=3, optics="none").raw
    off = build_pipeline(raw, bad_pixels="off").run(raw.data)
    for tile in (None, 32):
        on = build_pipeline(raw, bad_pixels="auto").run(raw.data, tile=tile)
        assert_close(on, off, f"the search beside an edge at the border, {cfa}, tile {tile}")


def test_fast_preset_searches_only_when_asked(defective):
    _, sim, _ = defective
    assert build_pipeline(sim.raw, preset="fast", opcodes=False).corrections.pre is None
    assert build_pipeline(sim.raw, preset="fast", bad_pixels="auto", opcodes=False).corrections.pre.test is not None
    assert build_pipeline(sim.raw, preset="balanced", opcodes=False).corrections.pre.test is not None


def test_frames_read_once_a_process(tmp_path, defective, monkeypatch):
    """Two raws of one process with the same dark and flat files: the frames are read for the first
    only (the second's masters are the first's); a frame file written again is read again."""
    import os
    import clisp.io.rawfile as rawfile
    d, sim, _ = defective
    paths = {}
    for kind in ("dark", "flat"):
        paths[kind] = [str(tmp_path / f"{kind}{i}.dng") for i in range(2)]
        for path, frame in zip(paths[kind], sd.frames(sim.raw, d, kind, 2, 4.0, 30)):
            rawfile.write_raw(path, frame)
    import clisp.pipeline.corrections as corrections
    reads = []
    real = rawfile.read_raw
    monkeypatch.setattr(corrections, "read_raw", lambda path, lazy=False: reads.append(path) or real(path, lazy))
    first = sensor_corrections(sim.raw, dark=paths["dark"], flat=paths["flat"])
    assert len(reads) == 4
    second = sensor_corrections(sim.raw, dark=paths["dark"], flat=paths["flat"])
    assert len(reads) == 4 and second.notes == first.notes
    assert np.array_equal(second.pre.dark, first.pre.dark) and np.array_equal(second.pre.flat, first.pre.flat)
    os.utime(paths["dark"][1], ns=(1, 1))                    # "written again": another modification time
    sensor_corrections(sim.raw, dark=paths["dark"], flat=paths["flat"])
    assert reads[4:] == paths["dark"]


def test_map_file_used_as_given(tmp_path, defective):
    from clisp.pipeline.corrections import read_bad_pixel_map, write_bad_pixel_map
    d, sim, _ = defective
    truth = sd.bad_sites(d, sim.raw.shape)
    write_bad_pixel_map(tmp_path / "map.txt", truth)
    assert np.array_equal(read_bad_pixel_map(str(tmp_path / "map.txt"), sim.raw.shape), truth)
    corr = sensor_corrections(sim.raw, bad_pixels=str(tmp_path / "map.txt"), opcodes=False)
    assert corr.pre.test is None and int(corr.pre.mask.sum()) == int(truth.sum())


def test_a_map_array_of_another_shape_is_refused(defective):
    """A map given in memory (``bad_pixels=`` an H x W bool array) must match the raw; a raw with
    no map, frame or opcode gets no mask at all (no H x W pass)."""
    from clisp.errors import ClispError
    _, sim, _ = defective
    h, w = sim.raw.shape
    with pytest.raises(ClispError, match=f"bad pixel map of {w - 1}x{h} for a raw of {w}x{h}"):
        sensor_corrections(sim.raw, bad_pixels=np.zeros((h, w - 1), bool), opcodes=False)
    given = np.zeros((h, w), bool)
    given[3, 5] = True
    assert int(sensor_corrections(sim.raw, bad_pixels=given, opcodes=False).pre.mask.sum()) == 1
    assert sensor_corrections(sim.raw, opcodes=False).pre.mask is None


def test_the_schedule_pickles_after_a_run():
    """The memo keys pickle a schedule's stages, which every call of one camera and settings reuses:
    the device state a run leaves on the sensor stage must not stop them (the metering kept on disk
    was skipped from the second call of a process on)."""
    import pickle
    from clisp.engine.executor import _kept_metering_name
    raw = simulate(0.4 * scene(), cfa="bayer", gain=2, seed=1).raw
    build_pipeline(raw, preset="quality").run(raw.data)
    schedule = build_pipeline(raw, preset="quality").schedule()
    stage = next(st for st in schedule if isinstance(st, SensorCorrect))
    assert stage._devices                                     # the run left its state on the shared stage
    assert _kept_metering_name(get_runtime(), schedule, raw.data.dtype) is not None
    again = pickle.loads(pickle.dumps(stage))
    assert again._devices == {} and again.test == stage.test


def test_dark_frame_scaled_by_exposure_time(defective):
    d, sim, _ = defective
    half = sd.frames(sim.raw, dataclasses.replace(d, exposure_time=0.5), "dark", 1, 4.0, 30)[0]
    corr = sensor_corrections(sim.raw, dark=[half], opcodes=False)
    expected = sd.expected_dark(d, sim.raw.shape, 4.0, sd.NoiseModel())
    lit = expected - 64 > 5
    ratio = (corr.pre.dark[lit] - 64) / (expected[lit] - 64)
    assert abs(float(np.median(ratio)) - 1.0) < 0.1                      # the half-time frame, doubled


def test_hot_pixels_are_not_clipped_light():
    raw = simulate(0.4 * scene(), cfa="bayer", gain=2, seed=1, defects=sd.SensorDefects(hot=0.002, hot_level=1.5, seed=4)).raw
    pre = sensor_corrections(raw).pre
    assert only_isolated_clips(raw, pre)
    assert not only_isolated_clips(raw, None)
    blob = raw.data.copy()
    blob[20:26, 30:36] = 1023
    assert not only_isolated_clips(dataclasses.replace(raw, data=blob), pre)
    assert build_pipeline(raw).describe().count("highlights") == 0
    assert "highlights" in build_pipeline(raw, bad_pixels="off").describe()


def test_cli_names_unapplied_opcodes(tmp_path, capfd):
    from clisp.app.cli import main
    from clisp.io.opcodes import OtherOpcode
    from clisp.io.rawfile import write_raw
    sim = simulate(scene(), cfa="bayer", gain=2, seed=1)
    sim.raw.metadata["opcodes"] = [OtherOpcode(1, bytes(8), list_no=3), OtherOpcode(1, bytes(8), list_no=3)]
    write_raw(tmp_path / "r.dng", sim.raw)
    assert main(["process", str(tmp_path / "r.dng"), "-o", str(tmp_path / "o.exr"), "--preset", "fast",
                 "--bad-pixels", "auto", "--explain"]) == 0
    out, err = capfd.readouterr()
    assert err.count("DNG opcode WarpRectilinear (OpcodeList3) not applied") == 1
    assert "sensor: bad pixels auto" in out


def test_sensor_modules_load_only_for_raws_that_need_them(tmp_path):
    """Start-up is part of every command's time: a raw without opcodes, read and given no correction
    (the fast preset's --bad-pixels off), loads neither the sensor stage, the opcodes nor the defect
    simulator; the auto search loads the stage, not the opcodes."""
    import subprocess
    import sys
    code = f"""import sys, numpy as np, clisp.app.cli
from clisp.io.rawfile import read_raw, write_raw
from clisp.pipeline.corrections import sensor_corrections
from clisp.sim.simulate import simulate
write_raw({str(tmp_path / 'a.dng')!r}, simulate(np.full((16, 16, 3), 0.3), cfa='bayer', gain=1).raw)
raw = read_raw({str(tmp_path / 'a.dng')!r})
mods = ('clisp.modules.sensor.stage', 'clisp.io.opcodes', 'clisp.sim.defects')
print(','.join(m for m in mods if m in sys.modules), end=';')
assert sensor_corrections(raw, bad_pixels='off').pre is None
print(','.join(m for m in mods if m in sys.modules), end=';')
assert sensor_corrections(raw).pre is not None
print(','.join(m for m in mods if m in sys.modules))"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == ";;clisp.modules.sensor.stage", out


@pytest.mark.parametrize("cfa", [bayer_cfa(), lms_cfa()], ids=lambda c: c.name)
def test_dead_pixels_are_told_from_dark_texture_by_their_ratio(cfa):
    """A dead pixel reads black: it is found though its 4 nearest pixels are darker than its pair's
    (the support test alone kept it, as a dark detail). A live pixel darker than all its same-channel
    neighbours but above RHO of them (0.6: a dark point through the lens) is left alone though nothing
    near it is darker. Kernel equals reference."""
    rt = get_runtime()
    h, w = 40, 48
    x = np.full((h, w), 600, np.uint16)
    x[20, 20] = 66                                     # dead, black 64
    for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1)):
        x[20 + dy, 20 + dx] = 300                      # its 4 nearest pixels darker than its pair's
    x[10, 12] = 64 + int(0.6 * (600 - 64))             # a live dark point, unsupported
    stage = SensorCorrect(cfa, np.full(3, 64.0), 1023.0, DefectTest((1e-4,) * 3, (1e-6,) * 3, (1.0, 1.0, 1.0)))
    origin = Origin(-HALO, -HALO, (h, w))
    window = gather_window(x, origin[0], origin[1], h + 2 * HALO, w + 2 * HALO, cfa.period)
    expected, found = stage.correct(window, origin)
    got = rt.download(stage.enqueue(rt, rt.upload(window), origin)).reshape(expected.shape)
    assert found[20, 20] and not found[10, 12]
    assert found.sum() == 1
    assert_close(got, expected, f"sensor_correct {cfa.name}, a dead pixel and a dark point")


@pytest.mark.parametrize("cfa", [bayer_cfa(), lms_cfa()], ids=lambda c: c.name)
def test_a_dead_pixel_reads_black(cfa):
    """A live pixel far below RHO of its same-channel neighbours (0.05 of the range on a ground at 0.3:
    the LMS S channel's dark details, whose neighbours lie 2-4 px away) but well above black in the
    raw's floor noise is a detail, left alone; a pixel beside it that reads black is dead. Kernel
    equals reference."""
    rt = get_runtime()
    h, w = 40, 48
    x = np.full((h, w), 64 + int(0.3 * 959), np.uint16)
    x[20, 20] = 64 + int(0.05 * 959)                   # live: 0.05, far above 4.5 floor sigmas (0.0055)
    x[12, 28] = 65                                     # dead: black 64 and a DN of noise
    stage = SensorCorrect(cfa, np.full(3, 64.0), 1023.0, DefectTest((1e-4,) * 3, (1e-6,) * 3, (1.0, 1.0, 1.0)))
    assert 0.05 < stage.test.rho * 0.3                 # the ratio test alone took it for dead
    origin = Origin(-HALO, -HALO, (h, w))
    window = gather_window(x, origin[0], origin[1], h + 2 * HALO, w + 2 * HALO, cfa.period)
    expected, found = stage.correct(window, origin)
    got = rt.download(stage.enqueue(rt, rt.upload(window), origin)).reshape(expected.shape)
    assert found[12, 28] and not found[20, 20] and found.sum() == 1
    assert_close(got, expected, f"sensor_correct {cfa.name}, a dark detail and a dead pixel")

@pytest.mark.parametrize("cfa", [bayer_cfa(), lms_cfa()], ids=lambda c: c.name)
def test_kernel_equals_reference_beside_known_bad_pixels_and_past_the_edge(cfa):
    """A hot and a dead pixel 2 px from a brighter / darker known bad one (sensor_fix leaves that
    neighbour out, so the screen must pass them on), and a window 10-12 px past the image (its
    mirrored margin, which the edges' list leaves out beyond RADIUS): kernel equals reference."""
    rt = get_runtime()
    h, w = 40, 48
    x = np.full((h, w), 300, np.uint16)
    x[20, 20], x[20, 22], x[10, 10], x[10, 12] = 800, 1000, 66, 64   # a dead pixel reads black
    x[1, 30] = 900                                     # hot, within RADIUS of the top edge
    mask = np.zeros((h, w), np.uint16)
    mask[20, 22] = mask[10, 12] = mask[0, 5] = 1
    stage = SensorCorrect(cfa, np.full(3, 64.0), 1023.0, DefectTest((1e-4,) * 3, (1e-6,) * 3, (1.0, 1.0, 1.0)), mask)
    for origin, shape in ((Origin(-HALO, -HALO, (h, w)), (h + 2 * HALO, w + 2 * HALO)),
                          (Origin(-HALO - 12, -HALO - 10, (h, w)), (h + 2 * HALO + 24, w + 2 * HALO + 21))):
        window = gather_window(x, origin[0], origin[1], shape[0], shape[1], cfa.period)
        expected, found = stage.correct(window, origin)
        got = rt.download(stage.enqueue(rt, rt.upload(window), origin)).reshape(expected.shape)
        assert found[20 - origin[0] - HALO, 20 - origin[1] - HALO] and found[10 - origin[0] - HALO, 10 - origin[1] - HALO]
        assert_close(got, expected, f"sensor_correct {cfa.name} at {tuple(origin)}")


@pytest.mark.parametrize("cfa", [bayer_cfa(), lms_cfa()], ids=lambda c: c.name)
def test_a_map_alone_replaces_its_pixels_beside_the_edge(cfa):
    """A map without the search (``--bad-pixels MAP``): its pixels within RADIUS of the image's edge
    are replaced on the device as in the reference (the edges' list once came with the search only,
    and the kernel left them as read)."""
    rt = get_runtime()
    h, w = 40, 48
    x = np.full((h, w), 300, np.uint16)
    mask = np.zeros((h, w), np.uint16)
    for y, xx in ((0, 9), (1, 20), (h - 1, 30), (17, 0), (22, w - 2), (h - 2, w - 1), (20, 24)):
        x[y, xx], mask[y, xx] = 1000, 1
    stage = SensorCorrect(cfa, np.full(3, 64.0), 1023.0, None, mask)
    origin = Origin(-HALO, -HALO, (h, w))
    window = gather_window(x, origin[0], origin[1], h + 2 * HALO, w + 2 * HALO, cfa.period)
    expected, _ = stage.correct(window, origin)
    got = rt.download(stage.enqueue(rt, rt.upload(window), origin)).reshape(expected.shape)
    assert_close(got, expected, f"sensor_correct {cfa.name}, a map alone")
    assert got.max() < 0.5 * (1000 - 64) / (1023 - 64) + expected.min()


@pytest.mark.parametrize("cfa", [bayer_cfa(), lms_cfa()], ids=lambda c: c.name)
def test_a_dead_pixel_in_the_shadows_is_found_within_its_noise(cfa):
    """A dead pixel on a ground at 0.05 of the range whose noise (a gain-16 sensor's) puts it 5.2
    sigmas below its neighbours: over K_COLD (the ratio test keeps texture out) though under K, the
    hot pixels' margin. Kernel equals reference."""
    rt = get_runtime()
    h, w = 40, 48
    x = np.full((h, w), 64 + 48, np.uint16)            # 0.05 of the range (black 64, white 1023)
    x[20, 20] = 64                                     # dead: reads black
    noise = DefectTest((1.82e-3,) * 3, (1e-6,) * 3, (1.0, 1.0, 1.0))
    sigma = np.sqrt(1.82e-3 * 0.05 + 1e-6)
    assert noise.k_cold < 0.05 / sigma < noise.k
    stage = SensorCorrect(cfa, np.full(3, 64.0), 1023.0, noise)
    origin = Origin(-HALO, -HALO, (h, w))
    window = gather_window(x, origin[0], origin[1], h + 2 * HALO, w + 2 * HALO, cfa.period)
    expected, found = stage.correct(window, origin)
    got = rt.download(stage.enqueue(rt, rt.upload(window), origin)).reshape(expected.shape)
    assert found[20, 20] and found.sum() == 1
    assert_close(got, expected, f"sensor_correct {cfa.name}, a dead pixel in the shadows")


@pytest.mark.parametrize("cfa", [bayer_cfa(), lms_cfa()], ids=lambda c: c.name)
def test_a_hot_pixels_margin_follows_its_ground(cfa):
    """A quiet sensor (gain 1): a one-pixel detail at 1.3 times its brighter ground (0.3, excess
    0.09: far over K noise sigmas, and no neighbour lit) is texture, left alone (HOT_SLOPE: it must be
    twice the ground, at most HOT_CAP over it); a warm pixel of 0.05 over a ground of 0.02 and a hot
    one of 0.3 over a bright ground (0.6) are found. Kernel equals reference."""
    rt = get_runtime()
    h, w = 48, 64
    black, span = 64.0, 959.0
    level = np.full((h, w), 0.3)
    level[:, 32:] = 0.6
    level[:16, :] = 0.02
    level[8, 12] += 0.05                               # warm, on a dark ground
    level[30, 12] *= 1.3                               # a texture's one-pixel detail
    level[30, 44] += 0.3                               # hot, on a bright ground
    x = np.round(black + span * level).astype(np.uint16)
    quiet = DefectTest((1e-5,) * 3, (1e-7,) * 3, (1.0, 1.0, 1.0))
    assert 0.09 > quiet.k * np.sqrt(1e-5 * 0.3 + 1e-7) and quiet.hot_slope * 0.3 > 0.09
    stage = SensorCorrect(cfa, np.full(3, black), black + span, quiet)
    origin = Origin(-HALO, -HALO, (h, w))
    window = gather_window(x, origin[0], origin[1], h + 2 * HALO, w + 2 * HALO, cfa.period)
    expected, found = stage.correct(window, origin)
    got = rt.download(stage.enqueue(rt, rt.upload(window), origin)).reshape(expected.shape)
    assert_close(got, expected, f"sensor_correct {cfa.name}, a margin that follows the ground")
    assert found[8, 12] and found[30, 44] and not found[30, 12]
    assert found.sum() == 2


@pytest.mark.parametrize("cfa", ["bayer", "lms"])
def test_a_map_of_the_searchs_finds_replaces_them_alike(cfa):
    """The pixels the search finds, given back as a map (no search): the same replacement, on the
    device too. A map's replacement takes its colour difference in the raw's white-balanced units
    as the search's does (it once took them unbalanced: the LMS camera's S pixels, whose raw level
    is a third of L's, got L's detail three times over)."""
    rt = get_runtime()
    sim = simulate(scene(64, 96), cfa=cfa, gain=1, seed=3, defects=sd.SensorDefects(hot=0.004, dead=0.004, seed=5))
    h, w = sim.raw.shape
    origin = Origin(-HALO, -HALO, (h, w))
    window = gather_window(sim.raw.data, -HALO, -HALO, h + 2 * HALO, w + 2 * HALO, sim.raw.cfa.period)
    searched, found = sensor_corrections(sim.raw).pre.correct(window, origin)
    assert found.sum() >= 20
    given = sensor_corrections(sim.raw, bad_pixels=found).pre
    assert given.test is None
    expected, _ = given.correct(window, origin)
    assert_close(expected, searched, f"a map of the search's finds, {cfa}")
    got = rt.download(given.enqueue(rt, rt.upload(window), origin)).reshape(expected.shape)
    assert_close(got, expected, f"sensor_correct, a map alone, {cfa}")
