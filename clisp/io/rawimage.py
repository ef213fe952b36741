"""The in-memory raw image: mosaic data plus everything the pipeline needs to process it."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..cfa import CFA
from ..errors import ClispError


@dataclass
class RawImage:
    """A CFA mosaic and its processing metadata.

    data          H x W mosaic in sensor DN: uint16 (quantised) or float32 (noiseless simulation:
                  no quantisation, no clipping). Black pedestal included.
    cfa           the colour filter array; channel of pixel (y, x) is cfa.pattern[y % p, x % p].
    black_level   per-channel black level in DN, shape (n_channels,).
    white_level   saturation level in DN.
    wb            white-balance pass-1 multipliers per CFA channel (as shot), shape (n_channels,).
    exposure      extra linear gain applied in pass 1 (the simulator's 1/k_exp; 1 for camera raws).
    colour_matrix 3 x 3, white-balanced camera channels -> linear sRGB (D65).
    wb2           white-balance pass-2 gains on linear sRGB, shape (3,); identity by default.
    metadata      free-form facts kept on the round trip (gain, noise model, simulation settings).
    source        file name or 'simulated', used in messages.
    """

    data: np.ndarray
    cfa: CFA
    black_level: np.ndarray
    white_level: float
    wb: np.ndarray
    colour_matrix: np.ndarray
    exposure: float = 1.0
    wb2: np.ndarray = field(default_factory=lambda: np.ones(3))
    metadata: dict[str, Any] = field(default_factory=dict)
    source: str = "array"

    def __post_init__(self) -> None:
        self.black_level = np.broadcast_to(np.asarray(self.black_level, dtype=np.float64),
                                           (self.cfa.n_channels,)).copy()
        # np.array copies: callers often pass module constants, which must never be aliased.
        self.wb = np.array(self.wb, dtype=np.float64).reshape(self.cfa.n_channels)
        self.colour_matrix = np.array(self.colour_matrix, dtype=np.float64).reshape(3, 3)
        self.wb2 = np.array(self.wb2, dtype=np.float64).reshape(3)
        if self.data.ndim != 2:
            raise ValueError(f"{self.source}: raw data must be H x W, got shape {self.data.shape}")

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.data.shape[0]), int(self.data.shape[1]))

    def pass1_gains(self) -> np.ndarray:
        """Multipliers per CFA channel that take black-subtracted, white-normalised data to
        white-balanced camera values (WB pass 1 times exposure), shape (n_channels,)."""
        return self.wb * self.exposure


NO_CAMERA_WB = "none: the file has no camera white balance"
"""``metadata['wb_source']`` of a raw read without usable as-shot multipliers (the Canon D30 CRW):
its ``wb`` holds the daylight multipliers (or ones) as placeholders, and a run's ``--wb camera``
estimates the light (clisp.scene.white_balance.with_white_balance)."""

MAX_GAIN = 1e4
"""Largest white-balance or exposure multiplier (and smallest: its inverse) a raw may carry; past
it the float32 kernels' intermediates (squares in the guided filters) leave their precision."""

FLOAT_RANGE = 2.0**20
"""Float raws (noiseless simulations) may exceed the white level, not beyond FLOAT_RANGE times the
black-to-white span (an unclipped highlight 10^6 times white is corrupt data, and its square
would leave float32's range in the guided filters)."""

_SCAN_ROWS = 256
"""Rows of a (memory-mapped) float raw checked at once by :func:`check_samples`."""


def check_levels(raw: RawImage) -> str | None:
    """What is wrong with ``raw``'s levels and gains (black, white, WB passes, exposure, colour
    matrix), as a short phrase, or None when the pipeline can use them: finite, black below white,
    gains within [1/MAX_GAIN, MAX_GAIN]. Read as Python floats: a dozen numbers, where numpy's
    reductions cost about 70 us of every call (a fifth of a small raw's host time).

    >>> from dataclasses import replace
    >>> from clisp.cfa import bayer_cfa
    >>> raw = RawImage(np.zeros((2, 2), np.uint16), bayer_cfa(), np.full(3, 64.0), 1023.0, np.ones(3), np.eye(3))
    >>> check_levels(raw) is None, check_levels(replace(raw, wb=np.array([1.0, 0.0, 1.0])))
    (True, 'white balance 1, 0, 1 outside 0.0001..10000')
    """
    black, white = _floats(raw.black_level), float(raw.white_level)
    if not all(map(math.isfinite, black)) or not math.isfinite(white):
        return "black or white level is not a finite number"
    if white <= max(black):
        return f"white level {white:g} is not above the black level {max(black):g}"
    for name, values in (("white balance", raw.wb), ("exposure", raw.exposure), ("white balance pass 2", raw.wb2)):
        gains = _floats(values)
        if not all(1.0 / MAX_GAIN <= g <= MAX_GAIN for g in gains):        # also NaN
            return f"{name} {', '.join(f'{g:.4g}' for g in gains[:3])} outside {1 / MAX_GAIN:g}..{MAX_GAIN:g}"
    m = _floats(raw.colour_matrix)
    if not all(math.isfinite(v) and abs(v) <= MAX_GAIN for v in m):
        return "colour matrix is not finite or has entries beyond 1e4"
    return None


def _floats(values: Any) -> list[float]:
    """``values`` (a number or an array of any shape) as a flat list of Python floats."""
    return np.ravel(np.asarray(values, dtype=np.float64)).tolist()


def check_samples(raw: RawImage) -> None:
    """ClispError naming ``raw.source`` when a float raw holds NaN or infinite samples, or samples
    beyond FLOAT_RANGE (corrupt data; the kernels would turn them into NaN/Inf pixels). Integer
    raws hold nothing the pipeline cannot take. A memory-mapped raw is scanned _SCAN_ROWS at a time."""
    data = raw.data
    if data.dtype.kind != "f":
        return
    span = float(raw.white_level) - float(np.min(raw.black_level))
    lo = float(np.min(raw.black_level)) - FLOAT_RANGE * abs(span)
    hi = float(np.max(raw.black_level)) + FLOAT_RANGE * abs(span)
    bad = far = 0
    for y in range(0, data.shape[0], _SCAN_ROWS):
        rows = np.asarray(data[y:y + _SCAN_ROWS])
        finite = np.isfinite(rows)
        bad += int(rows.size - np.count_nonzero(finite))
        far += int(np.count_nonzero(finite & ((rows < lo) | (rows > hi))))
    total = data.shape[0] * data.shape[1]
    if bad:
        raise ClispError(f"{raw.source}: {bad} of {total} samples are NaN or infinite (corrupt float raw); "
                         f"not processed")
    if far:
        raise ClispError(f"{raw.source}: {far} of {total} samples lie beyond {FLOAT_RANGE:g} times the "
                         f"white level (corrupt float raw); not processed")
