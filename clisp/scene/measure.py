"""The scene measured before anything is decided: :func:`measure_scene` takes a raw and the
estimates a run asks for (``--wb``, the noise, white balance pass 2, ``--auto-exposure``) and gives
a :class:`Scene`, which the pipeline's decisions (clisp.pipeline.build) read instead of the raw.

The mosaic is read once, by the statistics pass (clisp.scene.statistics), and every estimate reads
its tables: pass 1's plausible lights or grey pixels, pass 2's gray world and gray pixels and the
exposure read its cell thumbnail, the noise estimate of a camera raw its noise strips, and the
skip planner's analysis (clisp.scene.block_analysis) its block table. A run that asks for none of
them (a simulated raw with its own white balance and noise model, no skip analysis) reads nothing.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import ClispError, clip
from ..io.rawimage import MAX_GAIN, RawImage
from .noise import NoiseEstimateError, has_noise_model, raw_noise
from .white_balance import has_camera_wb, with_white_balance
from .statistics import SceneStatistics
from .statistics_device import scene_statistics
from .white_balance_pass2 import estimate_wb2


@dataclass
class Scene:
    """What :func:`measure_scene` found.

    raw        the raw with ``--wb``'s pass-1 multipliers (``metadata['wb_source']`` says which).
    noise      ChannelNoise of its white-balanced channels (clisp.scene.noise), None when not asked
               for or when the raw is too small to estimate it.
    gains2     white balance pass 2's gains on linear sRGB, shape (3,).
    exposure   the exposure in EV: ``--exposure`` plus ``--auto-exposure``'s estimate, within
               +-``limit``.
    statistics the raw's SceneStatistics (clisp.scene.statistics) when an estimate read them, else
               None; :meth:`measured` gives them, measuring them once when none did.
    """

    raw: RawImage
    noise: Any
    gains2: np.ndarray
    exposure: float
    statistics: SceneStatistics | None = None
    runtime: Any = None
    """The runtime whose device measures the statistics (None: the NumPy reference)."""

    def measured(self, cells: bool = False, table: bool = True) -> SceneStatistics:
        """The raw's statistics, measured now if no estimate needed them yet (then kept); ``cells``:
        with the cell thumbnail read in the same pass (the estimates that read it ask for it).
        ``table`` False: the caller reads the thumbnail alone and no later estimate of the run will
        ask for more, so the reference may read just that (clisp.scene.statistics.thumbnail_statistics);
        should one ask after all, the whole pass runs then."""
        if self.statistics is None or (table and not self.statistics.complete):
            self.statistics = scene_statistics(self.raw, self.runtime, cells, table)
        return self.statistics


def measure_scene(raw: RawImage, wb: str = "camera", wb2: str = "metadata", noise: bool = False,
                  exposure: float = 0.0, auto_exposure: bool = False, limit: float = 10.0,
                  runtime: Any = None) -> Scene:
    """The :class:`Scene` of ``raw``: pass 1's multipliers by ``wb`` (clisp.scene.white_balance),
    the noise when ``noise`` (its model, else estimated), pass 2's gains by ``wb2``, and the
    exposure (``exposure`` EV plus LibRaw's auto-bright estimate when ``auto_exposure``: clisp.scene.
    exposure). Every estimate reads the raw's statistics (clisp.scene.statistics), measured once, on
    first need, on ``runtime``'s device when given (clisp.scene.statistics.statistics_runtime), else
    by the NumPy reference. ClispError naming the raw for estimates it cannot serve."""
    scene = Scene(raw, None, np.ones(3), exposure, runtime=runtime)
    estimated = wb == "auto" or (wb == "camera" and not has_camera_wb(raw))
    thumbnail = estimated or auto_exposure or wb2 != "metadata"      # the estimates that read the cells
    table = noise and not has_noise_model(raw)                         # the noise estimate reads the strips
    scene.raw = with_white_balance(raw, wb, scene.measured(thumbnail, table) if estimated else None)
    raw = scene.raw
    if noise:
        try:
            scene.noise = raw_noise(raw, statistics=None if has_noise_model(raw) else scene.measured(thumbnail))
        except NoiseEstimateError:
            scene.noise = None    # a raw too small to estimate its noise is processed without chroma denoise
    scene.gains2 = wb2_gains(raw, wb2, None if wb2 == "metadata" else scene.measured(thumbnail, table))
    if auto_exposure:
        from .exposure import auto_exposure_ev      # deferred: only --auto-exposure estimates
        scene.exposure = float(np.clip(exposure + auto_exposure_ev(raw, scene.gains2, limit,
                                                                   scene.measured(thumbnail, table)), -limit, limit))
    return scene


def wb2_gains(raw: RawImage, method: str, statistics: SceneStatistics | None = None) -> np.ndarray:
    """estimate_wb2's gains (from ``statistics`` where given), refused (ClispError naming the raw)
    when not finite and positive: a gray-world estimate of a black frame, or a corrupt illuminant
    in the metadata."""
    try:
        gains = np.asarray(estimate_wb2(raw, method, statistics), dtype=np.float64).reshape(3)
    except ClispError as exc:
        raise ClispError(f"{raw.source}: {clip(exc, 120)}") from exc
    except (TypeError, ValueError, np.linalg.LinAlgError) as exc:
        raise ClispError(f"{raw.source}: white balance pass 2 from the metadata failed ({clip(exc)})") from exc
    if not np.all(np.isfinite(gains)) or np.any(gains < 1.0 / MAX_GAIN) or np.any(gains > MAX_GAIN):
        raise ClispError(f"{raw.source}: white balance pass 2 ({method}) gives unusable gains "
                         f"{', '.join(f'{g:.3g}' for g in gains)}")
    return gains
