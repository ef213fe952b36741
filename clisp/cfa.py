"""Colour filter array descriptions.

A CFA is a small periodic pattern of channel indices plus channel names. Every
stage is written against this description, never against a hard-coded layout:
the channel of pixel (y, x) is ``pattern[y % p, x % p]`` (row ``y`` down,
column ``x`` right, (0, 0) top-left).

The paper's LMS pattern (docs/model.md section 1), phase (0, 0)::

    y\\x 0 1 2 3
    0    L M L S
    1    M L M L
    2    L S L M
    3    M L M L

L iff (x + y) even; S iff y even and (x - y) mod 4 == 3; else M.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import ClispError

LMS_TILE = np.array(
    [[0, 1, 0, 2],
     [1, 0, 1, 0],
     [0, 2, 0, 1],
     [1, 0, 1, 0]], dtype=np.int8)
"""The paper's 4x4 LMS tile at phase (0, 0); 0 = L, 1 = M, 2 = S."""

BAYER_PHASES = ("RGGB", "GRBG", "GBRG", "BGGR")


@dataclass(frozen=True)
class CFA:
    """A periodic colour filter array.

    ``pattern`` is a (p, p) int8 array of channel indices into ``channels``;
    ``kind`` is ``"lms"`` or ``"bayer"`` and selects the colour pipeline.
    """

    name: str
    kind: str
    channels: tuple[str, ...]
    pattern: np.ndarray = field(repr=False, compare=False)

    @property
    def period(self) -> int:
        """Side of the repeating tile in pixels (2 for Bayer, 4 for LMS)."""
        return int(self.pattern.shape[0])

    @property
    def n_channels(self) -> int:
        return len(self.channels)

    def channel_map(self, height: int, width: int, origin: tuple[int, int] = (0, 0)) -> np.ndarray:
        """Channel index of every pixel of an H x W window whose (0, 0) is image pixel ``origin``.

        ``origin`` may be negative (windows that reach past the image edge). Returns H x W int8.
        """
        p = self.period
        ys = (np.arange(height) + origin[0]) % p
        xs = (np.arange(width) + origin[1]) % p
        return self.pattern[ys[:, None], xs[None, :]]

    def densities(self) -> np.ndarray:
        """Fraction of pixels of each channel, shape (n_channels,)."""
        return np.bincount(self.pattern.ravel(), minlength=self.n_channels) / self.pattern.size

    def covering_radius(self, channel: int) -> int:
        """Smallest r such that every (2r+1)^2 window holds a sample of ``channel`` (Chebyshev metric)."""
        p = self.period
        sites = np.argwhere(self.pattern == channel)
        for r in range(p + 1):
            ok = True
            for y in range(p):
                for x in range(p):
                    dy = np.abs((sites[:, 0] - y + p // 2) % p - p // 2)
                    dx = np.abs((sites[:, 1] - x + p // 2) % p - p // 2)
                    if not np.any(np.maximum(dy, dx) <= r):
                        ok = False
            if ok:
                return r
        raise ClispError(f"CFA {self.name}: channel {self.channels[channel]} has no samples")

    @property
    def dng_pattern(self) -> bytes:
        """CFAPattern tag bytes with DNG colour codes (0 red/L, 1 green/M, 2 blue/S)."""
        return bytes(int(v) for v in self.pattern.ravel())


def lms_cfa(phase: tuple[int, int] = (0, 0)) -> CFA:
    """The paper's 4x4 LMS CFA; ``phase=(dy, dx)`` shifts it so pixel (y, x) reads tile[(y+dy)%4][(x+dx)%4]."""
    dy, dx = (int(phase[0]) % 4, int(phase[1]) % 4)
    pattern = np.roll(LMS_TILE, shift=(-dy, -dx), axis=(0, 1)).copy()
    name = "lms" if (dy, dx) == (0, 0) else f"lms@{dy},{dx}"
    return CFA(name=name, kind="lms", channels=("L", "M", "S"), pattern=pattern)


def bayer_cfa(phase: str = "RGGB") -> CFA:
    """A 2x2 Bayer CFA named by its colours in reading order (RGGB, GRBG, GBRG or BGGR)."""
    phase = phase.upper()
    if phase not in BAYER_PHASES:
        raise ClispError(f"unsupported Bayer phase {phase!r}; expected one of {', '.join(BAYER_PHASES)}")
    index = {"R": 0, "G": 1, "B": 2}
    pattern = np.array([[index[phase[0]], index[phase[1]]],
                        [index[phase[2]], index[phase[3]]]], dtype=np.int8)
    return CFA(name=f"bayer-{phase.lower()}", kind="bayer", channels=("R", "G", "B"), pattern=pattern)


def cfa_from_name(name: str) -> CFA:
    """Parse ``lms``, ``lms@dy,dx``, ``bayer`` (= RGGB) or ``bayer-<phase>``."""
    key = name.strip().lower()
    if key == "lms":
        return lms_cfa()
    if key.startswith("lms@"):
        try:
            dy, dx = (int(v) for v in key[4:].split(","))
        except ValueError as exc:
            raise ClispError(f"bad LMS phase in CFA name {name!r}; expected lms@dy,dx") from exc
        return lms_cfa((dy, dx))
    if key == "bayer":
        return bayer_cfa("RGGB")
    if key.startswith("bayer-"):
        return bayer_cfa(key[6:])
    raise ClispError(f"unknown CFA {name!r}; expected lms, lms@dy,dx, bayer or bayer-<RGGB|GRBG|GBRG|BGGR>")


def cfa_from_pattern(pattern: np.ndarray, colours: str) -> CFA:
    """Build a Bayer CFA from a 2x2 index pattern and a colour description such as rawpy's ``'RGBG'``.

    Raises ClispError naming the pattern when it is not one of the four Bayer phases.
    """
    pattern = np.asarray(pattern)
    letters = "".join(colours[int(v)] for v in pattern.ravel()) if pattern.size else ""
    if pattern.shape == (2, 2) and letters in BAYER_PHASES:
        return bayer_cfa(letters)
    raise ClispError(
        f"unsupported CFA pattern {pattern.shape[0]}x{pattern.shape[1] if pattern.ndim > 1 else 0} "
        f"'{letters}' (only the Bayer phases {', '.join(BAYER_PHASES)} and clisp's LMS CFA are supported)")
