"""Malvar-He-Cutler gradient-corrected linear demosaic (Bayer layout, any doubled channel).

H. S. Malvar, L.-W. He and R. Cutler, "High-quality linear interpolation for demosaicing of
Bayer-patterned color images", Proc. IEEE ICASSP 2004, vol. 3, pp. 485-488.

A missing colour is the bilinear estimate corrected by a Laplacian of the channel measured at the
pixel; the paper publishes the result as four 5 x 5 kernels (scaled by 1/8), used per Bayer site:

    G at R or B sites                         ``G_AT_RB``
    R (B) at G sites in an R (B) row          ``RB_AT_G_SAME_ROW``
    R (B) at G sites in an R (B) column       ``RB_AT_G_SAME_COLUMN`` (the transpose)
    R at B sites, B at R sites                ``RB_AT_BR``

Measured samples are kept. The operator is linear, so on OpenCL it runs as a per-phase linear
filter (clisp/modules/linear_filter, halo 2), which also folds the preceding normalisation and white
balance and the following colour matrix into one kernel. :meth:`DemosaicMalvar.reference` is an
independent implementation (the four kernels convolved with the mosaic, picked per site by masks),
so the test compares two different derivations of the same operator.

Example: a flat mosaic stays flat (every kernel sums to 1)::

    >>> from clisp.cfa import bayer_cfa
    >>> out = DemosaicMalvar(bayer_cfa("GRBG")).reference(np.full((6, 7), 0.25), (0, 0))
    >>> out.shape, bool(np.allclose(out, 0.25))
    ((2, 3, 3), True)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...cfa import CFA
from ...errors import ClispError
from ...engine.runtime import DeviceImage, Runtime
from ...engine.stage import Stage
from ..linear_filter.stage import LinearPhaseFilter, tap_channels, tap_offsets

R, G, B = 0, 1, 2

G_AT_RB = np.array([
    [0, 0, -1, 0, 0],
    [0, 0, 2, 0, 0],
    [-1, 2, 4, 2, -1],
    [0, 0, 2, 0, 0],
    [0, 0, -1, 0, 0]]) / 8.0
"""Malvar et al. 2004, Fig. 2: G at an R site (and at a B site)."""

RB_AT_G_SAME_ROW = np.array([
    [0, 0, 0.5, 0, 0],
    [0, -1, 0, -1, 0],
    [-1, 4, 5, 4, -1],
    [0, -1, 0, -1, 0],
    [0, 0, 0.5, 0, 0]]) / 8.0
"""Malvar et al. 2004, Fig. 2: R at a G site whose row holds R (B likewise for B rows)."""

RB_AT_G_SAME_COLUMN = RB_AT_G_SAME_ROW.T
"""Malvar et al. 2004, Fig. 2: R at a G site whose column holds R (B likewise)."""

RB_AT_BR = np.array([
    [0, 0, -1.5, 0, 0],
    [0, 2, 0, 2, 0],
    [-1.5, 0, 6, 0, -1.5],
    [0, 2, 0, 2, 0],
    [0, 0, -1.5, 0, 0]]) / 8.0
"""Malvar et al. 2004, Fig. 2: R at a B site (and B at an R site)."""

RADIUS = 2
"""Half-size of the 5 x 5 kernels: the stage's halo."""


def check_bayer(cfa: CFA, what: str) -> None:
    """Raise ClispError unless ``cfa`` has the Bayer layout (clisp.cfa.layout_of: 2 x 2, one channel
    doubled on a diagonal, the other two once): RGB Bayer in any of its four phases, L, M, S on it
    (lms-bayer), or another channel doubled (``ML/LS``: L doubled). The Bayer demosaics interpolate
    the channels by their roles (clisp.cfa CFA.bayer_roles: the doubled one as G)."""
    if cfa.layout != "bayer" or cfa.n_channels != 3:
        raise ClispError(f"{what} needs a Bayer CFA (RGGB, GRBG, GBRG or BGGR), got {cfa.name}")


def channel_order(rgb: np.ndarray, cfa: CFA) -> np.ndarray:
    """A Bayer demosaic's H x W x 3 output in role order (R, G, B: clisp.cfa CFA.bayer_roles) in
    ``cfa``'s channel order; ``rgb`` itself where the two agree (RGB Bayer, lms-bayer).

    >>> from clisp.cfa import cfa_from_name
    >>> channel_order(np.array([[[1.0, 2.0, 3.0]]]), cfa_from_name("ML/LS")).tolist()   # R=M, G=L, B=S
    [[[2.0, 1.0, 3.0]]]
    """
    roles = cfa.bayer_roles
    return rgb if roles == (0, 1, 2) else rgb[..., np.argsort(roles)]


@dataclass
class DemosaicMalvar(Stage):
    """H x W white-balanced Bayer mosaic -> (H-4) x (W-4) x 3 camera RGB (Malvar-He-Cutler 2004)."""

    cfa: CFA
    name = "demosaic_malvar"
    in_channels = 1
    out_channels = 3

    def __post_init__(self) -> None:
        check_bayer(self.cfa, "the Malvar-He-Cutler demosaic")

    @property
    def halo(self) -> int:
        return RADIUS

    def reference(self, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
        """The published kernels by convolution, each kept where its Bayer site applies."""
        h, w = x.shape
        r = RADIUS
        x = x.astype(np.float64)
        channel = self.cfa.role_cfa().channel_map(h, w, origin)          # roles: R, G, B (check_bayer)
        row_has = [np.any(channel == c, axis=1)[:, None] for c in range(3)]   # rows holding c
        col_has = [np.any(channel == c, axis=0)[None, :] for c in range(3)]   # columns holding c

        def conv(kernel: np.ndarray) -> np.ndarray:
            from scipy import ndimage      # reference only; scipy costs 0.15 s of start-up
            return ndimage.correlate(x, kernel, mode="constant")

        g_at_rb, same_row, same_col, at_br = (conv(k) for k in (G_AT_RB, RB_AT_G_SAME_ROW,
                                                               RB_AT_G_SAME_COLUMN, RB_AT_BR))
        out = np.empty((h, w, 3))
        out[..., G] = np.where(channel == G, x, g_at_rb)
        for c, other in ((R, B), (B, R)):
            plane = np.where(channel == other, at_br, x)
            plane = np.where((channel == G) & row_has[c], same_row, plane)
            plane = np.where((channel == G) & col_has[c], same_col, plane)
            out[..., c] = plane
        return channel_order(out[r:h - r, r:w - r], self.cfa)

    def as_phase_filter(self) -> LinearPhaseFilter:
        """The same operator as per-phase weights (4 phases, 3 outputs, 25 taps), zero bias.

        Phase k's centre channel picks the kernel; for R/B at a G site the kernel is the one whose
        bilinear part reads the tap channel at (0, +-1) (same row) or at (+-1, 0) (same column).
        """
        ch = tap_channels(self.cfa.role_cfa(), RADIUS)                  # (4, 25) roles R, G, B
        offsets = [tuple(o) for o in tap_offsets(RADIUS)]
        centre, east, south = (offsets.index(o) for o in ((0, 0), (0, 1), (1, 0)))
        weights = np.zeros((ch.shape[0], 3, len(offsets)))
        for k in range(ch.shape[0]):
            here = ch[k, centre]
            for c in range(3):
                if c == here:
                    kernel = np.zeros((5, 5))
                    kernel[RADIUS, RADIUS] = 1.0
                elif c == G:
                    kernel = G_AT_RB
                elif here != G:
                    kernel = RB_AT_BR
                elif ch[k, east] == c:
                    kernel = RB_AT_G_SAME_ROW
                elif ch[k, south] == c:
                    kernel = RB_AT_G_SAME_COLUMN
                else:  # pragma: no cover - excluded by check_bayer
                    raise ClispError(f"{self.cfa.name}: no Malvar kernel for {self.cfa.channels[c]}")
                weights[k, c] = kernel.ravel()
        weights = weights[:, np.argsort(self.cfa.bayer_roles)]          # outputs in channel order
        return LinearPhaseFilter(self.cfa, RADIUS, weights, np.zeros((ch.shape[0], 3)))

    def fuse(self, following: Stage) -> Stage | None:
        return self.as_phase_filter().fuse(following)

    def enqueue(self, rt: Runtime, src: DeviceImage, origin: tuple[int, int]) -> DeviceImage:
        if not hasattr(self, "_filter"):  # built once per stage, reused by every tile
            self._filter = self.as_phase_filter()
        return self._filter.enqueue(rt, src, origin)
