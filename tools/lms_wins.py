"""When the LMS camera wins, and why (issue 45): the layouts by the linear bound with noise, each
camera with its strongest chroma denoiser under one protocol, and the acceptance figures, in one run.

    python tools/lms_wins.py [--data ../shared/data] [--subset N] [--dead-leaves 8]
        [--gains none,4,16,64] [--crossover-gains 8,32] [--tune-size 384] [--seeds 2]
        [--bound-subset 6] [--bound-dead-leaves 3] [--bound-train 8] [--bound-support 11] [--no-bound]
        [--csv docs/lms_wins.csv] [--results docs/RESULTS.md] [--cameras bayer,lms] [--strongest-from CSV]
        [--section lms-wins]
    python tools/lms_wins.py --from-csv PART.csv [PART2.csv ...] [--results docs/RESULTS.md]

Cameras (CAMERAS): a CFA and the strongest demosaic clisp has for its layout: RGB Bayer with RI (the
quality preset's Bayer demosaic), the paper's 4 x 4 LMS CFA with ``guided``, L doubled on the Bayer
layout (``ML/LS``) with RI, LMS on the Bayer layout (``lms-bayer``) with RI, and the paper's tile
with M and S swapped (``LSLM/SLSL/LMLS/SLSL``: L on the checkerboard, S on 3/8, M on 1/8), which
only the any-CFA ``bilinear`` serves.

Denoisers, the same classes and search for every camera:
* ``bilateral``: clisp's luminance-guided multiresolution bilateral (clisp.modules.chroma_denoise),
  luminance ``paper`` (LMS (L + M) / 2, Bayer BT.601), ``cfa`` (the CFA's baseband luminance) or
  ``snr`` (its least-noise weighting; LUMAS), each at noise_scale 0.8, 1 and 1.25: 9 settings;
* ``nlm``: luminance-guided non-local means on chroma patches in the same pyramid (research.chroma_nlm),
  the same three luminances, k_chroma 1.5, 2 and 3: 9 settings.
The quality preset's denoiser is ``bilateral`` paper x 1 (the default). Each camera's strongest
denoiser is the setting with the best mean PSNR on the tuning scenes (made in code, never judged:
dead-leaves charts of seeds 2000-2001, the same desaturated towards grey as natural colour is,
seeds 2002-2003, and the demo chart; gains 4 and 16, noise seed 0). Kodak, McMaster and the
dead-leaves charts of seeds 0.. judge, at every level of ``--gains`` (all cameras) and of
``--crossover-gains`` (Bayer and the paper's LMS, to place the crossover).

Pipelines (the protocol of tools/paper_tables.py's Runner: what ``--highlights off --bad-pixels off`` runs): normalise,
white balance pass 1, the demosaic (clisp.pipeline.make_demosaic: configured for the raw's noise),
then the chroma denoiser with its noise table calibrated through that demosaic on the device, or
at no noise the plain colour matrix (the denoiser does not run). ``nlm`` runs in NumPy on the
device's demosaic output. Simulation: clisp.sim.simulate (Airy optics, the paper's sensor, noise
seed 0). PSNR: tone-mapped (clip, sRGB-encode), 10 px border, the mean of the images' dB.

Gray-panel SNR (the paper's Table 2 measure; clisp.metrics.gray_panel_snr, linear output, mean of
R, G, B and of the six panels) per camera with the default and its strongest denoiser, and the
paper's Bayer (DLMMSE, BT.601 denoiser), demo chart, ``--seeds`` noise seeds, gains 4, 16, 64.

The linear bound with noise (tools/cfa_linear_bound.py): per-phase ``--bound-support`` filters
from the mosaic straight to linear sRGB, trained with the sensor's noise at the gain they are
tested at on ``--bound-train`` dead-leaves charts (seeds 1000..), on the first ``--bound-subset``
Kodak and McMaster images and ``--bound-dead-leaves`` charts, for every camera's CFA.

With ``--results PATH`` the generated block (tables and the paragraph that reads them) replaces the
section between the ``lms-wins`` markers of PATH (toolkit.update_results).
"""
from __future__ import annotations

import argparse
import shlex
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

import toolkit  # before clisp: puts this checkout on sys.path
from toolkit import BORDER

import cfa_linear_bound as bound
from clisp.cfa import cfa_from_name
from clisp.engine.runtime import get_runtime
from clisp.engine.stage import Stage
from clisp.io.rawimage import RawImage
from clisp.metrics import gray_panel_snr, psnr
from clisp.modules.chroma_denoise.stage import (LUMAS, ChromaDenoise, ChromaDenoiseParams, calibrate_noise,
                                                is_noiseless, space_for_cfa)
from clisp.modules.colour.stage import ColourMatrix
from clisp.modules.raw_scale.stage import normalize, white_balance1
from clisp.scene.noise import raw_noise
from clisp.pipeline import Pipeline, make_demosaic
from clisp.sim.charts import dead_leaves, demo_chart
from clisp.sim.simulate import simulate
from research.chroma_nlm import NLMParams, chroma_nlm

SECTION = "lms-wins"
CAMERAS: tuple[tuple[str, str], ...] = (("bayer", "ri"), ("lms", "guided"), ("ML/LS", "ri"), ("lms-bayer", "ri"),
                                        ("LSLM/SLSL/LMLS/SLSL", "bilinear"))
"""(CFA, demosaic): the cameras, each with the strongest demosaic clisp has for its layout."""
BAYER, LMS = CAMERAS[0], CAMERAS[1]
LMS_CAMERAS = CAMERAS[1:]
"""The cameras with the LMS filters (the paper's cones), on their layouts."""
PAPER_BAYER = ("bayer", "dlmmse")
"""The paper's Bayer (its Table 2 baseline), for the gray-panel SNR lead."""
TUNE_GAINS = (4, 16)
SNR_GAINS = (4, 16, 64)
STRENGTHS = (0.8, 1.0, 1.25)
"""The bilateral's search: noise_scale (every noise sigma of its table times this)."""
NLM_K = (1.5, 2.0, 3.0)
"""The non-local means' search: k_chroma."""
TUNE_SEEDS = (2000, 2001, 2002, 2003)
"""Dead-leaves seeds of the tuning charts; the last two desaturated (DESATURATE)."""
DESATURATE = 0.5
"""Share of grey mixed into the desaturated tuning charts: dead leaves draw their colours uniformly
in RGB, far more saturated than photographs."""


# ------------------------------------------------------------------------------------------
# denoisers
# ------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Denoiser:
    """One chroma denoiser setting: ``kind`` 'bilateral' (clisp's, ``params``) or 'nlm'
    (research.chroma_nlm, ``nlm``), in the luminance ``params.luma``."""

    kind: str
    params: ChromaDenoiseParams = field(default_factory=ChromaDenoiseParams)
    nlm: NLMParams | None = None

    @property
    def label(self) -> str:
        if self.kind == "nlm":
            return f"nlm {self.params.luma} k{self.nlm.k_chroma:g}"
        return f"bilateral {self.params.luma} x{self.params.noise_scale:g}"


DEFAULT = Denoiser("bilateral", ChromaDenoiseParams(luma="paper"))
"""The quality preset's chroma denoiser when issue 45 began (the paper's space for each camera)."""


def search() -> list[Denoiser]:
    """Every setting tried for every camera (the module doc's 9 + 9)."""
    out = [Denoiser("bilateral", ChromaDenoiseParams(luma=luma, noise_scale=s)) for luma in LUMAS for s in STRENGTHS]
    out += [Denoiser("nlm", ChromaDenoiseParams(luma=luma), NLMParams(patch=1, patch_luma=0, k_chroma=k))
            for luma in LUMAS for k in NLM_K]
    return out


# ------------------------------------------------------------------------------------------
# one camera on one scene
# ------------------------------------------------------------------------------------------

def camera_stages(raw: RawImage, demosaic: Stage) -> list[Stage]:
    return [normalize(raw.cfa, raw.black_level, raw.white_level), white_balance1(raw.cfa, raw.pass1_gains()), demosaic]


class Shot:
    """One camera's raw of one scene at one noise level, demosaicked once; :meth:`output` runs a
    denoiser on it (the colour matrix alone at no noise)."""

    def __init__(self, scene: np.ndarray, camera: tuple[str, str], gain: float | None, seed: int = 0) -> None:
        self.sim = simulate(scene, camera[0], gain=gain, seed=seed)
        self.raw = self.sim.raw
        self.noise = raw_noise(self.raw)
        self.demosaic = make_demosaic(camera[1], self.raw)
        self._cam: np.ndarray | None = None
        self._plain: np.ndarray | None = None

    @property
    def noiseless(self) -> bool:
        return is_noiseless(self.noise)

    def cam(self) -> np.ndarray:
        """The demosaic's white-balanced camera image (H x W x 3), on the device, whole."""
        if self._cam is None:
            self._cam = Pipeline(self.raw.cfa, camera_stages(self.raw, self.demosaic)).run(self.raw.data)
        return self._cam

    def table(self, params: ChromaDenoiseParams):
        cfa = self.raw.cfa
        space = space_for_cfa(cfa, self.raw.colour_matrix, params.luma, self.raw.pass1_gains(), params.strengths)
        return space, calibrate_noise(self.demosaic, cfa, space, self.noise, params.levels, rt=get_runtime())

    def output(self, denoiser: Denoiser) -> np.ndarray:
        """Linear sRGB H x W x 3 through ``denoiser`` (the colour matrix at no noise)."""
        raw = self.raw
        if self.noiseless:
            if self._plain is None:
                self._plain = Pipeline(raw.cfa, camera_stages(raw, self.demosaic)
                                       + [ColourMatrix(raw.colour_matrix)]).run(raw.data)
            return self._plain
        space, table = self.table(denoiser.params)
        if denoiser.kind == "nlm":
            return chroma_nlm(self.cam(), space, table, denoiser.nlm).astype(np.float32)
        stages = camera_stages(raw, self.demosaic) + [ChromaDenoise(space, table, denoiser.params)]
        return Pipeline(raw.cfa, stages).run(raw.data)

    def score(self, denoiser: Denoiser) -> float:
        return psnr(self.output(denoiser), self.sim.truth, border=BORDER)


Key = tuple[str, tuple[str, str], str, object]
"""(set, camera, denoiser label, gain)."""


def evaluate(scenes: dict[str, list], cameras: Sequence[tuple[str, str]], denoisers: Callable[[tuple[str, str]], list[Denoiser]],
             gains: Sequence[float | None], progress: str = "") -> dict[Key, list[float]]:
    """{(set, camera, denoiser label, gain): [PSNR per scene]} for every camera's ``denoisers(camera)``."""
    out: dict[Key, list[float]] = {}
    total = sum(len(v) for v in scenes.values()) * len(cameras) * len(gains)
    done, start = 0, time.perf_counter()
    for set_name, items in scenes.items():
        for _, scene in items:
            for camera in cameras:
                for gain in gains:
                    shot = Shot(scene, camera, gain)
                    for d in denoisers(camera):
                        out.setdefault((set_name, camera, d.label, gain), []).append(shot.score(d))
                    done += 1
            if progress:
                print(f"  {progress}: {done}/{total} shots, {time.perf_counter() - start:.0f} s", flush=True)
    return out


def mean(scores: dict[Key, list[float]]) -> dict[Key, float]:
    return {k: float(np.mean(v)) for k, v in scores.items()}


# ------------------------------------------------------------------------------------------
# tuning
# ------------------------------------------------------------------------------------------

def tuning_scenes(size: int) -> dict[str, list]:
    """The scenes the denoisers are tuned on (module doc), all made in code."""
    items = []
    for i, seed in enumerate(TUNE_SEEDS):
        image = dead_leaves(size, seed=seed)
        if i >= len(TUNE_SEEDS) // 2:
            grey = image.mean(axis=-1, keepdims=True)
            image = (1.0 - DESATURATE) * image + DESATURATE * grey
            items.append((f"dead_leaves_{seed}_desaturated", image))
        else:
            items.append((f"dead_leaves_{seed}", image))
    items.append(("demo chart", demo_chart().image))
    return {"tuning": items}


def tune(cameras: Sequence[tuple[str, str]], size: int) -> tuple[dict[tuple[str, str], Denoiser], dict[Key, float]]:
    """({camera: its strongest denoiser}, {key: mean tuning PSNR}) over search() on tuning_scenes at TUNE_GAINS."""
    grid = search()
    scores = mean(evaluate(tuning_scenes(size), cameras, lambda c: grid, TUNE_GAINS, progress="tuning"))
    best = {}
    for camera in cameras:
        best[camera] = max(grid, key=lambda d: np.mean([scores[("tuning", camera, d.label, g)] for g in TUNE_GAINS]))
    return best, scores


# ------------------------------------------------------------------------------------------
# gray-panel SNR
# ------------------------------------------------------------------------------------------

def panel_snrs(denoisers: dict[tuple[str, str], list[Denoiser]], seeds: int,
               gains: Sequence[float] = SNR_GAINS) -> dict[tuple[tuple[str, str], str, float], float]:
    """{(camera, denoiser label, gain): gray-panel SNR (dB; mean of R, G, B and the six panels, mean
    over ``seeds``)} on the demo chart."""
    chart = demo_chart()
    out = {}
    for camera, ds in denoisers.items():
        for gain in gains:
            acc: dict[str, list[float]] = {}
            for seed in range(seeds):
                shot = Shot(chart.image, camera, gain, seed=seed)
                for d in ds:
                    acc.setdefault(d.label, []).append(float(np.mean(gray_panel_snr(shot.output(d), chart.gray_rois))))
            for label, v in acc.items():
                out[(camera, label, gain)] = float(np.mean(v))
    return out


# ------------------------------------------------------------------------------------------
# markdown
# ------------------------------------------------------------------------------------------

def gname(g: float | None) -> str:
    return "noiseless" if g is None else f"{g:g}"


def cname(camera: tuple[str, str]) -> str:
    return f"`{camera[0]}` ({camera[1]})"


@dataclass
class Run:
    """Everything one run measured."""

    sets: list[str]
    gains: list[float | None]
    crossover: list[float]
    best: dict[tuple[str, str], Denoiser]
    tuning: dict[Key, float]
    judged: dict[Key, float]
    snr: dict[tuple[tuple[str, str], str, float], float]
    bound: dict[tuple[str, str, float | None], float] | None
    images: dict[str, int]
    bound_images: dict[str, int]

    def psnr(self, set_name: str, camera: tuple[str, str], label: str, gain) -> float:
        return self.judged.get((set_name, camera, label, gain), float("nan"))

    def strongest(self, camera: tuple[str, str]) -> str:
        return self.best[camera].label

    @property
    def cameras(self) -> tuple[tuple[str, str], ...]:
        """The cameras measured, in CAMERAS' order (all of them unless parts are missing)."""
        return tuple(c for c in CAMERAS if c in self.best)

    @property
    def lms_cameras(self) -> tuple[tuple[str, str], ...]:
        return tuple(c for c in self.cameras if c in LMS_CAMERAS)


def cell(values: Sequence[float], fmt: str = "{:.2f}") -> str:
    return " / ".join("-" if np.isnan(v) else fmt.format(v) for v in values)


def md_bound(run: Run) -> list[str]:
    gains = run.gains
    lines = ["| layout | " + " | ".join(gname(g) for g in gains) + " |", "|---|" + "---|" * len(gains)]
    for camera in (c for c in CAMERAS if all((s, c[0], g) in run.bound for s in run.sets for g in gains)):
        cfa = cfa_from_name(camera[0])
        shares = "/".join(str(int(round(d * 16))) for d in cfa.densities())
        lines.append(f"| `{camera[0]}` (L/M or R/G/B in 16ths: {shares}) | "
                     + " | ".join(cell([run.bound[(s, camera[0], g)] for s in run.sets]) for g in gains) + " |")
    return lines


def md_judged(run: Run, cameras: Sequence[tuple[str, str]], gains: Sequence) -> list[str]:
    lines = ["| camera | denoiser | " + " | ".join(gname(g) for g in gains) + " |", "|---|---|" + "---|" * len(gains)]
    for camera in cameras:
        labels = [DEFAULT.label] + ([run.strongest(camera)] if run.strongest(camera) != DEFAULT.label else [])
        for label in labels:
            tag = "default" if label == DEFAULT.label else "strongest"
            if label == DEFAULT.label and run.strongest(camera) == DEFAULT.label:
                tag = "default = strongest"
            lines.append(f"| {cname(camera)} | {label} ({tag}) | "
                         + " | ".join(cell([run.psnr(s, camera, label, g) for s in run.sets]) for g in gains) + " |")
    return lines


def leads(run: Run, lms: tuple[str, str], lms_label: str, bayer_label: str, gains) -> dict:
    """{(set, gain): LMS - Bayer (dB)} of ``lms`` with ``lms_label`` against Bayer RI with ``bayer_label``."""
    return {(s, g): run.psnr(s, lms, lms_label, g) - run.psnr(s, BAYER, bayer_label, g) for s in run.sets for g in gains}


def md_leads(run: Run, gains) -> list[str]:
    """LMS - Bayer per gain: the paper's LMS and the best LMS camera, each with its strongest
    denoiser, against Bayer RI with the default and with its strongest denoiser."""
    lines = ["| LMS camera (denoiser) | against Bayer RI with | " + " | ".join(gname(g) for g in gains) + " |",
             "|---|---|" + "---|" * len(gains)]
    bayer_best = run.strongest(BAYER)
    for camera in run.lms_cameras:
        for lab, blab, what in ((DEFAULT.label, DEFAULT.label, "the default"),
                                (run.strongest(camera), bayer_best, f"its strongest ({bayer_best})")):
            d = leads(run, camera, lab, blab, gains)
            lines.append(f"| {cname(camera)} ({lab}) | {what} | "
                         + " | ".join(cell([d[(s, g)] for s in run.sets], "{:+.2f}") for g in gains) + " |")
    return lines


def md_tuning(run: Run, cameras) -> list[str]:
    """Per camera: the strongest setting (its mean tuning PSNR), the default's, and the best of each
    class in each luminance."""
    grid = search()

    def t(camera, d: Denoiser) -> float:
        return float(np.mean([run.tuning[("tuning", camera, d.label, g)] for g in TUNE_GAINS]))
    head = [f"{k} {luma}" for k in ("bilateral", "nlm") for luma in LUMAS]
    lines = ["| camera | strongest | default | " + " | ".join(head) + " |", "|---|---|---|" + "---|" * len(head)]
    for camera in cameras:
        cells = []
        for k in ("bilateral", "nlm"):
            for luma in LUMAS:
                d = max((d for d in grid if d.kind == k and d.params.luma == luma), key=lambda d: t(camera, d))
                cells.append(f"{t(camera, d):.2f} ({d.label.split()[-1]})")
        lines.append(f"| {cname(camera)} | {run.strongest(camera)} ({t(camera, run.best[camera]):.2f}) | "
                     f"{t(camera, DEFAULT):.2f} | " + " | ".join(cells) + " |")
    return lines


def md_snr(run: Run) -> list[str]:
    gains = SNR_GAINS
    lines = ["| camera | denoiser | " + " | ".join(f"gain {g:g}" for g in gains) + " |", "|---|---|" + "---|" * len(gains)]
    order = CAMERAS + (PAPER_BAYER,)
    for camera, label in sorted({(c, l) for c, l, _ in run.snr}, key=lambda k: (order.index(k[0]), k[1] != DEFAULT.label)):
        lines.append(f"| {cname(camera)} | {label} | " + " | ".join(f"{run.snr[(camera, label, g)]:.2f}" for g in gains) + " |")
    return lines


def crossover(run: Run, lms_label: str, bayer_label: str, set_name: str) -> float | None:
    """The lowest gain from which the paper's LMS camera stays ahead of Bayer RI (both with the
    given denoisers) on ``set_name``, over every judged gain; None if it never leads at the last."""
    gains = sorted(g for g in set(run.gains) | set(run.crossover) if g is not None)
    ahead = [run.psnr(set_name, LMS, lms_label, g) > run.psnr(set_name, BAYER, bayer_label, g) for g in gains]
    for i, g in enumerate(gains):
        if all(ahead[i:]):
            return g
    return None


def paragraph(run: Run) -> list[str]:
    """The reading of the tables: when the LMS camera wins, by how much, why; from this run's figures."""
    bayer_best, lms_best = run.strongest(BAYER), run.strongest(LMS)
    gains = sorted(g for g in set(run.gains) | set(run.crossover) if g is not None)
    photos = [s for s in run.sets if s in ("Kodak", "McMaster")]
    d_def = leads(run, LMS, DEFAULT.label, DEFAULT.label, gains)
    d_best = leads(run, LMS, lms_best, bayer_best, gains)
    goal = {(s, g): d_best[(s, g)] >= need for s in photos for g, need in ((4, 0.3), (16, 1.0)) if (s, g) in d_best}
    best_lms_camera = {g: max(run.lms_cameras, key=lambda c: np.mean([run.psnr(s, c, run.strongest(c), g) for s in photos]))
                       for g in gains}

    def fig(d: dict, g) -> str:
        return ", ".join(f"{s} {d[(s, g)]:+.2f}" for s in run.sets)

    out = ["**When the LMS camera wins.** "]
    cross = {s: crossover(run, lms_best, bayer_best, s) for s in run.sets}
    cross_def = {s: crossover(run, DEFAULT.label, DEFAULT.label, s) for s in run.sets}
    out[0] += ("With each camera given its strongest chroma denoiser (Bayer RI: " + bayer_best + "; LMS: " + lms_best
               + "), the paper's LMS camera leads Bayer from gain "
               + ", ".join(f"{gname(v) if v is not None else 'never (within the gains run)'} on {s}" for s, v in cross.items())
               + " (with the default denoiser for both: "
               + ", ".join(f"{gname(v) if v is not None else 'never'} on {s}" for s, v in cross_def.items()) + "). "
               + "LMS minus Bayer, both strongest, dB: "
               + "; ".join(f"gain {g:g}: {fig(d_best, g)}" for g in gains) + ". ")
    met = all(goal.values()) if goal else False
    out[0] += ("The issue's goal (at least +0.3 dB at gain 4 and +1 dB at gain 16 on Kodak and McMaster, Bayer "
               "given its strongest denoiser too) is " + ("**met**" if met else "**not met**") + ": "
               + ", ".join(f"{s} gain {g:g} {d_best[(s, g)]:+.2f}" for (s, g) in goal) + ". ")
    out[0] += ("The best LMS camera per gain (photos' mean): "
               + ", ".join(f"{gname(g)} {best_lms_camera[g][0]}" for g in gains) + ".")
    noiseless = leads(run, LMS, DEFAULT.label, DEFAULT.label, [None]) if None in run.gains else {}
    why = ["**Why.** Noiseless the LMS camera trails ("
           + ", ".join(f"{s} {v:+.2f}" for (s, _), v in noiseless.items())
           + " dB) on demosaic error, which its colour matrix amplifies (eq. (1) multiplies L - M error by 8.60, "
           "Bayer's R - G by 1.81) and which no chroma denoiser touches; the more saturated the scene, the more of "
           "the error is chroma (McMaster's saturated colours trail Kodak's, dead leaves, drawn uniformly in RGB, "
           "trail at every gain)."]
    if run.bound is not None:
        gaps = [run.bound[(s, BAYER[0], g)] - run.bound[(s, c[0], g)] for s in run.sets for g in run.gains
                for c in LMS_CAMERAS if (s, c[0], g) in run.bound]
        why.append(f"The linear bound with noise shows what sampling and matrix cost before any algorithm: Bayer's "
                   f"best linear estimator leads every LMS layout's at every gain run by {min(gaps):+.2f} to "
                   f"{max(gaps):+.2f} dB" if min(gaps) > 0 else
                   f"The linear bound with noise: Bayer minus the LMS layouts {min(gaps):+.2f} to {max(gaps):+.2f} dB")
        why[-1] += ("; the LMS camera's wins are the non-linear pipeline's: the luminance-guided chroma denoiser "
                    "working around a luminance with more signal.")
    snr_lead = {g: run.snr[(LMS, lms_best, g)] - run.snr[(BAYER, bayer_best, g)] for g in SNR_GAINS
                if (LMS, lms_best, g) in run.snr and (BAYER, bayer_best, g) in run.snr}
    snr_def = {g: run.snr[(LMS, DEFAULT.label, g)] - run.snr[(BAYER, DEFAULT.label, g)] for g in SNR_GAINS
               if (LMS, DEFAULT.label, g) in run.snr and (BAYER, DEFAULT.label, g) in run.snr}
    if snr_lead:
        why.append("With the chroma flattened what remains in the output is the luminance noise: on the gray "
                   "panels the LMS camera leads Bayer RI by "
                   + ", ".join(f"{v:+.2f}" for v in snr_lead.values()) + " dB at gains "
                   + ", ".join(f"{g:g}" for g in snr_lead) + " (both strongest; with the default for both "
                   + ", ".join(f"{v:+.2f}" for v in snr_def.values()) + "): the broad, overlapping cones' (L + M) / 2 "
                   "(or the CFA's baseband luminance) carries more signal than Bayer's, and that lead grows in the "
                   "output's PSNR as the "
                   "noise grows past the LMS camera's demosaic error.")
    lay = {g: best_lms_camera[g][0] for g in gains}
    why.append("The other layouts give up the L/M quincunx that the guided demosaic and the luminance ride on: "
               "doubling L (`ML/LS`) or M (`lms-bayer`) on 2 x 2 buys S samples (1/4 of the pixels, not 1/8) "
               "but leaves the other cone 1/4, so L - M, the difference eq. (1) amplifies most, is sampled more "
               "coarsely; the best LMS layout by gain (photos' mean): "
               + ", ".join(f"{gname(g)} `{v}`" for g, v in lay.items()) + ".")
    why = " ".join(why)
    return out + ["", why]


def run_facts(minutes: float) -> str:
    """The run's time, device, CPU and revision, as the section says them."""
    return (f"{minutes:.1f} min on {get_runtime().describe()} ({toolkit.cpu_model()}), revision "
            f"{toolkit.git_rev(toolkit.REPO, dirty=True)}")


def csv_rows(run: Run, command: str, facts: str) -> list[dict[str, object]]:
    """Every figure of ``run`` as CSV rows (part, set, cfa, demosaic, denoiser, gain, dB, images), the
    command and facts in a first 'run' row: what :func:`run_from_csv` reads back."""
    def row(part, set_name, camera, label, gain, value, images=""):
        return {"part": part, "set": set_name, "cfa": camera[0], "demosaic": camera[1], "denoiser": label,
                "gain": gname(gain), "db": repr(float(value)), "images": images}
    rows = [{"part": "run", "set": command, "cfa": facts, "demosaic": "", "denoiser": "", "gain": "", "db": "",
             "images": ""}]
    rows += [row("judged" if g in run.gains else "crossover", s, c, lab, g, v, run.images[s])
             for (s, c, lab, g), v in run.judged.items()]
    rows += [row("tuning", s, c, lab, g, v) for (s, c, lab, g), v in run.tuning.items()]
    rows += [row("gray_snr", "demo chart", c, lab, g, v) for (c, lab, g), v in run.snr.items()]
    if run.bound:
        rows += [row("linear_bound", s, (c, "linear"), "linear", g, v, run.bound_images[s])
                 for (s, c, g), v in run.bound.items()]
    return rows


def run_from_csv(paths: Path | Sequence[Path]) -> tuple[Run, str, str]:
    """(Run, command, facts) from :func:`csv_rows`' file, or from several (the parts of one run made
    with ``--cameras``: their rows together, their commands and facts joined by ' + ' and '; ')."""
    import csv
    rows = []
    for path in ([paths] if isinstance(paths, Path) else paths):
        with open(path, newline="") as f:
            rows += list(csv.DictReader(f))
    heads = [r for r in rows if r["part"] == "run"]
    head = {"set": " + ".join(r["set"] for r in heads), "cfa": "; ".join(r["cfa"] for r in heads)}

    def g(text: str):
        return None if text == "noiseless" else float(text)
    judged, tuning, snr, bnd, images, bimages = {}, {}, {}, {}, {}, {}
    for r in rows:
        camera, v = (r["cfa"], r["demosaic"]), float(r["db"] or "nan")
        if r["part"] in ("judged", "crossover"):
            judged[(r["set"], camera, r["denoiser"], g(r["gain"]))] = v
            images[r["set"]] = int(r["images"])
        elif r["part"] == "tuning":
            tuning[(r["set"], camera, r["denoiser"], g(r["gain"]))] = v
        elif r["part"] == "gray_snr":
            snr[(camera, r["denoiser"], g(r["gain"]))] = v
        elif r["part"] == "linear_bound":
            bnd[(r["set"], r["cfa"], g(r["gain"]))] = v
            bimages[r["set"]] = int(r["images"])
    grid = search()
    best = {c: max(grid, key=lambda d: np.mean([tuning[("tuning", c, d.label, t)] for t in TUNE_GAINS]))
            for c in CAMERAS if any(k[1] == c for k in tuning)}
    every = {g(r["gain"]) for r in rows if r["part"] == "judged"}
    both = {g(r["gain"]) for r in rows if r["part"] == "crossover"}
    gains = sorted(every, key=lambda x: -1 if x is None else x)
    run = Run(list(images), gains, sorted(both), best, tuning, judged, snr, bnd or None, images, bimages)
    return run, head["set"], head["cfa"]


def markdown(run: Run, command: str, minutes: float, facts: str, section: str = SECTION) -> str:
    start, end = toolkit.markers(section)
    sets = " / ".join(run.sets)
    lines = [
        start,
        "```sh",
        command,
        "```",
        "",
        f"Run: {facts}. Judged on "
        + ", ".join(f"{n} {s}" for s, n in run.images.items())
        + f" images; cells {sets}, mean PSNR dB (tone-mapped, 10 px border), noise seed 0; no highlight stage "
          "(`--highlights off` for both cameras, as the issue asks) and no defect search (`--bad-pixels off`).",
        "",
        *paragraph(run),
        "",
    ]
    if run.bound is not None:
        lines += ["### The layouts by the linear bound with noise", "",
                  "Per-phase least-squares filters from the mosaic to linear sRGB, trained with the sensor's noise "
                  "at each gain (tools/cfa_linear_bound.py; " + ", ".join(f"{n} {s}" for s, n in run.bound_images.items())
                  + "). The best linear joint demosaic and denoise each layout allows:", "", *md_bound(run), ""]
    lines += ["### Each camera with its strongest chroma denoiser (tuned on scenes made in code)", "",
              "Mean PSNR over the tuning scenes and gains 4 and 16: the strongest of the 18 settings, the default "
              "(bilateral paper x1), and the best of each class in each luminance (its setting in brackets):", "",
              *md_tuning(run, run.cameras), "",
              "### End to end, judged", "", *md_judged(run, run.cameras, run.gains), ""]
    if run.crossover:
        lines += ["Bayer and the paper's LMS at the gains between:", "",
                  *md_judged(run, (BAYER, LMS), run.crossover), ""]
    all_gains = sorted(g for g in set(run.gains) | set(run.crossover) if g is not None)
    lines += ["### LMS minus Bayer (dB)", "", *md_leads(run, [None] + all_gains if None in run.gains else all_gains), "",
              "### Gray-panel SNR (dB, linear output, demo chart)", "", *md_snr(run), end]
    return "\n".join(lines) + "\n"


# ------------------------------------------------------------------------------------------
# main
# ------------------------------------------------------------------------------------------

def judging_scenes(data: Path, subset: int | None, dead: int) -> dict[str, list]:
    out = {}
    if (data / toolkit.KODAK.folder).is_dir():
        out["Kodak"] = toolkit.kodak(data, subset)
        out["McMaster"] = toolkit.mcmaster(data, subset)
    if dead:
        out["dead leaves"] = toolkit.dead_leaves_charts(dead, 512)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    toolkit.add_data_option(ap)
    ap.add_argument("--subset", type=int, default=None, help="the first N Kodak and McMaster images (default all)")
    ap.add_argument("--dead-leaves", type=int, default=8, help="dead-leaves charts judged (seeds 0..N-1)")
    ap.add_argument("--gains", type=bound.parse_gains, default=[None, 4.0, 16.0, 64.0])
    ap.add_argument("--crossover-gains", type=lambda t: [float(g) for g in t.split(",") if g], default=[8.0, 32.0])
    ap.add_argument("--tune-size", type=int, default=384)
    ap.add_argument("--seeds", type=int, default=2, help="noise seeds of the gray-panel SNR")
    ap.add_argument("--bound-subset", type=int, default=6)
    ap.add_argument("--bound-dead-leaves", type=int, default=3)
    ap.add_argument("--bound-train", type=int, default=8)
    ap.add_argument("--bound-support", type=int, default=11)
    ap.add_argument("--no-bound", action="store_true", help="skip the linear bound")
    ap.add_argument("--csv", type=Path, default=None, help="write every measured figure here")
    ap.add_argument("--cameras", default=None,
                    help="measure only these of CAMERAS (CFA names, comma-separated; default all): a part of a run, "
                         "for parts run side by side and joined by --from-csv. Crossover gains need bayer and lms, "
                         "the paper's Bayer's SNR bayer; the linear bound always covers every camera")
    ap.add_argument("--strongest-from", type=Path, nargs="+", default=None,
                    help="tune nothing: each camera's strongest denoiser (and the tuning table) from the --csv "
                         "of an earlier run or its parts; judge on this run's sets")
    ap.add_argument("--section", default=SECTION, help=f"the RESULTS section's marker name (default {SECTION})")
    ap.add_argument("--from-csv", type=Path, nargs="+", default=None,
                    help="measure nothing: write the section from the --csv of an earlier run, or of its "
                         "--cameras parts (their commands and facts)")
    ap.add_argument("--results", type=Path, default=None)
    args = ap.parse_args(argv)
    if args.from_csv is not None:
        run, command, facts = run_from_csv(args.from_csv)
        text = markdown(run, command, 0.0, facts, args.section)
        print(text)
        if args.results is not None:
            toolkit.update_results(args.results, text, args.section)
            print(f"wrote the {args.section} section of {args.results}")
        return 0
    t0 = time.perf_counter()

    bound_scores, bound_images = None, {}
    if not args.no_bound:
        banks = bound.train_banks([c for c, _ in CAMERAS], args.gains, args.bound_train, args.bound_support)
        bsc = judging_scenes(args.data, args.bound_subset, args.bound_dead_leaves)
        bound_scores = bound.score_banks(banks, bsc)
        bound_images = {s: len(v) for s, v in bsc.items()}
        print(f"linear bound: {(time.perf_counter() - t0) / 60:.1f} min", flush=True)

    cameras = CAMERAS if args.cameras is None else tuple(c for c in CAMERAS if c[0] in args.cameras.split(","))
    if args.strongest_from is not None:
        earlier = run_from_csv(args.strongest_from)[0]
        missing = [c[0] for c in cameras if c not in earlier.best]
        if missing:
            ap.error(f"{args.strongest_from[0]}: no tuning rows for {', '.join(missing)}")
        best = {c: earlier.best[c] for c in cameras}
        tuning = {k: v for k, v in earlier.tuning.items() if k[1] in cameras}
    else:
        best, tuning = tune(cameras, args.tune_size)
    for camera, d in best.items():
        print(f"strongest for {camera}: {d.label}", flush=True)

    scenes = judging_scenes(args.data, args.subset, args.dead_leaves)

    def chosen(camera: tuple[str, str]) -> list[Denoiser]:
        return [DEFAULT] + ([best[camera]] if best[camera] != DEFAULT else [])
    judged = mean(evaluate(scenes, cameras, chosen, args.gains, progress="judging"))
    pair = tuple(c for c in (BAYER, LMS) if c in cameras)
    if args.crossover_gains and pair:
        judged.update(mean(evaluate(scenes, pair, chosen, args.crossover_gains, progress="crossover")))
    snr = panel_snrs({**{c: chosen(c) for c in cameras}, **({PAPER_BAYER: [DEFAULT]} if BAYER in cameras else {})},
                     args.seeds)

    run = Run(list(scenes), list(args.gains), list(args.crossover_gains), best, tuning, judged, snr, bound_scores,
              {s: len(v) for s, v in scenes.items()}, bound_images)
    minutes = (time.perf_counter() - t0) / 60
    argv_used = sys.argv[1:] if argv is None else argv
    command = ("python tools/lms_wins.py " + " ".join(shlex.quote(a) for a in argv_used)).strip()
    facts = run_facts(minutes)
    if args.csv is not None:
        toolkit.write_csv(csv_rows(run, command, facts), args.csv)
    if cameras != CAMERAS:
        print(f"a part ({', '.join(c[0] for c in cameras)}): the whole section comes from --from-csv over every "
              "part's CSV; this part's alone:")
    text = markdown(run, command, minutes, facts, args.section)
    print(text)
    if args.results is not None:
        toolkit.update_results(args.results, text, args.section)
        print(f"wrote the {args.section} section of {args.results}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
