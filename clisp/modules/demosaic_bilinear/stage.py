"""Bilinear demosaic for any CFA by normalised convolution.

Channel c keeps its measured sample at its own sites; elsewhere it is the tent-weighted mean of the
c samples within radius r_c, the tent being (r_c+1-|dy|)(r_c+1-|dx|). r_c is the channel's covering
radius from the CFA description (Bayer: 1 for R, G, B, which reproduces classic bilinear exactly;
LMS: 1 for L and M, 2 for the 1-in-8 S). Halo = max r_c.

The reference below is the normalised convolution itself. On OpenCL the same operator runs as a
per-phase linear filter (clisp/modules/linear_filter), whose weights are derived here from the CFA.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...cfa import CFA
from ...engine.runtime import DeviceImage, Runtime
from ...engine.stage import Stage
from ..linear_filter.stage import LinearPhaseFilter, tap_channels, tap_offsets


def tent(radius: int) -> np.ndarray:
    """(2R+1) x (2R+1) separable tent weights (R+1-|dy|)(R+1-|dx|), unnormalised, float64."""
    w = radius + 1 - np.abs(np.arange(-radius, radius + 1))
    return np.outer(w, w).astype(np.float64)


@dataclass
class DemosaicBilinear(Stage):
    """H x W white-balanced mosaic -> H x W x n_channels camera image (L,M,S or R,G,B)."""

    cfa: CFA
    name = "demosaic_bilinear"
    in_channels = 1
    out_channels = 3

    @property
    def radii(self) -> np.ndarray:
        return np.array([self.cfa.covering_radius(c) for c in range(self.cfa.n_channels)], dtype=np.int32)

    @property
    def halo(self) -> int:
        return int(self.radii.max())

    def reference(self, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
        h, w = x.shape
        r = self.halo
        channel = self.cfa.channel_map(h, w, origin)
        x = x.astype(np.float64)
        out = np.empty((h - 2 * r, w - 2 * r, self.cfa.n_channels))
        for c, radius in enumerate(self.radii):
            mask = (channel == c).astype(np.float64)
            from scipy import ndimage      # reference only; scipy costs 0.15 s of start-up
            num = ndimage.correlate(x * mask, tent(int(radius)), mode="constant")
            den = ndimage.correlate(mask, tent(int(radius)), mode="constant")
            plane = np.where(mask > 0, x, num / np.maximum(den, 1e-30))
            out[..., c] = plane[r:h - r, r:w - r]
        return out

    def as_phase_filter(self) -> LinearPhaseFilter:
        """The same operator as per-phase weights (P*P, n_channels, (2R+1)^2), zero bias."""
        r = self.halo
        ch = tap_channels(self.cfa, r)                                  # (K, T)
        offsets = tap_offsets(r)
        centre = len(offsets) // 2
        k_count, n = ch.shape[0], self.cfa.n_channels
        weights = np.zeros((k_count, n, len(offsets)))
        for c, radius in enumerate(self.radii):
            t = tent(int(radius)) if radius == r else np.pad(tent(int(radius)), r - int(radius))
            tent_taps = t.ravel()
            for k in range(k_count):
                if ch[k, centre] == c:
                    weights[k, c, centre] = 1.0
                else:
                    wk = tent_taps * (ch[k] == c)
                    weights[k, c] = wk / wk.sum()
        return LinearPhaseFilter(self.cfa, r, weights, np.zeros((k_count, n)), basis=weights, mix=np.eye(n))

    def fuse(self, following: Stage) -> Stage | None:
        return self.as_phase_filter().fuse(following)

    def enqueue(self, rt: Runtime, src: DeviceImage, origin: tuple[int, int]) -> DeviceImage:
        return self.as_phase_filter().enqueue(rt, src, origin)
