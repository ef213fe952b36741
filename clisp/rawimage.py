"""The in-memory raw image: mosaic data plus everything the pipeline needs to process it."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .cfa import CFA


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
