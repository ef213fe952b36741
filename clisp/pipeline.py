"""Building a pipeline and processing raws: the presets, :func:`build_pipeline` (a raw and a few
choices to a list of stages, with the noise calibration step), and :func:`process` /
:func:`process_file` (the public API and the CLI's path). The pipeline is data: the executor
(clisp.engine.executor.Pipeline) runs any list of stages over tiles, so later work can drop or swap
stages per image or per tile without touching it.
"""
from __future__ import annotations

import time
from contextlib import closing, nullcontext
from dataclasses import replace
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from .corrections import only_isolated_clips, sensor_corrections
from .errors import ClispError, clip
from .io.exif import output_attributes
from .io.rawfile import read_raw
from .io.rawimage import MAX_GAIN, RawImage, check_levels, check_samples
from .engine.executor import DEFAULT_BUDGET, Pipeline, RunStats, device_limits
from .engine.runtime import DEVICE_LOCK, get_runtime
from .engine.stage import Stage
from .engine.streaming import ArraySink, BandSink, progress_bar, window_source
from .engine.tiling import MIN_TILE, TilePlan, make_plan
from .modules.chroma_denoise.stage import (ChromaDenoise, ChromaDenoiseParams, calibrate_noise, is_noiseless,
                                           space_for_cfa)
from .modules.colour.stage import ColourMatrix, WhiteBalance2, tone_curve_for
from .modules.demosaic_ari.stage import DemosaicARI
from .modules.demosaic_ri.stage import DemosaicRI
from .modules.demosaic_bilinear.stage import DemosaicBilinear
from .modules.demosaic_dlmmse.stage import DemosaicDLMMSE
from .modules.demosaic_lms.stage import DemosaicLMSHybrid
from .modules.demosaic_lms_guided.stage import DemosaicLMSGuided
from .modules.demosaic_malvar.stage import DemosaicMalvar
from .modules.half_size.stage import HalfSize
from .modules.highlights.stage import DEFAULT_MODE as DEFAULT_HIGHLIGHTS, highlight_stage
from .modules.raw_scale.stage import normalize, white_balance1
from .modules.resize.stage import (ResizeSink, StreamingResize, check_long_edge, resize_image, resize_reference,
                                   resized_size)
from .noise_estimate import NoiseEstimateError, raw_noise
from .stage_choice import alternative_for, choose_demosaic
from .white_balance import with_white_balance
from .white_balance2 import estimate_wb2

DEMOSAICS: dict[str, type[Stage]] = {
    "bilinear": DemosaicBilinear,
    "malvar": DemosaicMalvar,
    "dlmmse": DemosaicDLMMSE,
    "hybrid": DemosaicLMSHybrid,
    "guided": DemosaicLMSGuided,
    "ari": DemosaicARI,
    "ri": DemosaicRI,
}
"""Demosaic stages by CLI name, each built by its ``for_raw(raw)`` (Stage: from the raw's CFA;
stages that adapt to the raw's noise override it); ``cfa_kinds`` lists the CFA layouts it supports."""

PRESETS: dict[str, dict[str, Any]] = {
    "fast": {"demosaic": {"lms": "bilinear", "bayer": "bilinear", "other": "bilinear"}, "denoise_levels": 0,
             "highlights": "clamp", "bad_pixels": "off"},
    "balanced": {"demosaic": {"lms": "hybrid", "bayer": "dlmmse", "other": "bilinear"}, "denoise_levels": 2,
                 "highlights": "reconstruct"},
    "quality": {"demosaic": {"lms": "guided", "bayer": "ri", "other": "bilinear"}, "denoise_levels": 3,
                "highlights": "reconstruct"},
    "best": {"demosaic": {"lms": "guided", "bayer": "ari", "other": "bilinear"}, "denoise_levels": 3,
             "highlights": "reconstruct"},
}
"""Named parameter sets (``--preset``); an option is one value or a dict per CFA layout (clisp.cfa
``CFA.layout``: 'lms', 'bayer', 'other'; lms-bayer and L doubled on the Bayer layout (``ML/LS``) take
the Bayer demosaics, the any-CFA bilinear serves the other layouts). The colour side (camera constants, chroma space) follows the CFA's
channels, not the preset.
``denoise_levels``: pyramid depth of the chroma denoiser, 0 = none. ``highlights``: the highlight
mode (clisp.modules.highlights.stage; fast: the per-pixel clamp, since reconstruct costs 1 s on a 24 MP
raw with clipping spread over a fifth of it). ``bad_pixels``: the defect search's default where it is
not 'auto' (fast: off; the search is a pass of its own there, since the fast path folds the
normalisation into the demosaic: +15 % on a 24 MP raw; docs/RESULTS.md). Explicit options override."""

DEFAULT_PRESET = "quality"
EXPOSURE_LIMIT = 10.0
"""Largest ``--exposure`` in EV either way (a gain of 1024: past it a raw's quantisation shows)."""
OUTPUTS = ("linear", "srgb", "srgb16", "srgb8")
HALF_SIZE_DOWNSCALE = 2
"""Raw pixels per output pixel along each axis with ``--half-size``."""
HALF_SIZE_HIGHLIGHTS = "clamp"
"""The highlight mode of ``--half-size`` whatever the preset (an explicit ``--highlights`` wins): the
per-pixel clamp, as LibRaw's default, in keeping with a preview (reconstruct's radii and rim are
tuned to a demosaic's full-resolution false colour)."""
HALF_SIZE_BAD_PIXELS = "off"
"""The defect search of ``--half-size`` whatever the preset (an explicit ``--bad-pixels`` wins): off, as
the fast preset's, in keeping with a preview (the binning averages a hot pixel with three good ones);
known bad pixels (a map, the DNG's lists, the frames') are still replaced."""
HALF_SIZE_NO_DENOISE = ("--half-size runs no chroma denoise (the binning averages the samples): "
                        "leave out --denoise-scale and --chroma-strengths")
"""The refusal of an explicit chroma denoiser with ``--half-size`` (docs/messages.md)."""


def resolve_options(preset: str | None, demosaic: str | None, kind: str | None = None,
                    half_size: bool = False, cfa_kind: str | None = None) -> dict[str, Any]:
    """The options for CFA layout ``kind`` ('lms', 'bayer' or 'other': ``CFA.layout``; for the LMS and
    Bayer CFAs their kind): the preset's, overridden by explicit ones.

    Raises ClispError on unknown names, and on a demosaic that does not support the layout
    (a stage class may declare ``cfa_kinds``, the layouts it serves; without it, it supports every
    CFA). With ``kind=None`` only the names are checked. ``cfa_kind``: the CFA's kind, said in the
    refusal when its layout is not its name (lms-bayer). ``half_size``: the preview path (no demosaic, no
    chroma denoise, highlights HALF_SIZE_HIGHLIGHTS); an explicit demosaic is refused.
    """
    name = preset or DEFAULT_PRESET
    if name not in PRESETS:
        raise ClispError(f"unknown preset {name!r}; available: {', '.join(PRESETS)}")
    if demosaic and demosaic not in DEMOSAICS:
        raise ClispError(f"unknown demosaic {demosaic!r}; available: {', '.join(DEMOSAICS)}")
    if half_size and demosaic:
        raise ClispError(f"--half-size bins each 2x2 block into one pixel, without a demosaic: "
                         f"leave out --demosaic {demosaic}")
    if kind is None:
        return {}
    options = {key: value[kind] if isinstance(value, dict) else value for key, value in PRESETS[name].items()}
    if half_size:
        return {**options, "demosaic": None, "denoise_levels": 0, "highlights": HALF_SIZE_HIGHLIGHTS,
                "bad_pixels": HALF_SIZE_BAD_PIXELS}
    if demosaic:
        options["demosaic"] = demosaic
    kinds = DEMOSAICS[options["demosaic"]].cfa_kinds or (kind,)
    if kind not in kinds:
        which = kind if cfa_kind in (None, kind) else f"{cfa_kind} (the {kind} layout)"
        raise ClispError(f"demosaic {options['demosaic']!r} works on {' and '.join(kinds)} CFAs, not {which}")
    return options


def make_demosaic(name: str, raw: RawImage) -> Stage:
    """The demosaic stage ``name`` configured for ``raw`` (its CFA, and its noise if the stage uses it)."""
    return DEMOSAICS[name].for_raw(raw)


FILES_IN_FLIGHT = 2
"""Files one process has under way at once on a device that shares host memory (``clisp process
RAW... -o OUTDIR``): one on the device while the other is decoded or its last bands written and
the file closed (clisp.engine.runtime.DEVICE_LOCK lets one thread at a time on the device).
Twelve 3 MP Bayer raws to TIFF on 2 PoCL cores: quality 4.4-5.3 s against 5.1-6.3 s one at a
time, fast 0.35-0.46 against 0.37-0.46 (docs/RESULTS.md, issue 41)."""

GPU_FILES_IN_FLIGHT = 3
"""The same on a discrete device, and the threads of a ``clisp batch`` worker there: decode the
next, run this one, write the last, on the host's cores while the GPU runs."""

SKIP_WHERE_IT_PAYS = "auto"
"""build_pipeline's ``skip`` for the CLI's default: skip where it pays on the device."""


def build_pipeline(raw: RawImage, preset: str | None = None, demosaic: str | Stage | None = None,
                   output: str = "linear", denoise: ChromaDenoiseParams | bool | None = None,
                   wb2: str = "metadata", skip: bool | str | None = None,
                   highlights: str | None = None, exposure: float = 0.0, auto_exposure: bool = False,
                   wb: str = "camera", half_size: bool = False, bad_pixels: Any = None,
                   dark: Sequence[str] = (), flat: Sequence[str] = (), opcodes: bool = True) -> Pipeline:
    """Stages for ``raw``: normalise, WB pass 1, demosaic, highlights, colour (+ chroma denoise),
    WB pass 2, tone curve.

    ``output='linear'`` ends in linear sRGB (for EXR); ``'srgb'`` appends the sRGB tone curve;
    ``'srgb16'`` the tone curve to 16-bit codes, uint16 (for 16-bit TIFF/PNG); ``'srgb8'`` to 8-bit
    codes, uint8 (for JPEG: the device writes the file's bytes). ``demosaic``: a name
    (DEMOSAICS; None = the preset's) or a configured demosaic stage, used as given. ``denoise``: None =
    the preset's depth, False = off, True = on (the preset's depth, at least 1 level), or explicit
    ChromaDenoiseParams; its noise comes from the raw's sensor model, else it is estimated from the
    raw. ``wb2``: white balance pass 2 from
    'metadata' (known illuminant), 'gray_world' or 'gray_pixels'; left out when it is the identity.
    ``skip``: None = every stage on every tile, no scene analysis; True = analyse the raw and let
    each tile skip what it does not need (clisp.skip; the run's plan is ``Pipeline.skip_plan``);
    False = analyse and plan, but every tile takes the full path (``--no-skip --explain``);
    SKIP_WHERE_IT_PAYS ('auto', the CLI's default) = True where clisp.skip.why_not_skip finds that
    skipping can pay on the device, else no analysis and ``Pipeline.skip_off`` says why. With
    True the demosaic is also chosen for the raw's noise (clisp.stage_choice: the cheapest whose
    expected error there is within the budget of the preset's; ``Pipeline.stage_choice`` says
    which and why). A
    pipeline without a chroma denoiser (preset fast) has nothing to skip: no analysis (it would
    cost 10-30 ms/MP for nothing). ``highlights``: 'clip', 'reconstruct' or 'off'
    (clisp.modules.highlights.stage), None = the preset's; the stage is left out of raws without clipped
    samples. ``exposure``: EV applied to linear sRGB after the colour conversion (2^EV, within
    +-EXPOSURE_LIMIT; 0: colorimetric, 1.0 = the raw's white), with white balance pass 2's gains, so
    highlight reconstruction and the denoiser's noise model see the raw as it is.
    ``auto_exposure``: add LibRaw's auto-bright exposure, estimated from the raw (clisp.exposure).
    The pipeline's ``exposure_ev`` says what was applied. ``wb``: white balance pass 1, 'camera'
    (as shot), 'auto' (the scene's light, clisp.illuminant; ``Pipeline.wb_explain`` says what it
    found), 'daylight' or multipliers 'a,b,c' (clisp.white_balance).
    ``half_size``: the preview path (``--half-size``): normalise, WB pass 1 and a 2 x 2 binning in
    one stage (clisp.modules.half_size), then highlights, colour, WB pass 2 and tone curve at half
    the raw's width and height; the preset's demosaic and chroma denoise are not used (an explicit
    ``demosaic`` or ``denoise`` is refused: the binning averages the samples), its highlight mode
    is HALF_SIZE_HIGHLIGHTS unless ``highlights`` says otherwise.
    ``bad_pixels`` ('auto', 'off' or a map file; None: the preset's, auto but for fast), ``dark`` and
    ``flat`` (frames' paths) and ``opcodes``
    (apply the DNG's opcodes): the sensor corrections (clisp.corrections), a first stage on the
    mosaic and, for gains, one after the chroma stage; the pipeline's ``corrections`` says what they did.
    """
    if output not in OUTPUTS:
        raise ClispError(f"unknown output {output!r}; expected one of {', '.join(OUTPUTS)}")
    if not -EXPOSURE_LIMIT <= exposure <= EXPOSURE_LIMIT:          # also NaN
        raise ClispError(f"--exposure {exposure:g}: EV must be within -{EXPOSURE_LIMIT:g}..+{EXPOSURE_LIMIT:g}")
    check_raw(raw)
    raw = with_white_balance(raw, wb)
    cfa = raw.cfa
    given = demosaic if isinstance(demosaic, Stage) else None
    options = resolve_options(preset, None if given else demosaic, cfa.layout, half_size, cfa.kind)
    params = denoise_params(denoise, options["denoise_levels"])
    if half_size and params is not None:
        raise ClispError(HALF_SIZE_NO_DENOISE)
    demosaic_stage = HalfSize.for_raw(raw) if half_size else (given or make_demosaic(options["demosaic"], raw))
    colour: Stage = ColourMatrix(raw.colour_matrix)
    adapt = bool(skip) and given is None and alternative_for(demosaic_stage) is not None
    noise = None
    if params is not None or adapt:
        try:
            noise = raw_noise(raw)
        except NoiseEstimateError:
            noise = None        # a raw too small to estimate its noise is processed without chroma denoise
    if bad_pixels is None:                                  # the preset's (fast: off), else auto
        bad_pixels = options.get("bad_pixels", "auto")
    corrections = sensor_corrections(raw, bad_pixels, dark, flat, opcodes, noise)
    noise = corrections.noise(noise)                        # the dark frame's own noise added
    choice = None
    if adapt and noise is not None:                         # the cheapest demosaic its noise allows
        demosaic_stage, choice = choose_demosaic(demosaic_stage, raw, noise)
    if params is not None and noise is not None:
        colour = chroma_denoise_for(raw, demosaic_stage, params, noise, calibration_runtime())
    gains2 = _wb2_gains(raw, wb2)
    stages: list[Stage] = [demosaic_stage] if half_size else [normalize(cfa, raw.black_level, raw.white_level),
                                                              white_balance1(cfa, raw.pass1_gains()), demosaic_stage]
    if corrections.pre is not None:
        stages.insert(0, corrections.pre)
    highlight = highlight_stage(raw, highlights or options.get("highlights", DEFAULT_HIGHLIGHTS), gains2,
                                noise=noise, scale=2 if half_size else 1)
    if highlight is not None and only_isolated_clips(raw, corrections.pre):
        highlight = None                                    # a hot pixel is not a clipped light
    if highlight is not None:
        stages.append(highlight)
    stages.append(colour)
    shade = corrections.shade(raw.colour_matrix, HALF_SIZE_DOWNSCALE if half_size else 1)
    if shade is not None:                                   # the smooth gain, after highlights and denoiser
        stages.append(shade)
    if auto_exposure:
        from .exposure import auto_exposure_ev      # deferred: only --auto-exposure estimates
        exposure = float(np.clip(exposure + auto_exposure_ev(raw, gains2, EXPOSURE_LIMIT),
                                 -EXPOSURE_LIMIT, EXPOSURE_LIMIT))
    output_gains = gains2 * 2.0 ** exposure
    if not np.allclose(output_gains, 1.0, rtol=0, atol=0):
        stages.append(WhiteBalance2(output_gains))
    tone = tone_curve_for(output)
    if tone is not None:
        stages.append(tone)
    explain_wb = str(raw.metadata.get("wb_explain", "")) if wb in ("auto", "camera") else ""   # camera: read-time auto
    pipeline = Pipeline(cfa, stages, exposure_ev=exposure, wb_source=str(raw.metadata.get("wb_source", "camera")),
                        wb_explain=explain_wb, stage_choice=choice)
    pipeline.corrections = corrections
    if skip is not None and any(isinstance(stage, ChromaDenoise) for stage in stages):
        from .skip import Skipper, why_not_skip   # deferred (7 ms of start-up); nothing to skip without a chroma denoiser
        pipeline.skip_off = why_not_skip(calibration_runtime(), cfa, stages) if skip == SKIP_WHERE_IT_PAYS else ""
        if not pipeline.skip_off:
            pipeline.skipper = Skipper.for_pipeline(raw, stages, enabled=bool(skip))
    return pipeline


def chroma_denoise_for(raw: RawImage, demosaic: Stage, params: ChromaDenoiseParams | None = None,
                       noise: Any = None, rt: Any = None) -> Stage:
    """The colour stage that follows ``demosaic`` for ``raw``, with the noise calibration step of
    building a pipeline: the chroma denoiser's noise table measured through ``demosaic``.

    ``noise``: per-channel noise of the white-balanced raw (:class:`clisp.sim.noise.ChannelNoise`,
    or anything with ``shot``, ``floor`` and ``variance(channel, level)``); None takes it from the
    raw (its sensor model when the metadata has one, else estimated from the mosaic). ``rt``: the
    runtime whose device runs the calibration's demosaic (:func:`calibration_runtime`), None for
    the NumPy reference. Returns a :class:`ChromaDenoise` in the paper's space for the CFA kind
    (LMS: Y = (L+M)/2, chroma R-Y, G-Y, B-Y; Bayer: BT.601 YUV) with that table; when the raw has
    no noise (noiseless simulation) the plain ``ColourMatrix``, which the denoiser would equal
    anyway (so noiseless output is unchanged, and linear demosaics still fuse with it).
    """
    params = params or ChromaDenoiseParams()
    noise = raw_noise(raw) if noise is None else noise
    if is_noiseless(noise) or params.noise_scale == 0:
        return ColourMatrix(raw.colour_matrix)
    space = space_for_cfa(raw.cfa, raw.colour_matrix, params.luma, raw.pass1_gains(), params.strengths)
    table = calibrate_noise(demosaic, raw.cfa, space, noise, params.levels, rt=rt)
    return ChromaDenoise(space, table, params)


def calibration_runtime() -> Any:
    """The runtime for the noise calibration when an OpenCL device can be had (the calibration
    then runs the demosaic's kernels), else None: the NumPy reference, so that a machine without
    OpenCL can still build a pipeline (and run it with the reference backend)."""
    try:
        return get_runtime()
    except ClispError:
        return None


def check_raw(raw: RawImage) -> None:
    """ClispError naming ``raw.source`` for what the pipeline cannot process into finite pixels:
    levels and gains out of range (rawimage.check_levels), NaN, infinite or absurd samples in a
    float raw (rawimage.check_samples; such raws are refused, not repaired), a mosaic smaller
    than one CFA tile."""
    problem = check_levels(raw)
    if problem:
        raise ClispError(f"{raw.source}: {problem}")
    if raw.data.ndim != 2 or min(raw.data.shape) < raw.cfa.period:
        raise ClispError(f"{raw.source}: raw of {raw.shape[1]}x{raw.shape[0]} is smaller than one "
                         f"{raw.cfa.period}x{raw.cfa.period} CFA tile")
    check_samples(raw)


def _wb2_gains(raw: RawImage, method: str) -> np.ndarray:
    """estimate_wb2's gains, refused (ClispError naming the raw) when not finite and positive:
    a gray-world estimate of a black frame, or a corrupt illuminant in the metadata."""
    try:
        gains = np.asarray(estimate_wb2(raw, method), dtype=np.float64).reshape(3)
    except ClispError as exc:
        raise ClispError(f"{raw.source}: {clip(exc, 120)}") from exc
    except (TypeError, ValueError, np.linalg.LinAlgError) as exc:
        raise ClispError(f"{raw.source}: white balance pass 2 from the metadata failed ({clip(exc)})") from exc
    if not np.all(np.isfinite(gains)) or np.any(gains < 1.0 / MAX_GAIN) or np.any(gains > MAX_GAIN):
        raise ClispError(f"{raw.source}: white balance pass 2 ({method}) gives unusable gains "
                         f"{', '.join(f'{g:.3g}' for g in gains)}")
    return gains


def denoise_params(denoise: ChromaDenoiseParams | bool | None, levels: int) -> ChromaDenoiseParams | None:
    """The chroma denoiser's parameters from a build_pipeline ``denoise`` argument and the preset's
    depth, or None for no denoiser."""
    if isinstance(denoise, ChromaDenoiseParams):
        return denoise
    if denoise is False or (denoise is None and levels == 0):
        return None
    return ChromaDenoiseParams(levels=max(1, int(levels)))


def orient(image: np.ndarray, flip: int) -> np.ndarray:
    """Apply LibRaw's ``sizes.flip`` code (0 none, 3 180 degrees, 5 90 CCW, 6 90 CW) to H x W x C."""
    if flip == 3:
        return image[::-1, ::-1]
    if flip == 5:
        return np.rot90(image, 1)
    if flip == 6:
        return np.rot90(image, -1)
    return image


def crop_of(raw: RawImage) -> tuple[int, int, int, int] | None:
    """The crop ``raw`` declares, (top, left, height, width) in its mosaic's coordinates
    (``metadata['crop']``: a DNG's DefaultCrop, see clisp.io.camera), or None for the whole mosaic
    (none declared, or one that does not lie inside the mosaic)."""
    crop = raw.metadata.get("crop")
    try:
        top, left, height, width = (int(v) for v in crop)
    except (TypeError, ValueError):
        return None
    h, w = raw.shape
    if top < 0 or left < 0 or height <= 0 or width <= 0 or top + height > h or left + width > w:
        return None
    return None if (top, left, height, width) == (0, 0, h, w) else (top, left, height, width)


def output_crop(crop: tuple[int, int, int, int] | None, pipeline: Pipeline,
                shape: tuple[int, int]) -> tuple[int, int, int, int] | None:
    """``crop`` (:func:`crop_of`, in the mosaic of ``shape``) on ``pipeline``'s output: the same for a
    pipeline that keeps the grid; with ``--half-size`` (downscale 2) the output pixels whose blocks
    hold any of it (an even crop, the usual, halves exactly).

    >>> from clisp.cfa import bayer_cfa
    >>> output_crop((12, 8, 100, 61), Pipeline(bayer_cfa(), [HalfSize(bayer_cfa(), [0] * 3, [1] * 3)]), (200, 100))
    (6, 4, 50, 31)
    """
    return scaled_crop(crop, pipeline.downscale, shape)


def scaled_crop(crop: tuple[int, int, int, int] | None, s: int,
                shape: tuple[int, int]) -> tuple[int, int, int, int] | None:
    """``crop`` in the mosaic of ``shape`` on an output ``s`` times smaller (rounded up, as
    Pipeline.output_shape): the output pixels whose blocks hold any of it.

    >>> scaled_crop((12, 8, 100, 61), 2, (200, 100))
    (6, 4, 50, 31)
    """
    if crop is None or s == 1:
        return crop
    top, left, height, width = crop
    out_h, out_w = -(-int(shape[0]) // s), -(-int(shape[1]) // s)
    bottom, right = min(-(-(top + height) // s), out_h), min(-(-(left + width) // s), out_w)
    return top // s, left // s, bottom - top // s, right - left // s


def cropped_writes(write: Callable[[int, np.ndarray], None],
                   crop: tuple[int, int, int, int]) -> Callable[[int, np.ndarray], None]:
    """``write(y0, rows)`` of a band sink for the whole mosaic's rows, passing on only the crop's
    rows and columns, renumbered from the crop's top. The pipeline runs on the whole mosaic (the
    crop's border pixels see their real neighbours, and tiled still equals whole), the output
    holds the crop; memory stays one band."""
    top, left, height, width = crop

    def write_cropped(y0: int, rows: np.ndarray) -> None:
        a, b = max(y0, top), min(y0 + rows.shape[0], top + height)
        if a < b:
            write(a - top, rows[a - y0:b - y0, left:left + width])
    return write_cropped


def output_size(raw: RawImage, crop: bool = True, half_size: bool = False) -> tuple[int, int]:
    """(height, width) of the image :func:`process_file` makes of ``raw`` before any resize: the
    crop the raw declares (:func:`crop_of`; with ``crop`` False the whole mosaic), halved with
    ``half_size`` (:func:`scaled_crop`), turned upright."""
    s = HALF_SIZE_DOWNSCALE if half_size else 1
    region = scaled_crop(crop_of(raw) if crop else None, s, raw.shape)
    height, width = (-(-raw.shape[0] // s), -(-raw.shape[1] // s)) if region is None else region[2:]
    return (width, height) if int(raw.metadata.get("flip", 0) or 0) in (5, 6) else (height, width)


def _crop_image(image: np.ndarray, crop: tuple[int, int, int, int] | None) -> np.ndarray:
    if crop is None:
        return image
    top, left, height, width = crop
    return image[top:top + height, left:left + width]


def process_with_stats(raw: RawImage, tile: int | None = None, backend: str = "opencl", crop: bool = True,
                       **options: Any) -> tuple[np.ndarray, RunStats]:
    """:func:`process` for a RawImage, also returning the run's timing."""
    with DEVICE_LOCK:                                # one thread at a time builds and runs on the device
        pipeline = build_pipeline(raw, **options)
        image = pipeline.run(raw.data, tile=tile, backend=backend)
    image = _crop_image(image, output_crop(crop_of(raw), pipeline, raw.shape) if crop else None)
    image = np.ascontiguousarray(orient(image, int(raw.metadata.get("flip", 0) or 0)))
    return image, pipeline.stats


def process(raw: RawImage | str | Path, tile: int | None = None, backend: str = "opencl", crop: bool = True,
            **options: Any) -> np.ndarray:
    """Process a raw image (or a raw file's path) into H x W x 3 float32 sRGB.

    ``options`` are :func:`build_pipeline`'s: preset, demosaic, output ('linear': scene-linear
    sRGB, white 1.0, unclipped; 'srgb': sRGB-encoded in [0, 1]), denoise, wb2.
    ``crop``: keep only the crop the raw declares (:func:`crop_of`, a DNG's DefaultCrop); False
    keeps the whole mosaic. Orientation from camera metadata is applied last. ``half_size=True``:
    half the width and height, one pixel per 2 x 2 block, no demosaic (:func:`build_pipeline`).
    """
    if not isinstance(raw, RawImage):
        raw = read_raw(raw)
    return process_with_stats(raw, tile, backend, crop, **options)[0]


def process_file(raw: RawImage, path: str | Path, tile: int | None = None, budget: int = DEFAULT_BUDGET,
                 backend: str = "opencl", progress: bool = False, compression: str | None = None,
                 explain: dict | None = None, crop: bool = True, resize: int | None = None,
                 **options: Any) -> tuple[tuple[int, int], RunStats]:
    """Process ``raw`` into the image file ``path`` (EXR linear, TIFF/PNG sRGB-encoded), streaming.

    Tile windows are read as needed (from disk for ``read_raw(path, lazy=True)``) and results
    written band by band (imageio.ImageWriter). ``budget`` bounds the peak resident memory of the
    whole process (clisp.engine.memory): what the process holds when planning, plus the tiles' counted
    bytes, plus RSS_MARGIN; ClispError when even the smallest tile does not fit, naming the
    minimum. Raws with a camera rotation are oriented in memory (the whole output counts).
    ``progress``: a progress bar on stderr (when it is a terminal). ``compression``: EXR/TIFF
    compression (default imageio.DEFAULT_COMPRESSION). ``options``: :func:`build_pipeline`'s
    (the output kind follows the extension). ``explain``: a dict that receives the pipeline
    (key 'pipeline'), whose skipper and skip_plan describe the run. ``crop``: write only the crop
    the raw declares (:func:`crop_of`; the whole mosaic is processed, see :func:`cropped_writes`);
    False writes the whole mosaic. ``resize``: the output's long edge in pixels (``--resize``;
    never enlarged, see clisp.modules.resize): the pipeline ends in linear light and the resizer
    low-passes and samples the rows on the device, then applies the output's tone curve. The
    output carries the raw's metadata (clisp.io.exif.output_attributes). Atomic: on failure no file.
    Returns the output's (height, width) and the run's stats.
    """
    from .io.imageio import DEFAULT_COMPRESSION, ImageWriter, output_kind, write_image   # deferred: 2 ms of start-up
    compression = compression or DEFAULT_COMPRESSION
    attributes = output_attributes(raw)
    kind = output_kind(path)
    encoding = encoded_output(path) if kind == "srgb" else kind
    scale = HALF_SIZE_DOWNSCALE if options.get("half_size") else 1
    region = scaled_crop(crop_of(raw), scale, raw.shape) if crop else None
    upright = output_size(raw, crop, options.get("half_size", False))
    target = upright if resize is None else resized_size(*upright, check_long_edge(resize))
    resized = target != upright
    flip = int(raw.metadata.get("flip", 0) or 0)
    in_memory = bool(flip) or (resized and backend != "opencl")
    with DeviceHold() as hold:        # the device's part; decoding and writing run outside (DEVICE_LOCK)
        pipeline = build_pipeline(raw, output="linear" if resized else encoding, **options)
        notes = []                                                           # what was applied, in the file
        if options.get("wb", "camera") != "camera":
            notes.append(f"white balance {pipeline.wb_source} (clisp)")
        if options.get("exposure") or options.get("auto_exposure"):
            how = ", auto" if options.get("auto_exposure") else ""
            notes.append(f"exposure {pipeline.exposure_ev:+.2f} EV (clisp{how})")
        if resized:                                   # the size it had, in the file (no EXIF size is written)
            notes.append(f"resized from {upright[1]}x{upright[0]} to {target[1]}x{target[0]} "
                         f"(clisp, Lanczos-3 in linear light)")
        if notes:
            attributes["ImageDescription"] = "; ".join(filter(None, [attributes.get("ImageDescription"), *notes]))
        if explain is not None:                       # the caller reads the plan after the run
            explain["pipeline"] = pipeline
        resizer = StreamingResize(get_runtime(), upright, target, encoding, offset=region[:2] if region else (0, 0)) \
            if resized and not in_memory else None
        plan = _whole_process_plan(pipeline, raw, path, tile, budget, backend, in_memory=in_memory,
                                   extra=2 * resizer.window_bytes if resizer else 0)
        if in_memory:               # rotated output rows are input columns: orient the whole result
            image = np.empty(pipeline.output_shape(raw.shape) + (pipeline.out_channels,), dtype=pipeline.out_dtype)
            with closing(window_source(raw.data)) as source:
                pipeline.stream(source, ArraySink(image), plan, backend)
            oriented = orient(_crop_image(image, region), flip)
            if resized:
                _write_resized(path, oriented, target, encoding, backend, compression, attributes)
            else:
                hold.release()
                write_image(path, oriented, compression=compression, attributes=attributes)
            return target, pipeline.stats
        (height, width), channels = pipeline.output_shape(raw.shape), pipeline.out_channels
        out_h, out_w = target
        bar = progress_bar(plan.tiles, Path(path).name) if progress else nullcontext(None)
        start = time.perf_counter()
        with closing(window_source(raw.data)) as source, closing(resizer) if resizer else nullcontext(), \
                ImageWriter(path, out_w, out_h, channels, compression, attributes) as writer, \
                (ResizeSink(writer.write_rows, plan, width, resizer) if resizer else
                 BandSink(writer.write_rows if region is None else cropped_writes(writer.write_rows, region),
                          plan, width, channels, pipeline.out_dtype, staging=_band_staging(backend))) as sink, \
                bar as update:
            stats = pipeline.stream(source, sink, plan, backend, progress=update)
            if resizer is None:
                hold.release()                  # the bands left to write and the file's close need no device
        return (out_h, out_w), replace(stats, seconds=time.perf_counter() - start)    # the last write included


class DeviceHold:
    """This thread's hold of DEVICE_LOCK, taken on entering; :meth:`release` gives it up early
    (once; leaving the block then does nothing), so that process_file's device work can end before
    its file is written and closed."""

    def __enter__(self) -> "DeviceHold":
        DEVICE_LOCK.acquire()
        self.held = True
        return self

    def release(self) -> None:
        if self.held:
            self.held = False
            DEVICE_LOCK.release()

    def __exit__(self, *exc: object) -> None:
        self.release()


def _band_staging(backend: str) -> Any:
    """Where process_file's output bands come from: the runtime's pinned staging buffers on a
    discrete device (the downloads' destination, reused across files); None (plain arrays) on a
    device sharing host memory, whose last kernel writes into the band itself."""
    if backend != "opencl":
        return None
    rt = get_runtime()
    return None if rt.host_unified else rt.staging


def encoded_output(path: str | Path) -> str:
    """The pipeline output an sRGB-encoded file takes: 8-bit codes for JPEG ('srgb8'), 16-bit codes
    for TIFF and PNG ('srgb16').

    >>> encoded_output("a.JPG"), encoded_output("b.tif")
    ('srgb8', 'srgb16')
    """
    from .io.imageio import JPEG_EXTENSIONS       # deferred, as in process_file
    return "srgb8" if Path(path).suffix.lower() in JPEG_EXTENSIONS else "srgb16"


def _write_resized(path: str | Path, image: np.ndarray, target: tuple[int, int], encoding: str, backend: str,
                   compression: str, attributes: dict) -> None:
    """Write the linear H x W x 3 ``image`` resized to ``target`` (height, width) in ``encoding``
    ('linear', 'srgb16', 'srgb8'): on the device, band by band into the file; the NumPy reference (and
    ToneCurve's) for ``backend`` 'reference'."""
    from .io.imageio import ImageWriter, write_image   # deferred, as in process_file
    if backend != "opencl":
        pixels = resize_reference(image, *target)
        if encoding != "linear":
            pixels = tone_curve_for(encoding).reference(pixels, (0, 0))
        write_image(path, pixels, compression=compression, attributes=attributes)
        return
    with ImageWriter(path, target[1], target[0], 3, compression, attributes) as writer:
        resize_image(image, *target, output=encoding, write=writer.write_rows)


def _whole_process_plan(pipeline: Pipeline, raw: RawImage, path: str | Path, tile: int | None, budget: int,
                        backend: str, in_memory: bool, extra: int = 0) -> TilePlan:
    """The plan of :func:`process_file` for a whole-process ``budget`` (see clisp.engine.memory): the
    tiles get what the process does not already hold. ``in_memory``: the whole output is held
    (oriented raws) and counts too; ``extra``: bytes held besides (the resizer's device window).
    ClispError naming the minimum when nothing fits."""
    from .engine.memory import RSS_MARGIN, format_bytes, resident_bytes   # deferred: 0.6 ms (with resource)
    shape, dtype = raw.shape, raw.data.dtype
    if backend != "opencl":
        return pipeline.plan(shape, dtype, tile, budget, backend)
    limits = device_limits(backend)
    out_h, out_w = pipeline.output_shape(shape)           # the tiles' (the raw's unless --half-size)
    cost = pipeline.tile_cost(dtype, out_w, limits, sink_bands=not in_memory)
    smallest = cost(min(out_h, MIN_TILE), min(out_w, MIN_TILE))   # also builds the programs
    held = resident_bytes() + RSS_MARGIN + extra
    if in_memory:
        held += out_h * out_w * pipeline.out_channels * pipeline.out_dtype.itemsize
    if budget - held < smallest:
        raise ClispError(f"{path}: --mem {format_bytes(budget)} is below the minimum of "
                         f"{format_bytes(held + smallest)} for this {shape[1]}x{shape[0]} raw and these "
                         f"settings ({format_bytes(held)} for the process itself, "
                         f"{format_bytes(smallest)} for the smallest tile)")
    needs = replace(pipeline.needs(dtype), cost=cost)
    try:
        return make_plan(out_h, out_w, needs, tile, budget - held, limits)
    except ClispError as exc:
        raise ClispError(f"{path}: {exc}") from exc
