"""--half-size (clisp.modules.half_size, issue 31 item 3): the binning's rule, its kernel against
its reference (Bayer and LMS, fused or not), tiled = whole through the executor's downscale, the
output's shape with a crop and a camera rotation, a flat grey raw giving grey, the streamed file
path, and the options it refuses.

Comparisons use tests/tolerance.py's rule; 16-bit codes may be one code off where the encoded value
lies within the sRGB polynomial's error of a half code (as test_kernels' tone curve)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import clisp
from clisp.cfa import bayer_cfa, cfa_from_name, lms_cfa
from clisp.errors import ClispError
from clisp.io.imageio import read_image
from clisp.io.rawimage import RawImage
from clisp.modules.colour.stage import ColourMatrix, ToneCurve
from clisp.modules.half_size.stage import HalfSize, phase_weights, window_radius
from clisp.modules.highlights.stage import HighlightClamp
from clisp.engine.stage import Stage, image_extent
from clisp.pipeline import build_pipeline, process_file
from clisp.sim.colorimetry import B_BAYER, P_LMS, WB_BAYER, WB_LMS
from clisp.sim.simulate import simulate
from tolerance import assert_close

CFAS = ["bayer-rggb", "bayer-gbrg", "lms", "lms@1,2"]


def make_raw(kind: str, shape: tuple[int, int] = (97, 131), seed: int = 5, dtype: type = np.uint16) -> RawImage:
    """Random raw in DN (odd sides: the last output row and column bin mirrored padding)."""
    cfa = cfa_from_name(kind)
    matrix, wb = (P_LMS, WB_LMS) if cfa.kind == "lms" else (B_BAYER, WB_BAYER)
    rng = np.random.default_rng(seed)
    data = rng.integers(64, 1024, size=shape).astype(dtype)
    return RawImage(data=data, cfa=cfa, black_level=np.array([64.0, 65.0, 66.0]), white_level=1023.0,
                    wb=wb, colour_matrix=matrix, exposure=1.0)


def planes(out: np.ndarray) -> np.ndarray:
    return np.moveaxis(out, 0, -1)


# ------------------------------------------------------------------------------------------
# the rule
# ------------------------------------------------------------------------------------------

def test_bayer_cell_gives_its_r_the_mean_of_its_g_and_its_b() -> None:
    """Bayer: each 2x2 cell is one pixel (its R, the mean of its two G, its B; normalised and
    white-balanced), nothing from the neighbouring cells; GBRG read at its own phase."""
    cfa = bayer_cfa("GBRG")                     # G B / R G
    stage = HalfSize(cfa, np.array([10.0, 20.0, 30.0]), np.array([2.0, 1.0, 0.5]))
    assert window_radius(cfa) == stage.halo == 0 and stage.downscale == 2
    x = np.array([[120.0, 230.0, 0.0, 0.0],
                  [310.0, 140.0, 0.0, 0.0]])
    out = stage.reference(x, (0, 0))
    assert out.shape == (1, 2, 3)
    assert out[0, 0].tolist() == [(310 - 10) * 2.0, (130 - 20) * 1.0, (230 - 30) * 0.5]
    assert out[0, 1].tolist() == [-20.0, -20.0, -15.0]                   # only its own cell


def test_lms_window_is_4x4_and_holds_every_channel() -> None:
    """LMS: r = 1, the 4x4 window around each block holds 8 L, 6 M, 2 S at every block phase, and
    each channel's weights are a plain mean over its samples there (a box binning)."""
    for cfa in (lms_cfa(), lms_cfa((1, 2)), lms_cfa((3, 3))):
        assert window_radius(cfa) == 1
        w = phase_weights(cfa, 1)
        assert w.shape == (2, 2, 3, 4, 4)
        counts = (w > 0).sum(axis=(3, 4))
        assert (counts == np.array([8, 6, 2])).all()
        np.testing.assert_allclose(w.sum(axis=(3, 4)), 1.0)
    for phase in ("RGGB", "GRBG", "GBRG", "BGGR"):
        assert window_radius(bayer_cfa(phase)) == 0


@pytest.mark.parametrize("kind", CFAS)
def test_per_channel_constant_mosaic_gives_those_constants(kind: str) -> None:
    """A mosaic whose every channel is a constant comes out as those constants (normalised), at
    every pixel and every origin: each output pixel sees each channel."""
    cfa = cfa_from_name(kind)
    stage = HalfSize(cfa, np.zeros(3), np.ones(3) / 1000.0)
    r = stage.halo
    levels = np.array([300.0, 500.0, 900.0])
    for origin in [(-r, -r), (2 - r, 6 - r)]:
        x = levels[cfa.channel_map(20 + 2 * r, 24 + 2 * r, origin)]
        out = stage.reference(x, origin)
        assert out.shape == (10, 12, 3)
        np.testing.assert_allclose(out, np.broadcast_to(levels / 1000.0, out.shape), rtol=0, atol=1e-12)


# ------------------------------------------------------------------------------------------
# kernel = reference
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("kind", CFAS)
@pytest.mark.parametrize("dtype", [np.uint16, np.float32])
def test_kernel_equals_reference(rt, kind: str, dtype: type) -> None:
    """The kernel against the reference at several window origins (block phases), planar."""
    cfa = cfa_from_name(kind)
    stage = HalfSize(cfa, np.array([60.0, 64.0, 70.0]), np.array([1.1, 1.0, 1.7]) / 900.0)
    r = stage.halo
    x = np.random.default_rng(1).integers(0, 1000, (2 * 37 + 2 * r, 2 * 53 + 2 * r)).astype(dtype)
    for origin in [(-r, -r), (6 - r, 2 - r), (-4 - r, 10 - r)]:
        src = rt.upload(x)
        dst = stage.enqueue(rt, src, origin)
        assert (dst.height, dst.width, dst.interleaved) == (37, 53, False)
        assert_close(planes(rt.download(dst)), stage.reference(x, origin), f"{kind} {origin}")
        rt.release(src)
        rt.release(dst)


@pytest.mark.parametrize("kind", ["bayer-grbg", "lms"])
@pytest.mark.parametrize("tone", [None, "float", "uint16"])
def test_fused_clamp_matrix_and_tone_curve(rt, kind: str, tone: str | None) -> None:
    """The preview path's per-pixel stages fused into the binning (HalfSize.fuse) give what the
    reference gives stage by stage: clamp, colour matrix, white balance pass 2, tone curve."""
    raw = make_raw(kind, shape=(40, 52), seed=2)
    clamp = HighlightClamp(np.array([0.9, 1.0, 0.8]), 0.7)
    stages = [HalfSize.for_raw(raw), clamp, ColourMatrix(raw.colour_matrix), ColourMatrix(np.diag([1.2, 1.0, 0.9]))]
    if tone is not None:
        stages.append(ToneCurve(quantize=tone == "uint16"))
    fused = stages[0]
    for stage in stages[1:]:
        fused = fused.fuse(stage)
        assert fused is not None, type(stage).__name__
    assert fused.tone == tone and fused.cap is not None
    fused = fused.with_interleaved_output()
    r = fused.halo
    x, origin = raw.data, (-r, -r)                  # the window's blocks on even image coordinates
    expected = stages[0].reference(x, origin)
    for stage in stages[1:]:
        expected = stage.reference(expected, (0, 0))
    src = rt.upload(x)
    dst = fused.enqueue(rt, src, origin)
    got = rt.download(dst)
    assert dst.interleaved and got.dtype == fused.out_dtype and got.shape == expected.shape
    if tone == "uint16":
        diff = np.abs(got.astype(np.int32) - expected.astype(np.int32))
        assert diff.max() <= 1 and np.mean(diff > 0) < 0.05
    else:
        assert_close(got, expected, f"{kind} fused, tone {tone}")
    rt.release(src)
    rt.release(dst)
    assert HalfSize.for_raw(raw).fuse(ToneCurve()).fuse(ColourMatrix(np.eye(3))) is None   # out of order


# ------------------------------------------------------------------------------------------
# the pipeline: tiled = whole, shapes, grey
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("kind", ["bayer-rggb", "lms@1,2"])
@pytest.mark.parametrize("highlights", [None, "reconstruct"])
def test_tiled_equals_whole(kind: str, highlights: str | None) -> None:
    """Small tiles (16 output pixels: windows of 32 raw pixels plus the halo) give the whole
    image's output, on OpenCL and on the reference; also with reconstruct's 20 px halo after the
    binning (40 raw pixels). Odd raw sides: the output is rounded up."""
    raw = make_raw(kind)
    raw.data[10:30, 20:60] = 1023                                     # clipped: the highlight stage runs
    pipeline = build_pipeline(raw, output="srgb", half_size=True, highlights=highlights)
    assert pipeline.downscale == 2 and pipeline.stages[0].name == "half_size"
    assert pipeline.output_shape(raw.shape) == (49, 66)
    whole = pipeline.run(raw.data, tile=0)
    assert whole.shape == (49, 66, 3)
    tiled = pipeline.run(raw.data, tile=16)
    assert pipeline.stats.tiles > 4
    assert_close(tiled, whole, f"{kind} tiled")
    reference = pipeline.run(raw.data, tile=16, backend="reference")
    np.testing.assert_array_equal(reference, pipeline.run(raw.data, tile=0, backend="reference"))
    # the reconstruct kernels' own bound against their reference (tests/modules/test_highlights.py)
    assert_close(whole, reference, f"{kind} reference", tol=1e-4 if highlights == "reconstruct" else 1e-5)


class OriginProbe(Stage):
    """A test stage after the binning: each pixel's output is its image coordinate (y, x) and the
    image's height as the stage's Origin says them (the OpenCL face uploads the same from the host)."""

    name = "origin_probe"

    def reference(self, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
        h, w = x.shape[:2]
        ys, xs = np.mgrid[0:h, 0:w]
        image = image_extent(origin)
        return np.stack([ys + origin[0], xs + origin[1], np.full((h, w), image[0] if image else -1)], axis=-1)

    def enqueue(self, rt, src, origin):
        probe = self.reference(np.empty((src.height, src.width)), origin)
        return rt.upload(np.ascontiguousarray(np.moveaxis(probe, -1, 0), dtype=np.float32))


@pytest.mark.parametrize("kind", ["bayer-rggb", "lms"])
def test_stages_after_the_binning_see_the_half_size_grid(kind: str) -> None:
    """Every window's Origin after the binning is in the output's grid (the raw's divided by 2),
    and carries the output's extent, on OpenCL and the reference, tiled and whole."""
    raw = make_raw(kind)
    pipeline = build_pipeline(raw, half_size=True, highlights="off")
    pipeline.stages.append(OriginProbe())
    ys, xs = np.mgrid[0:49, 0:66]
    expected = np.stack([ys, xs, np.full((49, 66), 49)], axis=-1)
    for backend in ("opencl", "reference"):
        for tile in (0, 16):
            np.testing.assert_array_equal(pipeline.run(raw.data, tile=tile, backend=backend), expected,
                                          err_msg=f"{backend} tile {tile}")


def test_flat_grey_raw_gives_grey() -> None:
    """A noiseless flat grey scene: every output pixel is the same neutral grey (Bayer and LMS)."""
    for kind in ("bayer", "lms"):
        raw = simulate(np.full((48, 64, 3), 0.18), cfa=kind, gain=None, optics="none").raw
        out = clisp.process(raw, half_size=True)
        assert out.shape == (24, 32, 3)
        np.testing.assert_allclose(out, 0.18, rtol=1e-4, err_msg=kind)


def test_output_shape_with_crop_and_rotation(tmp_path: Path) -> None:
    """The raw's crop is halved (an odd one rounded outward) and the camera's rotation applied,
    in memory and streamed to a file; the crop is the same pixels as the uncropped output's."""
    raw = make_raw("bayer-rggb", shape=(100, 140))
    uncropped = clisp.process(raw, half_size=True, crop=False)
    assert uncropped.shape == (50, 70, 3)
    raw.metadata["crop"] = [10, 7, 61, 120]                          # rows 10..71, columns 7..127
    cropped = clisp.process(raw, half_size=True)
    assert cropped.shape == (31, 61, 3)
    np.testing.assert_array_equal(cropped, uncropped[5:36, 3:64])
    raw.metadata["flip"] = 6                                          # 90 degrees clockwise
    rotated = clisp.process(raw, half_size=True)
    np.testing.assert_array_equal(rotated, np.rot90(cropped, -1))
    shape, _ = process_file(raw, tmp_path / "r.exr", tile=16, half_size=True)
    assert shape == (61, 31)
    assert_close(read_image(tmp_path / "r.exr")[0], rotated, "rotated file")


@pytest.mark.parametrize("ext", [".exr", ".tif", ".png", ".jpg"])
def test_streamed_file_equals_in_memory(tmp_path: Path, ext: str) -> None:
    """The file path streams bands of half-size rows (several tiles) into each output format and
    gives the in-memory result (16-bit: within a code; 8-bit JPEG: on average)."""
    raw = make_raw("lms", shape=(120, 100))
    raw.metadata["crop"] = [4, 8, 100, 80]
    out = tmp_path / f"o{ext}"
    shape, stats = process_file(raw, out, tile=16, half_size=True)
    assert shape == (50, 40) and stats.tiles > 1
    got = read_image(out)[0]
    assert got.shape == (50, 40, 3)
    expected = clisp.process(raw, half_size=True, output="linear" if ext == ".exr" else "srgb")
    if ext == ".jpg":                  # random pixels: JPEG's chroma subsampling moves single pixels far
        assert np.abs(got - expected).mean() < 0.05
    else:
        assert_close(got, expected, ext, tol=1e-5 if ext == ".exr" else 1.0 / 65535)


def test_metered_tile_counts_what_a_half_size_tile_creates(rt) -> None:
    """--mem stays honest: the metering run of a half-size tile's window predicts the buffers a
    real tile creates."""
    raw = make_raw("lms", shape=(90, 122))
    pipeline = build_pipeline(raw, output="srgb16", half_size=True)
    pipeline.run(raw.data, tile=0)                                     # programs built, pool warm
    rt.trim_pool()
    held = rt.pool.created
    pipeline.run(raw.data, tile=0)
    window = (2 * 45 + 2 * pipeline.halo, 2 * 61 + 2 * pipeline.halo)
    expected = pipeline.metered_tile(pipeline.schedule(), window, raw.data.dtype)[0]
    created = rt.pool.created - held
    assert created <= expected + window[0] * window[1] * raw.data.dtype.itemsize   # + a gathered window


# ------------------------------------------------------------------------------------------
# what it refuses, and what it ignores
# ------------------------------------------------------------------------------------------

def test_refuses_a_demosaic_and_a_denoiser_and_ignores_the_presets() -> None:
    raw = make_raw("bayer-rggb", shape=(40, 40))
    with pytest.raises(ClispError, match="--half-size .* leave out --demosaic malvar"):
        build_pipeline(raw, demosaic="malvar", half_size=True)
    with pytest.raises(ClispError, match="--half-size runs no chroma denoise"):
        build_pipeline(raw, denoise=True, half_size=True)
    for preset in ("fast", "quality"):                     # the preset's demosaic and denoiser are not used
        names = build_pipeline(raw, preset=preset, half_size=True, denoise=False).describe()
        assert names.startswith("half_size") and "demosaic" not in names and "denoise" not in names


# ------------------------------------------------------------------------------------------
# the command line: process and batch
# ------------------------------------------------------------------------------------------

def test_cli_process_half_size_explains_its_path(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from clisp.app.cli import main
    from clisp.io.rawfile import write_raw
    raw = make_raw("bayer-rggb", shape=(64, 96))
    write_raw(tmp_path / "r.dng", raw)
    code = main(["process", str(tmp_path / "r.dng"), "-o", str(tmp_path / "o.png"), "--half-size",
                 "--preset", "quality", "--exposure", "1", "--explain"])
    out = capsys.readouterr().out
    assert code == 0 and "o.png: 48x32 from bayer-rggb raw" in out
    assert "explain: half-size path (one pixel per 2x2 block, no demosaic): half_size" in out
    assert read_image(tmp_path / "o.png")[0].shape == (32, 48, 3)


def test_batch_accepts_half_size(tmp_path: Path) -> None:
    """``clisp batch --half-size`` parses into BatchSettings (hashed: a half-size batch is not the
    full-size one's), and a worker's job writes the half-size image (run here, without Dask)."""
    from clisp.app.batch import BatchSettings, Job, process_one
    from clisp.app.cli import build_parser
    from clisp.io.rawfile import write_raw
    args = build_parser().parse_args(["batch", "in", "-o", str(tmp_path / "out"), "--half-size"])
    assert args.half_size
    settings = BatchSettings(format="tif", half_size=args.half_size)
    assert settings.identity()["half_size"] is True and "half_size" not in BatchSettings().identity()
    write_raw(tmp_path / "r.dng", make_raw("lms", shape=(64, 96)))
    job = Job(str(tmp_path / "r.dng"), str(tmp_path / "r.tif"))
    record = process_one(job, settings, settings.digest(), "run")
    assert record["status"] == "ok", record
    assert (record["width"], record["height"]) == (48, 32)
