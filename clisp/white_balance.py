"""White-balance estimation on the raw mosaic (pass 1, docs/model.md section 4).

Gray world: gain_c = mean(reference channel) / mean(channel c), over the CFA blocks that hold no
clipped pixel (a clipped pixel's block is dropped with it, so clipping cannot bias a channel).
The reference channel is G for Bayer and L for LMS, whose gain is therefore 1.
"""
from __future__ import annotations

import numpy as np

from .cfa import CFA
from .errors import ClispError

CLIP_FRACTION = 0.98
"""A pixel at or above black + 0.98 (white - black) counts as clipped."""


def reference_channel(cfa: CFA) -> int:
    """Index of the channel whose gain is 1: G for Bayer, L (the first) otherwise."""
    return cfa.channels.index("G") if "G" in cfa.channels else 0


def gray_world_gains(data: np.ndarray, cfa: CFA, black_level: np.ndarray, white_level: float) -> np.ndarray:
    """Gray-world pass-1 multipliers per CFA channel, shape (n_channels,), reference channel = 1.

    ``data``: H x W mosaic in DN (black included). Uses whole CFA blocks (period x period) only.
    """
    p = cfa.period
    h, w = data.shape[0] // p * p, data.shape[1] // p * p
    black = np.asarray(black_level, dtype=np.float64)
    channel = cfa.channel_map(p, p)
    blocks = data[:h, :w].astype(np.float64).reshape(h // p, p, w // p, p).transpose(0, 2, 1, 3)
    signal = blocks - black[channel]
    clipped = blocks >= black[channel] + CLIP_FRACTION * (float(white_level) - black[channel])
    keep = ~clipped.any(axis=(2, 3))
    if not keep.any():
        raise ClispError("gray-world white balance: every CFA block has a clipped pixel")
    means = np.array([signal[keep][:, channel == c].mean() for c in range(cfa.n_channels)])
    if np.any(means <= 0):
        raise ClispError("gray-world white balance: a channel has no signal above black")
    return means[reference_channel(cfa)] / means
