"""The scene measured before anything is decided: :func:`measure_scene` takes a raw and the
estimates a run asks for (``--wb``, the noise, white balance pass 2, ``--auto-exposure``) and gives
a :class:`Scene`, which the pipeline's decisions (clisp.pipeline.build) read instead of the raw.

Each estimate still reads the mosaic on its own (pass 1's grey pixels or plausible lights, the
noise's crops, pass 2's thumbnail, the exposure's tile colours); one statistics pass feeding all
of them is issue 42's item 2, and its table would be a field of :class:`Scene`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ..errors import ClispError, clip
from ..io.rawimage import MAX_GAIN, RawImage
from .noise import NoiseEstimateError, raw_noise
from .white_balance import with_white_balance
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
    """

    raw: RawImage
    noise: Any
    gains2: np.ndarray
    exposure: float


def measure_scene(raw: RawImage, wb: str = "camera", wb2: str = "metadata", noise: bool = False,
                  exposure: float = 0.0, auto_exposure: bool = False, limit: float = 10.0) -> Scene:
    """The :class:`Scene` of ``raw``: pass 1's multipliers by ``wb`` (clisp.scene.white_balance),
    the noise when ``noise`` (its model, else estimated), pass 2's gains by ``wb2``, and the
    exposure (``exposure`` EV plus LibRaw's auto-bright estimate when ``auto_exposure``: clisp.scene.
    exposure). ClispError naming the raw for estimates it cannot serve."""
    raw = with_white_balance(raw, wb)
    measured = None
    if noise:
        try:
            measured = raw_noise(raw)
        except NoiseEstimateError:
            measured = None      # a raw too small to estimate its noise is processed without chroma denoise
    gains2 = wb2_gains(raw, wb2)
    if auto_exposure:
        from .exposure import auto_exposure_ev      # deferred: only --auto-exposure estimates
        exposure = float(np.clip(exposure + auto_exposure_ev(raw, gains2, limit), -limit, limit))
    return Scene(raw, measured, gains2, exposure)


def wb2_gains(raw: RawImage, method: str) -> np.ndarray:
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
