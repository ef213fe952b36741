"""Noise-adaptive stage choice (issue 30): the cheapest demosaic whose expected error at the raw's
noise is within the budget of the preset's.

Noise hides detail: where it is high, the steps a demosaic spends on fine detail buy nothing, and
a cheaper configuration scores the same. The noise is known before processing (the sensor model
of clisp's simulations, else the raw's own estimate, clisp.scene.noise), so the choice is made
once per image when the pipeline is built, and every tile runs the chosen stages (tiled still
equals whole).

Noise measure: ``sigma`` = the noise std of the white-balanced reference channel (G for Bayer, L
for LMS) at 18 % grey, white = 1 (:func:`noise_sigma`); the simulated sensor gives 0.0052 at gain 1,
0.0209 at gain 16 and 0.0436 at gain 64.

Each :class:`Alternative` (ALTERNATIVES) carries its calibration: the PSNR change (alternative minus
the preset's stage, mean and worst over the calibration scenes) at measured noise levels. The rule: the
alternative is taken when the raw's sigma is at or above the alternative's threshold
(:meth:`Alternative.threshold`): the lowest calibrated sigma from which on, at every calibrated
sigma, the mean change is at least -ERROR_BUDGET_DB and the worst at least -WORST_BUDGET_DB.
The calibration scenes are made in code (dead leaves, clisp's demo chart, a sky), so the Kodak and
McMaster sets, which judge the choice, tuned nothing. Regenerate: ``python
tools/calibrate_skip.py --choice``.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Callable

import numpy as np

from ..engine.stage import Stage
from ..io.rawimage import RawImage
from ..scene.white_balance import reference_channel

ERROR_BUDGET_DB = 0.02
"""Largest mean PSNR loss against the preset's stage the choice accepts (dB)."""
WORST_BUDGET_DB = 0.1
"""Largest PSNR loss on any one calibration scene the choice accepts (dB)."""
REFERENCE_LEVEL = 0.18
"""Signal (white-balanced, white = 1) at which the noise is measured: mid-grey."""
SIGMA_TOLERANCE = 0.01
"""A raw's sigma within this share below a threshold counts as at it (the calibration rows hold
sigma to 4 digits: a raw of the calibrated gain must not miss its own row by rounding)."""


def noise_sigma(noise: Any, reference: int) -> float:
    """Noise std of channel ``reference`` at REFERENCE_LEVEL (``noise``: a ChannelNoise)."""
    return float(np.sqrt(max(float(noise.variance(reference, REFERENCE_LEVEL)), 0.0)))


@dataclass(frozen=True)
class Alternative:
    """A cheaper configuration of one demosaic stage, and its calibration.

    ``stage``: the class name of the stage it replaces; ``make``: the cheaper stage from the
    preset's; ``calibration``: rows (sigma, mean dB, worst dB) of PSNR(alternative) - PSNR(preset's)
    (tools/calibrate_skip.py --choice); ``cost``: its device time relative to the stage it replaces.
    """

    name: str
    stage: str
    make: Callable[[Stage], Stage]
    calibration: tuple[tuple[float, float, float], ...]
    cost: float

    def threshold(self) -> float:
        """The lowest calibrated sigma from which on every calibrated row is within budget
        (inf when the highest is not)."""
        rows = sorted(self.calibration)
        sigma = float("inf")
        for s, mean, worst in reversed(rows):
            if mean < -ERROR_BUDGET_DB or worst < -WORST_BUDGET_DB:
                break
            sigma = s
        return sigma


def _one_pass(stage: Stage) -> Stage:
    return replace(stage, params=replace(stage.params, passes=1))  # type: ignore[arg-type]


ALTERNATIVES: tuple[Alternative, ...] = (
    Alternative(
        name="guided, one pass", stage="DemosaicLMSGuided", make=_one_pass, cost=0.75,
        calibration=((0.0052, -0.668, -2.599), (0.0103, -0.358, -1.425), (0.0147, -0.215, -0.851),
                     (0.0209, -0.105, -0.433), (0.0258, -0.071, -0.310), (0.0300, -0.048, -0.206),
                     (0.0373, -0.028, -0.129), (0.0436, -0.016, -0.075)),
    ),
)
"""The alternatives, each with its calibration. Provenance: ``python tools/calibrate_skip.py
--choice`` (2026-11-26; 512 x 512 scenes made in code: four dead-leaves charts, the demo chart, a
sky; simulated at gains 1, 4, 8, 16, 24, 32, 48, 64, seed per scene; quality preset otherwise).
The worst scene is the demo chart (fine text) throughout. Measured and left out: bilinear in place
of the Bayer RI demosaic loses 0.48 dB on average at gain 64 (3.6 on the demo chart), so
no Bayer alternative qualifies yet. ``cost``: device time of the one-pass stage over the two-pass
one, 1.003 s against 1.341 s on a 12 MP Kodak collage at gain 64 (``clisp process --profile``)."""


@dataclass(frozen=True)
class Choice:
    """What :func:`choose_demosaic` decided, for ``--explain``."""

    stage: str
    alternative: str | None
    sigma: float
    threshold: float

    def explain(self) -> str:
        taken = (f"{self.alternative} (noise {self.sigma:.4f} at 18 % grey >= {self.threshold:.4f}: "
                 f"within {ERROR_BUDGET_DB:g} dB of the full stage there)") if self.alternative else \
            (f"the full stage (noise {self.sigma:.4f} at 18 % grey < {self.threshold:.4f})")
        return f"noise-adaptive choice: {self.stage} -> {taken}"


def alternative_for(stage: Stage | type[Stage]) -> Alternative | None:
    """The alternative of ``stage``'s kind (a stage or its class), if any."""
    name = stage.__name__ if isinstance(stage, type) else type(stage).__name__
    return next((a for a in ALTERNATIVES if a.stage == name), None)


def choose_demosaic(stage: Stage, raw: RawImage, noise: Any) -> tuple[Stage, Choice | None]:
    """``stage`` or its cheaper alternative for ``raw`` whose channel noise is ``noise``, and the
    choice (None when ``stage`` has no alternative)."""
    alternative = alternative_for(stage)
    if alternative is None:
        return stage, None
    sigma = noise_sigma(noise, reference_channel(raw.cfa))
    threshold = alternative.threshold()
    if sigma >= threshold * (1.0 - SIGMA_TOLERANCE):
        return alternative.make(stage), Choice(type(stage).__name__, alternative.name, sigma, threshold)
    return stage, Choice(type(stage).__name__, None, sigma, threshold)
