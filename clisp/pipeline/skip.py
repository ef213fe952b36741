"""Per-tile skip plans: which path each tile of a run takes, and why (issue 13).

A :class:`Skipper` is attached to a Pipeline by ``build_pipeline(..., skip=True)``. It holds the
scene analysis (clisp.scene.block_analysis) and the alternative stage lists ("paths"); when the pipeline runs
a TilePlan, :meth:`Skipper.plan` turns the analysis into a :class:`SkipPlan`, plain data: one
:class:`TileChoice` per tile (path, reason, the figures behind it), printable for
``clisp process --explain`` and testable.

Paths:

* ``full``  every stage as built (the chroma denoiser with the preset's J levels);
* ``light`` the chroma denoiser with LIGHT_LEVELS (1) Haar level: the same final full-resolution
  bilateral and level-1 shrink, no coarse levels; halo 10 px instead of 52 (J = 3);
* ``none``  the plain colour matrix instead of the denoiser;
* ``flat``  DemosaicFlat and the plain colour matrix instead of the demosaic and the denoiser
  (tiles with nothing but noise within the flat path's reach);
* ``mixed`` both at block granularity inside one tile (issue 30): the flat path over the whole
  tile, the tile's detail path (``full``, ``light`` or ``none``, by the rule below) only on
  rectangles around its texture blocks, joined per pixel by the distance to texture
  (clisp.modules.block_blend) before the stages every path shares. Taken where its modelled cost
  is at most MIX_GAIN of the detail path alone (:meth:`Skipper.mixed_rects`).

Rule, per tile: the predicted visible chroma noise of every analysis block the tile's output
depends on (the tile grown by the full denoiser's halo) is

    v_b = sqrt( mean_i  T'(rgb_i,b)^2  sum_k F_ik^2 var_k(Y_b) ) * excess

with var_k the denoiser's own level-0 chroma noise (its NoiseTable, from the sensor model or the
raw's estimate, through the actual demosaic) at the block's mean Y, F the space's chroma -> RGB
map, T' the slope of the sRGB encoding at the block's mean linear RGB (clamped to the linear
toe) and ``excess`` SceneAnalysis.noise_excess. v_b^2 is the chroma noise's contribution to the
tone-mapped MSE that PSNR measures, so thresholds on v are thresholds on the error budget. The
tile's v is the largest v_b: ``none`` below VISIBLE_NONE, ``light`` below VISIBLE_LIGHT, else
``full``. A tile is therefore never left undenoised unless every block it depends on is below
VISIBLE_NONE.

Blocks: a block has texture when its luminance detail or chroma activity reaches FLAT_DETAIL or
FLAT_CHROMA, or it holds clipped samples; ``flat`` and ``mixed`` use the flat path's output only
farther than its halo from every texture block, cross-fading over BLEND_RAMP px, so a tile is
``flat`` only when no texture block lies within that reach (:meth:`Skipper.block_blend`).

Device: where skipping cannot pay (a GPU, whose full path costs less than the analysis:
:func:`why_not_skip`), the CLI's default analyses nothing.

Seams: each tile's output equals the whole image processed on that tile's path (every path is a
stage list obeying the tiling contract), so tiles on different paths meet where the two paths'
outputs differ; both differ from ``full`` by at most the skip's effect, which the rule bounds by
the thresholds on both sides of the seam (the margin makes a tile's decision include its
neighbours' blocks within the halo). tests/pipeline/test_skip.py measures it.

Highlights: the plan flags every tile with clipped samples (``highlight``), which never takes
the flat path. The highlight stage (clisp.modules.highlights.stage, right after the demosaic, only in
pipelines of raws with clipped samples) is kept on every path: the flat path replaces the demosaic
and the denoiser around it.
"""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..scene.block_analysis import SceneAnalysis, analyse
from ..engine.tiling import Tile, TilePlan
from ..errors import ClispError
from ..modules.block_blend.blend import BlockBlend, rectangles
from ..modules.chroma_denoise.stage import ChromaDenoise
from ..modules.colour.stage import ColourMatrix
from ..modules.demosaic_flat.stage import DemosaicFlat
from ..modules.highlights.stage import HighlightClamp, Highlights

PATH_FULL, PATH_LIGHT, PATH_NONE, PATH_FLAT, PATH_MIXED = "full", "light", "none", "flat", "mixed"
PATHS = (PATH_FULL, PATH_LIGHT, PATH_NONE, PATH_FLAT, PATH_MIXED)
DETAIL_PATHS = (PATH_FULL, PATH_LIGHT, PATH_NONE)
"""The paths that run the preset's demosaic: a ``mixed`` tile runs one of them on its rectangles."""

FLAT_DETAIL = 2.0
"""Largest luminance detail (SceneAnalysis.detail: Laplacian energy of the cell means over what
the noise alone gives, ~1 on a flat field) of every block a ``flat`` tile depends on."""

FLAT_CHROMA = 2.0
"""Largest chroma activity (SceneAnalysis.chroma, the same ratio on the chroma planes) of every
block a ``flat`` tile depends on."""

LIGHT_MAX_FLAT_SHARE = 0.5
"""A tile takes ``light`` only when at most this share of its blocks is flat: flat areas are where
the coarse denoiser levels matter (calibrate_skip: -0.26 dB on the LMS sky with ``light``)."""

LIGHT_LEVELS = 1
"""Haar levels of the chroma denoiser on the ``light`` path."""

VISIBLE_LIGHT = 8.0e-3
"""Largest predicted visible chroma noise (tone-mapped std, white = 1) of a tile on the
``light`` path. Initial, conservative value: on flat grey fields (tools/calibrate_skip.py
--levels) v is 3.9-6.2e-3 at gain 1 (grey 0.9 down to 0.01, LMS and Bayer), 5.6-8.8e-3 at gain 2,
7.9-12.8e-3 at gain 4, 3-10e-2 at gain 64: at 8e-3 gain 1 takes ``light`` everywhere but in strongly saturated colours,
gain 2 only in bright areas, gain 4 and above never. Measured (tools/calibrate_skip.py): on
natural images at gain 1 the light path loses 0-0.04 dB, but on the flat sky 0.10 (Bayer) to
0.26 dB (LMS): flat areas need the coarse levels most, so this rule alone is not yet within the
error budget there (a flatness condition is the next step). Measured effect of the light path over whole images
(tools/calibrate_skip.py): see its docstring."""

VISIBLE_NONE = 1.0e-3
"""Largest predicted visible chroma noise of a tile left without chroma denoising: well under
1/4 of an 8-bit code, 1/4 of the lowest gain-1 figure: in practice never on the simulated sensor
(no denoising was measured to cost 0.1-0.7 dB at gain 1); left for cleaner sensors."""

FLAT_LOSES_TO = ("DemosaicRI", "DemosaicARI")
"""Full-path demosaics the flat path does not reach on flat fields, so a tile behind them never
takes it: residual interpolation follows a smooth gradient almost exactly where the flat path's
wide cell means blur it. Measured (issue 30; sky of tools/calibrate_skip.py, Bayer, PSNR of the
flat path's run against --no-skip): RI -0.43, -0.53, -0.69, -0.82 dB at gains 1, 4, 16, 64
(2048 x 1536); ARI -2.80 and -2.05 dB at gains 4 and 64 (1024 x 600), where DLMMSE gains +1.64
and +1.72, Malvar +1.27 and +1.44, and the guided LMS demosaic +0.06 to +0.25 (gains 1-64)."""

BLEND_RAMP = 32
"""Width (px) of the cross-fade from the detail path's output to the flat path's on a ``mixed``
tile (clisp.modules.block_blend): the two paths' grain meets over half a block, not at a line."""

FLAT_PATH_COST = 0.15
"""Device time per window pixel of the flat path's head (DemosaicFlat, highlights, colour matrix)
relative to the full path's (the preset's demosaic and chroma denoiser), for the choice between a
``mixed`` tile and the detail path alone. Measured (``clisp process --profile``, 12 MP LMS striped
sky, gain 1, 2-core Xeon, PoCL): the flat demosaic took 0.223 s on about 9 MP of mixed tiles,
the guided demosaic and the denoiser 2.04 s on 12 MP under --no-skip: 0.146 per pixel."""

MIX_GAIN = 0.85
"""A tile takes ``mixed`` only when its modelled cost (the flat path on the tile plus the detail
path on its rectangles, windows with their halos) is at most this share of the detail path alone:
the rest pays for the extra launches, uploads and the blend."""

RELATIVE_COST = {PATH_FULL: 1.0, PATH_LIGHT: 0.7, PATH_NONE: 0.0}
"""Declared device time of each detail path's chroma stage per pixel, relative to ``full`` (J = 3),
for the time-saved estimate of --explain (measured: tools/calibrate_skip.py --cost)."""


def flat_path(cfa: Any, stages: list[Any]) -> list[Any] | None:
    """The ``flat`` path of ``stages`` (the demosaic and the chroma denoiser replaced by
    DemosaicFlat and the plain colour matrix), or None where there is none: no denoiser, a CFA the
    flat demosaic does not serve, or a demosaic it does not reach on flat fields (FLAT_LOSES_TO)."""
    denoiser = next((s for s in stages if isinstance(s, ChromaDenoise)), None)
    if denoiser is None:
        return None
    i = stages.index(denoiser)
    flat, d = flat_demosaic(cfa), demosaic_index(stages, i)
    if flat is None or d < 0 or type(stages[d]).__name__ in FLAT_LOSES_TO:
        return None
    # the demosaic, then (highlights), then the denoiser
    return stages[:d] + [flat] + stages[d + 1:i] + [plain_colour(denoiser)] + stages[i + 1:]


def on_host_cpu(rt: Any) -> bool:
    """Whether ``rt``'s device is the host's CPU (PoCL) or ``rt`` is None (the NumPy reference)."""
    return rt is None or bool(rt.device.type & rt.cl.device_type.CPU)


def why_not_skip(rt: Any, cfa: Any = None, stages: list[Any] | None = None) -> str:
    """Why skipping cannot pay for its scene analysis ('' where it can), so the CLI's default runs
    none (build_pipeline's SKIP_WHERE_IT_PAYS):

    * on a device that is not the host's CPU (a GPU), the full path's device time is a few ms where
      the analysis costs tens of ms of host time. Measured (issue 30, 12 MP striped sky, LMS, NVIDIA
      H100 through its OpenCL): the guided demosaic's kernels took 6 ms and the chroma denoiser's
      1 ms of device time, the analysis 215 ms; the process took 1.16x of --no-skip. With the
      statistics pass on the device (issue 42) the host's part is the analysis from its tables, 31-44
      ms for 12 MP on a 2-core Xeon (clisp/scene/README.md): still more than the 7 ms it could save.
    * with ``stages`` given, where they have no flat path (:func:`flat_path`: behind RI or ARI, the
      Bayer quality and best presets): what is left, the denoiser's ``light`` and ``none`` paths,
      took no tile of any scene measured (issue 30's acceptance: striped sky, Kodak and McMaster
      collages, Bayer at gains 1, 16 and 64: PSNR identical to --no-skip, 1.02-1.12x its time).

    ``rt`` None (the NumPy reference) counts as the CPU."""
    if not on_host_cpu(rt):
        return (f"skipping is off on {rt.device.name.strip()} (not the host's CPU): its full path costs less "
                f"device time than the scene analysis would take on the host")
    if stages is not None and flat_path(cfa, stages) is None:
        return ("skipping is off: these stages have no flat path (the flat demosaic loses to residual "
                "interpolation on flat fields), and the denoiser's lighter paths alone never paid for the analysis")
    return ""


@dataclass(frozen=True)
class TileChoice:
    """One tile's path and why."""

    tile: Tile
    path: str
    reason: str
    visible_noise: float = 0.0
    highlight: bool = False
    flat: bool = False
    uniform: bool = False
    detail: str = ""
    """A ``mixed`` tile's detail path (full, light or none), run on ``rects``."""
    rects: tuple[Tile, ...] = ()
    """A ``mixed`` tile's rectangles (image px, inside the tile) where the detail path runs."""


@dataclass
class SkipPlan:
    """The per-tile plan of one run: data, printable (``str``) and testable."""

    choices: list[TileChoice]
    enabled: bool = True
    thresholds: dict[str, float] = field(default_factory=dict)
    note: str = ""

    def __post_init__(self) -> None:
        self._by_tile = {c.tile: c for c in self.choices}

    def path_of(self, tile: Tile) -> str:
        return self._by_tile[tile].path

    def choice(self, tile: Tile) -> TileChoice:
        return self._by_tile[tile]

    @property
    def counts(self) -> dict[str, int]:
        return dict(Counter(c.path for c in self.choices))

    def pixels(self, path: str) -> int:
        return sum(c.tile.h * c.tile.w for c in self.choices if c.path == path)

    @property
    def rects_count(self) -> int:
        """Rectangles of every ``mixed`` tile (where the detail path ran)."""
        return sum(len(c.rects) for c in self.choices)

    @property
    def detail_pixels(self) -> int:
        """Output pixels of those rectangles."""
        return sum(r.h * r.w for c in self.choices for r in c.rects)

    @property
    def highlight(self) -> bool:
        """Whether any tile has clipped samples (highlight handling needed)."""
        return any(c.highlight for c in self.choices)

    def explain(self) -> str:
        n = len(self.choices)
        total = max(1, sum(c.tile.h * c.tile.w for c in self.choices))
        head = "skip plan" if self.enabled else "skip plan (--no-skip: every stage everywhere)"
        lines = [f"{head}: {n} tiles" + (f"; {self.note}" if self.note else "")]
        if self.thresholds:
            lines.append("  thresholds: " + ", ".join(f"{k} {v:.2g}" for k, v in self.thresholds.items()))
        reasons = Counter((c.path, c.reason) for c in self.choices)
        for path in PATHS:
            k = self.counts.get(path, 0)
            if k:
                lines.append(f"  {path:<6} {k:4d} tiles, {100 * self.pixels(path) / total:5.1f} % of pixels")
                if path == PATH_MIXED:
                    lines.append(f"         the flat path on all of them, the detail path on {self.rects_count} "
                                 f"rectangles, {100 * self.detail_pixels / total:.1f} % of the image's pixels")
                for (p, reason), m in sorted(reasons.items()):
                    if p == path:
                        lines.append(f"         {m:4d} x {reason}")
        hl = sum(c.highlight for c in self.choices)
        lines.append(f"  highlight handling needed on {hl} tiles (clipped samples)"
                     if hl else "  highlight handling: not needed (nothing clipped)")
        flat = sum(c.flat for c in self.choices)
        uni = sum(c.uniform for c in self.choices)
        lines.append(f"  tiles without luminance detail {flat}, uniform tiles {uni} (uniform: no path of their own; "
                     f"they take flat)")
        return "\n".join(lines)

    __str__ = explain


def srgb_slope(v: np.ndarray) -> np.ndarray:
    """d/dv of the sRGB encoding at linear v, clamped to [toe, 1] (12.92 on the linear toe)."""
    v = np.clip(np.asarray(v, dtype=np.float64), 0.0031308, 1.0)
    return 1.055 / 2.4 * v ** (1.0 / 2.4 - 1.0)


def visible_chroma_noise(denoiser: Any, analysis: SceneAnalysis) -> np.ndarray:
    """v_b per analysis block (see the module docstring) for a ChromaDenoise stage."""
    space, table = denoiser.space, denoiser.noise
    f2 = denoiser.params.noise_scale ** 2
    y = np.maximum(analysis.luma, 0.0)
    var_k = np.stack([(table.approx[0, 1 + k, 0] * y + table.approx[0, 1 + k, 1]) * f2
                      for k in range(space.n_chroma)])                          # (n, rows, cols)
    var_rgb = np.tensordot(np.asarray(space.from_chroma) ** 2, var_k, axes=1)   # (3, rows, cols)
    rgb = np.tensordot(np.asarray(space.to_rgb), analysis.means, axes=1)        # block mean RGB
    mse = np.mean(srgb_slope(rgb) ** 2 * var_rgb, axis=0)
    return np.sqrt(mse) * analysis.noise_excess


def light_denoiser(stage: Any, levels: int = LIGHT_LEVELS) -> Any:
    """``stage`` (a ChromaDenoise) with ``levels`` Haar levels: its noise table's first levels
    (the calibration measures every level on the same fields, so the prefix is exact)."""
    levels = min(levels, stage.params.levels)
    return ChromaDenoise(stage.space, stage.noise.prefix(levels), replace(stage.params, levels=levels),
                         stage.interleaved)


def flat_demosaic(cfa: Any) -> Any:
    """The flat path's DemosaicFlat for ``cfa``, or None where it does not apply (not 3 channels).
    It reads the image's edges from each window's origin (clisp.engine.stage.Origin)."""
    try:
        return DemosaicFlat(cfa)
    except ClispError:
        return None


def plain_colour(stage: Any) -> Any:
    """The colour matrix the denoiser includes (its output with the chroma untouched)."""
    return ColourMatrix(np.asarray(stage.space.to_rgb))


def demosaic_index(stages: list[Any], denoiser_index: int) -> int:
    """Index of the demosaic in ``stages``: the stage before the chroma denoiser, or before the
    highlight stage that sits between them (-1 when there is none)."""
    d = denoiser_index - 1
    if d >= 0 and isinstance(stages[d], (Highlights, HighlightClamp)):
        d -= 1
    return d


@dataclass
class Skipper:
    """Analysis + alternative stage lists of one pipeline; :meth:`plan` makes a run's SkipPlan.

    stages    the full stage list (the pipeline's).
    paths     path name -> stage list (``full`` is ``stages``).
    denoiser  the ChromaDenoise stage of ``stages`` (None: nothing to skip).
    enabled   False (--no-skip): every tile takes ``full``; the analysis is still reported.
    image     the raw's (H, W): the flat path needs enough of the image in a window at its edges
              (:meth:`flat_window_fits`).
    """

    analysis: SceneAnalysis
    stages: list[Any]
    paths: dict[str, list[Any]]
    denoiser: Any = None
    enabled: bool = True
    visible_light: float = VISIBLE_LIGHT
    visible_none: float = VISIBLE_NONE
    image: tuple[int, int] | None = None

    @classmethod
    def for_pipeline(cls, raw: Any, stages: list[Any], enabled: bool = True,
                     analysis: SceneAnalysis | None = None) -> "Skipper":
        analysis = analysis if analysis is not None else analyse(raw)
        paths = {PATH_FULL: list(stages)}
        denoiser = next((s for s in stages if isinstance(s, ChromaDenoise)), None)
        if denoiser is not None:
            i = stages.index(denoiser)
            if denoiser.params.levels > LIGHT_LEVELS:
                paths[PATH_LIGHT] = stages[:i] + [light_denoiser(denoiser)] + stages[i + 1:]
            paths[PATH_NONE] = stages[:i] + [plain_colour(denoiser)] + stages[i + 1:]
            flat = flat_path(raw.cfa, stages)
            if flat is not None:
                paths[PATH_FLAT] = flat
        return cls(analysis, list(stages), paths, denoiser, enabled,
                   image=(int(raw.shape[0]), int(raw.shape[1])))

    def halo(self, path: str) -> int:
        return sum(stage.halo for stage in self.paths[path])

    def flat_reach(self) -> int:
        """How far (px) the flat path reads around a pixel from its demosaic on: its demosaic's halo and
        the later stages'. The stages before the demosaic (the sensor corrections) are every path's, so
        texture within their reach changes no path's choice; 0 without a flat path."""
        if PATH_FLAT not in self.paths:
            return 0
        path = self.paths[PATH_FLAT]
        d = next(i for i, stage in enumerate(path) if isinstance(stage, DemosaicFlat))
        return sum(stage.halo for stage in path[d:])

    def flat_window_fits(self, t: Tile, tile_h: int, tile_w: int) -> bool:
        """Whether the flat path's demosaic window for tile ``t`` (computing ``tile_h x tile_w``
        outputs) holds, along each axis where it crosses the image's edge, the stretch of image its
        point reflection reads (DemosaicFlat.min_inside_px). A narrower window, at the far edge of a
        last tile that keeps a few pixels, lacks cells the whole image has: that tile takes another
        path, so that tiles still equal the whole image."""
        if self.image is None or PATH_FLAT not in self.paths:
            return False
        flat = next(stage for stage in self.paths[PATH_FLAT] if isinstance(stage, DemosaicFlat))
        margin = self.flat_reach()            # the demosaic reads its window: its halo and the later stages'
        for start, size, extent in ((t.y0, tile_h, self.image[0]), (t.x0, tile_w, self.image[1])):
            lo, hi = start - margin, start + size + margin
            if (lo < 0 or hi > extent) and min(hi, extent) - max(lo, 0) < flat.min_inside_px:
                return False
        return True

    @property
    def head_length(self) -> int:
        """Stages of every path up to its chroma stage (the denoiser, or the plain colour matrix
        in its place): a ``mixed`` tile joins its two paths after them (paths replace stages one
        for one, so the index is every path's)."""
        return self.stages.index(self.denoiser) + 1

    def head(self, path: str) -> list[Any]:
        return self.paths[path][:self.head_length]

    @property
    def tail(self) -> list[Any]:
        """The stages after the chroma stage, shared by every path (white balance pass 2, tone curve)."""
        return self.stages[self.head_length:]

    def block_blend(self) -> BlockBlend | None:
        """The join of ``mixed`` tiles (clisp.modules.block_blend) for this analysis: the texture
        blocks (detail, chroma or clipping above the thresholds), the flat path's halo as its reach;
        None where no tile can mix (no flat path, or a tail with a halo: the join is per pixel)."""
        if PATH_FLAT not in self.paths or self.denoiser is None or any(st.halo for st in self.tail):
            return None
        a = self.analysis
        texture = (a.detail >= FLAT_DETAIL) | (a.chroma >= FLAT_CHROMA) | (a.clipped > 0)
        return BlockBlend(texture, a.block, self.flat_reach(), BLEND_RAMP)

    def mixed_head(self, path: str, blend: BlockBlend) -> list[Any]:
        """The head of ``path`` as a ``mixed`` tile runs it: the flat path's demosaic leaves out
        the texture blocks, whose output the detail path's replaces (weight 1 within the flat
        path's halo of texture, and the stages after the demosaic read less far than that)."""
        head = self.head(path)
        if path != PATH_FLAT:
            return head
        return [replace(stage, unread=blend.mask, block=blend.block) if isinstance(stage, DemosaicFlat) else stage
                for stage in head]

    def head_halo(self, path: str) -> int:
        return sum(stage.halo for stage in self.head(path))

    def mixed_rects(self, t: Tile, detail: str, support: np.ndarray, blend: BlockBlend) -> tuple[Tile, ...]:
        """The rectangles where tile ``t`` runs its ``detail`` path when mixing pays (its modelled
        cost, FLAT_PATH_COST per pixel of the flat path's window plus the rectangles' windows, at
        most MIX_GAIN of the detail path's window alone), else ()."""
        if self.image is None:
            return ()
        hd, hf = self.head_halo(detail), self.head_halo(PATH_FLAT)
        rects = rectangles(support, hd, blend.block, (t.y0, t.x0, t.h, t.w), self.image)
        mixed = FLAT_PATH_COST * (t.h + 2 * hf) * (t.w + 2 * hf) + sum((h + 2 * hd) * (w + 2 * hd)
                                                                      for _, _, h, w in rects)
        if not rects or mixed > MIX_GAIN * (t.h + 2 * hd) * (t.w + 2 * hd):
            return ()
        return tuple(Tile(*r) for r in rects)

    def plan(self, tiles: TilePlan | list[Tile]) -> SkipPlan:
        tile_list = tiles.tiles if isinstance(tiles, TilePlan) else list(tiles)
        a = self.analysis
        thresholds = {"visible_light": self.visible_light, "visible_none": self.visible_none,
                      "flat_detail": FLAT_DETAIL, "flat_chroma": FLAT_CHROMA}
        margin = self.denoiser.halo if self.denoiser is not None else 0
        vis = visible_chroma_noise(self.denoiser, a) if self.denoiser is not None else None
        flat_margin = self.flat_reach()
        blend = self.block_blend()
        support = blend.support() if blend is not None else None
        if blend is not None:
            thresholds["blend_ramp_px"] = BLEND_RAMP
        window = (tiles.tile_h, tiles.tile_w) if isinstance(tiles, TilePlan) else None
        choices = []
        for t in tile_list:
            rows, cols = a.blocks_for(t.y0, t.x0, t.h, t.w)
            highlight = bool((a.clipped[rows, cols] > 0).any())
            flat_blocks = a.detail[rows, cols] < FLAT_DETAIL
            flat, uniform = bool(flat_blocks.all()), bool(a.uniform[rows, cols].all())
            detail, rects = "", ()
            if vis is None:
                path, reason, v = PATH_FULL, "no chroma denoiser in this pipeline", 0.0
            else:
                grown = a.blocks_for(t.y0, t.x0, t.h, t.w, margin)
                v = float(vis[grown].max())
                fits = self.flat_window_fits(t, *(window or (t.h, t.w)))
                if support is not None:        # no texture block within the join's reach of the tile
                    flat_ok = fits and not support[rows, cols].any()
                else:
                    reach = a.blocks_for(t.y0, t.x0, t.h, t.w, flat_margin)
                    flat_ok = (PATH_FLAT in self.paths and bool((a.detail[reach] < FLAT_DETAIL).all())
                               and bool((a.chroma[reach] < FLAT_CHROMA).all()) and not (a.clipped[reach] > 0).any()
                               and fits)
                if not self.enabled:
                    path, reason = PATH_FULL, "--no-skip"
                elif flat_ok:
                    path, reason = PATH_FLAT, (f"no detail above the noise (luminance < {FLAT_DETAIL:g}x, "
                                               f"chroma < {FLAT_CHROMA:g}x, nothing clipped)")
                elif v < self.visible_none and PATH_NONE in self.paths:
                    path, reason = PATH_NONE, f"chroma noise below {self.visible_none:.1e} (invisible)"
                elif v < self.visible_light and PATH_LIGHT in self.paths \
                        and flat_blocks.mean() <= LIGHT_MAX_FLAT_SHARE:
                    path, reason = PATH_LIGHT, f"chroma noise below {self.visible_light:.1e} (coarse levels not needed)"
                else:
                    path, reason = PATH_FULL, "chroma noise visible" if v >= self.visible_light else \
                        "detail or flat areas that need every stage"
                if self.enabled and path in DETAIL_PATHS and support is not None and fits:
                    rects = self.mixed_rects(t, path, support, blend)
                    if rects:
                        detail, path = path, PATH_MIXED
                        reason = f"flat blocks on the flat path, texture on the {detail} path ({reason})"
            choices.append(TileChoice(t, path, reason, v, highlight, flat, uniform, detail, rects))
        note = f"visible chroma noise per block {np.min(vis):.1e}-{np.max(vis):.1e}" if vis is not None else ""
        return SkipPlan(choices, self.enabled, thresholds if vis is not None else {}, note)


def explain_run(pipeline: Any, stats: Any, profile: Any = None) -> str:
    """``clisp process --explain``: the analysis, the plan and, after the run, the time per stage
    and per path (OpenCL event profiling, when ``profile`` is a clisp.engine.profile.Profile) and
    the time the skips saved, estimated from RELATIVE_COST and the measured denoiser time. Without
    an analysis (nothing to skip, or skipping cannot pay: :func:`why_not_skip`) it says why."""
    skipper = getattr(pipeline, "skipper", None)
    plan = getattr(pipeline, "skip_plan", None)
    choice = getattr(pipeline, "stage_choice", None)
    statistics = getattr(pipeline, "scene_statistics", None)
    lines = [statistics.summary()] if statistics is not None else []
    if skipper is None:
        off = getattr(pipeline, "skip_off", "")
        lines.append(f"explain: no scene analysis ({off or 'nothing to skip: this pipeline has no chroma denoiser'})")
    else:
        lines.append(skipper.analysis.summary())
    if choice is not None:
        lines.append(choice.explain())
    if skipper is not None:
        lines.append(plan.explain() if plan is not None else "skip plan: none (nothing ran)")
    lines.append(f"run: {stats.seconds:.3f} s for {stats.megapixels:.2f} MP"
                 + (f" (analysis {skipper.analysis.seconds:.3f} s before it)" if skipper is not None else ""))
    if profile is not None:
        per_stage: dict[str, float] = {}
        for (stage, _kernel), (seconds, _n) in profile.device_seconds().items():
            per_stage[stage] = per_stage.get(stage, 0.0) + seconds
        lines.append("  device time per stage:")
        for stage, seconds in sorted(per_stage.items(), key=lambda kv: -kv[1]):
            lines.append(f"    {stage:<28}{seconds:8.3f} s")
        per_path = {p: v for p, v in profile.path_seconds().items() if p != "-"}
        if per_path:
            lines.append("  device time per path (the pixels each took; the shared stages of mixed tiles apart):")
            for path, seconds in sorted(per_path.items(), key=lambda kv: -kv[1]):
                lines.append(f"    {path:<36}{seconds:8.3f} s")
        if plan is not None and skipper is not None:
            lines.append("  " + time_saved(plan, per_stage, skipper))
    return "\n".join(lines)


def time_saved(plan: SkipPlan, per_stage: dict[str, float], skipper: Skipper) -> str:
    """The device time the skips saved in one run, estimated from the run itself: the full path's
    demosaic and chroma-denoise cost per pixel (measured on the tiles and rectangles that ran them;
    the denoiser's per path weighted by RELATIVE_COST) times the pixels that skipped them, less what
    the flat path's own stages and the block blend took. Halos are not counted (an estimate: the
    exact figure is the run against --no-skip). Without such pixels in the run it cannot be estimated."""
    demosaic = skipper.stages[demosaic_index(skipper.stages, skipper.stages.index(skipper.denoiser))].name \
        if skipper.denoiser else None
    ran: dict[str, int] = {p: plan.pixels(p) for p in DETAIL_PATHS}        # pixels per detail path
    skipped = plan.pixels(PATH_FLAT)                                     # pixels without the demosaic
    for c in plan.choices:
        if c.path == PATH_MIXED:
            inside = sum(r.h * r.w for r in c.rects)
            ran[c.detail] += inside
            skipped += c.tile.h * c.tile.w - inside
    ran_demosaic = sum(ran.values())
    units = sum(RELATIVE_COST[p] * n for p, n in ran.items())
    if demosaic is None or ran_demosaic == 0 or units == 0:
        return "time saved: not measurable in this run (no tile ran the full stages; compare with --no-skip)"
    t_dem = per_stage.get(demosaic, 0.0) / ran_demosaic
    t_den = per_stage.get("chroma_denoise", 0.0) / units
    skipped_dem = skipped * t_dem
    skipped_den = (skipped + sum((1.0 - RELATIVE_COST[p]) * n for p, n in ran.items())) * t_den
    flat_cost = per_stage.get("demosaic_flat", 0.0) + per_stage.get("block_blend", 0.0)
    saved = skipped_dem + skipped_den - flat_cost
    return (f"time saved (estimate from this run's own full-path pixels, halos not counted): {saved:.3f} s of "
            f"device time ({skipped_dem:.3f} s demosaic + {skipped_den:.3f} s chroma denoise skipped, "
            f"{flat_cost:.3f} s flat path and block blend)")
