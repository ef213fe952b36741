"""Building a pipeline: the presets and options, the demosaic by name, and :func:`build_pipeline`
(a raw and a few choices to a list of stages, with the noise calibration step). The pipeline is
data: the executor (clisp.engine.executor.Pipeline) runs any list of stages over tiles, so later
work can drop or swap stages per image or per tile without touching it.
"""
from __future__ import annotations

import pickle
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from importlib import import_module
from typing import Any, Sequence

import numpy as np

from .corrections import Corrections, only_isolated_clips, sensor_corrections
from ..errors import ClispError
from ..io.rawimage import RawImage, check_levels, check_samples
from ..engine.executor import Memo, Pipeline
from ..engine.runtime import get_runtime
from ..engine.stage import Stage
from ..modules.chroma_denoise.stage import (ChromaDenoise, ChromaDenoiseParams, calibrate_noise, is_noiseless,
                                           space_for_cfa)
from ..modules.colour.stage import ColourMatrix, WhiteBalance2, tone_curve_for
from ..modules.half_size.stage import HalfSize
from ..modules.highlights.stage import DEFAULT_MODE as DEFAULT_HIGHLIGHTS, highlight_stage
from ..modules.raw_scale.stage import normalize, white_balance1
from ..scene.noise import has_noise_model, raw_noise
from .demosaic_choice import alternative_for, choose_demosaic
from ..scene.measure import measure_scene
from ..scene.statistics_device import statistics_runtime
from ..scene.white_balance import has_camera_wb, with_white_balance


class StageRegistry(Mapping[str, type[Stage]]):
    """Stage classes by name, each module imported the first time its class is asked for: a run
    needs one demosaic, and importing all seven cost about 70 ms of every command's start-up
    (``python -X importtime``; ARI's alone 30-60 ms). Iterating gives the names in order."""

    def __init__(self, where: dict[str, tuple[str, str]]) -> None:
        self._where = where                  # name -> (module, class)
        self._classes: dict[str, type[Stage]] = {}

    def __getitem__(self, name: str) -> type[Stage]:
        cls = self._classes.get(name)
        if cls is None:
            module, attr = self._where[name]
            cls = self._classes[name] = getattr(import_module(module), attr)
        return cls

    def __iter__(self) -> Iterator[str]:
        return iter(self._where)

    def __len__(self) -> int:
        return len(self._where)


DEMOSAICS = StageRegistry({
    "bilinear": ("clisp.modules.demosaic_bilinear.stage", "DemosaicBilinear"),
    "malvar": ("clisp.modules.demosaic_malvar.stage", "DemosaicMalvar"),
    "dlmmse": ("clisp.modules.demosaic_dlmmse.stage", "DemosaicDLMMSE"),
    "hybrid": ("clisp.modules.demosaic_lms.stage", "DemosaicLMSHybrid"),
    "guided": ("clisp.modules.demosaic_lms_guided.stage", "DemosaicLMSGuided"),
    "ari": ("clisp.modules.demosaic_ari.stage", "DemosaicARI"),
    "ri": ("clisp.modules.demosaic_ri.stage", "DemosaicRI"),
})
"""Demosaic stages by CLI name, each built by its ``for_raw(raw)`` (Stage: from the raw's CFA;
stages that adapt to the raw's noise override it); ``cfa_kinds`` lists the CFA layouts it supports.

>>> list(DEMOSAICS)[:3], DEMOSAICS["ri"].__name__
(['bilinear', 'malvar', 'dlmmse'], 'DemosaicRI')
"""

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
    each tile skip what it does not need (clisp.pipeline.skip; the run's plan is ``Pipeline.skip_plan``);
    False = analyse and plan, but every tile takes the full path (``--no-skip --explain``);
    SKIP_WHERE_IT_PAYS ('auto', the CLI's default) = True where clisp.pipeline.skip.why_not_skip finds that
    skipping can pay on the device, else no analysis and ``Pipeline.skip_off`` says why. With
    True the demosaic is also chosen for the raw's noise (clisp.pipeline.demosaic_choice: the cheapest whose
    expected error there is within the budget of the preset's; ``Pipeline.stage_choice`` says
    which and why). A
    pipeline without a chroma denoiser (preset fast) has nothing to skip: no analysis (it would
    cost 10-30 ms/MP for nothing). ``highlights``: 'clip', 'reconstruct' or 'off'
    (clisp.modules.highlights.stage), None = the preset's; the stage is left out of raws without clipped
    samples. ``exposure``: EV applied to linear sRGB after the colour conversion (2^EV, within
    +-EXPOSURE_LIMIT; 0: colorimetric, 1.0 = the raw's white), with white balance pass 2's gains, so
    highlight reconstruction and the denoiser's noise model see the raw as it is.
    ``auto_exposure``: add LibRaw's auto-bright exposure, estimated from the raw (clisp.scene.exposure).
    The pipeline's ``exposure_ev`` says what was applied. ``wb``: white balance pass 1, 'camera'
    (as shot), 'auto' (the scene's light, clisp.scene.illuminant; ``Pipeline.wb_explain`` says what it
    found), 'daylight' or multipliers 'a,b,c' (clisp.scene.white_balance).
    ``half_size``: the preview path (``--half-size``): normalise, WB pass 1 and a 2 x 2 binning in
    one stage (clisp.modules.half_size), then highlights, colour, WB pass 2 and tone curve at half
    the raw's width and height; the preset's demosaic and chroma denoise are not used (an explicit
    ``demosaic`` or ``denoise`` is refused: the binning averages the samples), its highlight mode
    is HALF_SIZE_HIGHLIGHTS unless ``highlights`` says otherwise.
    ``bad_pixels`` ('auto', 'off' or a map file; None: the preset's, auto but for fast), ``dark`` and
    ``flat`` (frames' paths) and ``opcodes``
    (apply the DNG's opcodes): the sensor corrections (clisp.pipeline.corrections), a first stage on the
    mosaic and, for gains, one after the chroma stage; the pipeline's ``corrections`` says what they did.
    """
    # 1. the choices given, checked, with the preset's filled in
    if output not in OUTPUTS:
        raise ClispError(f"unknown output {output!r}; expected one of {', '.join(OUTPUTS)}")
    if not -EXPOSURE_LIMIT <= exposure <= EXPOSURE_LIMIT:          # also NaN
        raise ClispError(f"--exposure {exposure:g}: EV must be within -{EXPOSURE_LIMIT:g}..+{EXPOSURE_LIMIT:g}")
    check_raw(raw)
    given = demosaic if isinstance(demosaic, Stage) else None
    options = resolve_options(preset, None if given else demosaic, raw.cfa.layout, half_size, raw.cfa.kind)
    params = denoise_params(denoise, options["denoise_levels"])
    if half_size and params is not None:
        raise ClispError(HALF_SIZE_NO_DENOISE)
    kind = HalfSize if half_size else (type(given) if given else DEMOSAICS[options["demosaic"]])
    adapt = bool(skip) and given is None and alternative_for(kind) is not None
    if bad_pixels is None:                                  # the preset's (fast: off), else auto
        bad_pixels = options.get("bad_pixels", "auto")
    rt = calibration_runtime()
    # 2-3. the scene and the decisions it allows, kept per camera and settings where only the metadata made them
    key = decisions_key(raw, rt, options, params, output, wb, wb2, exposure, auto_exposure, skip, given,
                        half_size, bad_pixels, dark, flat, opcodes)
    decided = DECISIONS.get(key) if key is not None else None
    if decided is None:
        decided, scene = decide(raw, rt, options, params, output, wb, wb2, exposure, auto_exposure, adapt, given,
                                half_size, bad_pixels, dark, flat, opcodes)
        if key is not None and scene.statistics is None:   # nothing read the mosaic: a function of the key
            DECISIONS.put(key, decided)
        raw, statistics = scene.raw, scene.statistics
    else:                                                   # (never with skip: its key is None)
        raw, statistics, scene = with_white_balance(raw, wb), None, None   # as measure_scene gives it without estimates
    # 4. what the mosaic itself decides: the highlight stage, where it has clipped samples
    highlight = highlight_stage(raw, highlights or options.get("highlights", DEFAULT_HIGHLIGHTS), decided.gains2,
                                noise=decided.noise, scale=2 if half_size else 1,
                                peaks=statistics.peaks if statistics is not None else None)
    if highlight is not None and only_isolated_clips(raw, decided.corrections.pre):
        highlight = None                                    # a hot pixel is not a clipped light
    stages = [*decided.head, *([highlight] if highlight is not None else []), *decided.tail]
    pipeline = Pipeline(raw.cfa, stages, exposure_ev=decided.exposure, wb_source=decided.wb_source,
                        wb_explain=decided.wb_explain, stage_choice=decided.choice)
    pipeline.corrections = decided.corrections
    pipeline.scene_statistics = statistics                  # None when no estimate read the mosaic
    # 5. the skip plan, from the scene's block analysis
    if skip is not None and any(isinstance(stage, ChromaDenoise) for stage in stages):
        from .skip import Skipper, why_not_skip   # deferred (7 ms of start-up); nothing to skip without a chroma denoiser
        pipeline.skip_off = why_not_skip(rt, raw.cfa, stages) if skip == SKIP_WHERE_IT_PAYS else ""
        if not pipeline.skip_off:
            from ..scene.block_analysis import analyse   # deferred with the skip planner: only skipping runs one
            pipeline.skipper = Skipper.for_pipeline(raw, stages, enabled=bool(skip),
                                                    analysis=analyse(raw, statistics=scene.measured()))
            pipeline.scene_statistics = scene.statistics
    return pipeline


@dataclass(frozen=True)
class Decisions:
    """What :func:`build_pipeline` decides before it looks at the mosaic's clipped samples: the
    scene's noise (the corrections' added), pass 2's gains and the exposure, the sensor
    corrections, the demosaic choice, and the stages before and after the highlight stage's place."""

    noise: Any
    gains2: np.ndarray
    exposure: float
    corrections: Corrections
    choice: Any
    head: tuple[Stage, ...]
    tail: tuple[Stage, ...]
    wb_source: str
    wb_explain: str


DECISIONS = Memo(16)
""":class:`Decisions` by :func:`decisions_key`: a process that builds pipelines for raws of one
camera and settings in memory (``clisp.process`` on a burst, a preview redrawn) decides once what
only the metadata decides (not the command line's builds, whose ``--skip auto`` reads the mosaic:
:func:`decisions_key` is None there); the same stage objects come back, so the
schedule and plan memos (clisp.engine.executor) find them by identity. Built without it, a 0.26 MP
quality pipeline cost 0.65 ms of Python with warm caches and 1.2-2.2 ms between calls (README.md)."""


def decisions_key(raw: RawImage, rt: Any, options: Mapping[str, Any], params: ChromaDenoiseParams | None,
                  output: str, wb: str, wb2: str, exposure: float, auto_exposure: bool, skip: Any, given: Any,
                  half_size: bool, bad_pixels: Any, dark: Sequence[str], flat: Sequence[str],
                  opcodes: bool) -> tuple | None:
    """The :data:`DECISIONS` key of a build: everything :func:`decide` reads (the raw's CFA, levels,
    multipliers and matrix as their bytes, its metadata pickled, its shape and sample type, the
    options, the runtime); None where a decision reads the mosaic or a file: a raw without a noise
    model (its noise is estimated), an estimated white balance or exposure, pass 2 other than the
    metadata's, the skip analysis, frames, a bad pixel map or DNG opcodes, a demosaic stage given as
    an object. The raw's ``source`` is left out: only messages name it. Values, not one pickle of
    them all: a pickle also records which of its objects are one object, so two raws of equal
    values could differ in it."""
    md = raw.metadata or {}
    if given is not None or skip is not None or auto_exposure or dark or flat or wb2 != "metadata" \
            or wb == "auto" or not has_noise_model(raw) or not has_camera_wb(raw) \
            or not (isinstance(bad_pixels, str) and bad_pixels in ("auto", "off")) \
            or (opcodes and (md.get("opcodes") or md.get("opcodes_unreadable"))):
        return None
    try:
        key = (raw.cfa.name, raw.cfa.kind, tuple(raw.cfa.channels), raw.cfa._pattern_bytes,
                *(np.asarray(a, dtype=np.float64).tobytes() for a in (raw.black_level, raw.wb, raw.colour_matrix,
                                                                     raw.wb2)),
                float(raw.white_level), float(raw.exposure), pickle.dumps(md, protocol=4), raw.data.shape,
                raw.data.dtype.str, tuple(options.items()), pickle.dumps(params, protocol=4), output, wb,
                float(exposure), half_size, bad_pixels, opcodes, id(rt))
        hash(key)                                           # an option of an unhashable value: not kept
    except (pickle.PicklingError, TypeError, AttributeError):
        return None
    return key


def decide(raw: RawImage, rt: Any, options: Mapping[str, Any], params: ChromaDenoiseParams | None, output: str,
           wb: str, wb2: str, exposure: float, auto_exposure: bool, adapt: bool, given: Stage | None,
           half_size: bool, bad_pixels: Any, dark: Sequence[str], flat: Sequence[str],
           opcodes: bool) -> tuple[Decisions, Any]:
    """:func:`build_pipeline`'s decisions for ``raw`` (steps 2 and 3) and the measured scene
    (clisp.scene.measure.Scene: the raw with pass 1's multipliers, the statistics where an estimate
    read them)."""
    # 2. the scene, measured once: pass 1's white balance, the noise, pass 2's gains, the exposure
    scene = measure_scene(raw, wb, wb2, noise=params is not None or adapt, exposure=exposure,
                          auto_exposure=auto_exposure, limit=EXPOSURE_LIMIT, runtime=statistics_runtime(rt))
    raw, cfa = scene.raw, scene.raw.cfa
    # 3. the decisions: the corrections, the demosaic the noise allows, the denoiser's table
    corrections = sensor_corrections(raw, bad_pixels, dark, flat, opcodes, scene.noise)
    noise = corrections.noise(scene.noise)                  # the dark frame's own noise added
    demosaic_stage = HalfSize.for_raw(raw) if half_size else (given or make_demosaic(options["demosaic"], raw))
    choice = None
    if adapt and noise is not None:                         # the cheapest demosaic its noise allows
        demosaic_stage, choice = choose_demosaic(demosaic_stage, raw, noise)
    colour: Stage = ColourMatrix(raw.colour_matrix)
    if params is not None and noise is not None:
        colour = chroma_denoise_for(raw, demosaic_stage, params, noise, rt)
    # the stages in the order they run, the highlight stage's place between head and tail
    head: list[Stage] = [demosaic_stage] if half_size else [normalize(cfa, raw.black_level, raw.white_level),
                                                            white_balance1(cfa, raw.pass1_gains()), demosaic_stage]
    if corrections.pre is not None:
        head.insert(0, corrections.pre)
    tail: list[Stage] = [colour]
    shade = corrections.shade(raw.colour_matrix, HALF_SIZE_DOWNSCALE if half_size else 1)
    if shade is not None:                                   # the smooth gain, after highlights and denoiser
        tail.append(shade)
    output_gains = scene.gains2 * 2.0 ** scene.exposure
    if np.any(output_gains != 1.0):                          # the identity is left out
        tail.append(WhiteBalance2(output_gains))
    tone = tone_curve_for(output)
    if tone is not None:
        tail.append(tone)
    explain_wb = str(raw.metadata.get("wb_explain", "")) if wb in ("auto", "camera") else ""   # camera: a file without it
    gains2 = np.array(scene.gains2, dtype=np.float64)
    gains2.setflags(write=False)                            # shared by the pipelines of one key
    return Decisions(noise, gains2, float(scene.exposure), corrections, choice, tuple(head), tuple(tail),
                     str(raw.metadata.get("wb_source", "camera")), explain_wb), scene


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


def denoise_params(denoise: ChromaDenoiseParams | bool | None, levels: int) -> ChromaDenoiseParams | None:
    """The chroma denoiser's parameters from a build_pipeline ``denoise`` argument and the preset's
    depth, or None for no denoiser."""
    if isinstance(denoise, ChromaDenoiseParams):
        return denoise
    if denoise is False or (denoise is None and levels == 0):
        return None
    return ChromaDenoiseParams(levels=max(1, int(levels)))
