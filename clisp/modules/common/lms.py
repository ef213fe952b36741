"""Pieces shared by the LMS demosaics: filters and the CFA structure they rely on (and its closed form
in the kernels, ``LATTICE``)."""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from ...cfa import CFA
from ...errors import ClispError
from ...sim.noise import ChannelNoise

LATTICE = {"L_PAR": 0, "S_Y": 0, "S_D": 1}
"""The kernels' closed form of the base LMS tile (docs/model.md section 1, phase (0, 0)): L iff x + y + L_PAR is
even; S iff y + S_Y is even and x - y + S_D is a multiple of 4; M otherwise (``at_l``, ``at_s`` in
clisp/modules/common/common.h)."""


def binomial(n: int) -> np.ndarray:
    """1-D binomial of length n normalised to sum 1 (n = 5: [1 4 6 4 1]/16; n = 9: .../256)."""
    row = np.array([1.0])
    for _ in range(n - 1):
        row = np.convolve(row, [1.0, 1.0])
    return row / row.sum()


def diamond_halfband(radius: int = 4, exact_halfband: bool = True) -> np.ndarray:
    """(2R+1)^2 windowed diamond half-band filter (D of the hybrid demosaic's step B).

    D[n1, n2] ~ (2/pi^2) s(n1+n2) s(n1-n2) w(n1) w(n2), s(t) = sin(pi t/2)/t, s(0) = pi/2,
    w = numpy.hamming(2R+3)[1:-1]. Ideal response: 1 inside the diamond |w_x| + |w_y| < pi, 0 outside.
    s(t) is set exactly to 0 at even t != 0, so the taps off the origin lie on odd n1 + n2 only.

    Normalisation: the windowed taps sum to 0.99494, not 1. ``exact_halfband`` (default) keeps the
    centre at 1/2 and scales the off-centre taps to sum 1/2: DC gain 1 and exactly 0 at (pi, pi), the
    two properties h_lum needs (a flat L/M field then demosaics exactly).
    False: every tap scaled to sum 1 (centre 0.50254, response 0.00509 at (pi, pi)).
    """
    t = np.arange(-radius, radius + 1)
    n1, n2 = np.meshgrid(t, t, indexing="ij")

    def s(v: np.ndarray) -> np.ndarray:
        out = np.where(v % 2 == 0, 0.0, np.sin(np.pi * v / 2.0) / np.where(v == 0, 1, v))
        return np.where(v == 0, np.pi / 2.0, out)

    w = np.hamming(2 * radius + 3)[1:-1]
    d = (2.0 / np.pi ** 2) * s(n1 + n2) * s(n1 - n2) * w[n1 + radius] * w[n2 + radius]
    if not exact_halfband:
        return d / d.sum()
    centre = np.zeros_like(d)
    centre[radius, radius] = 0.5
    off = d.copy()
    off[radius, radius] = 0.0
    return centre + 0.5 * off / off.sum()


def check_lms_structure(cfa: CFA, what: str = "LMS demosaic") -> tuple[int, int, int]:
    """(L, M, S) channel indices after checking the neighbourhood step A relies on (docs/model.md section 1):
    around every S site the 4-neighbours are L, the diagonals and (0, +-2), (+-2, 0) are M, the
    (+-2, +-2) are S; L and M+S fill the two quincunxes. The check is memoised per pattern (every
    build of a pipeline asks it twice)."""
    if cfa.layout != "lms":     # the layout (clisp.cfa): channels 0, 1, 2 on 1/2, 3/8, 1/8 of the pixels
        raise ClispError(f"the {what} needs an LMS CFA, got {cfa.name}")
    problem = _lms_structure_problem(cfa._pattern_bytes, cfa.period)
    if problem:
        raise ClispError(f"CFA {cfa.name}: {problem}")
    return 0, 1, 2


@lru_cache(maxsize=64)
def _lms_structure_problem(pattern: bytes, p: int) -> str:
    """What check_lms_structure finds wrong with the (p, p) int8 pattern (its bytes) whose channels
    0, 1, 2 are L, M, S; '' when nothing."""
    ch_l, ch_m, ch_s = 0, 1, 2
    pat = np.frombuffer(pattern, dtype=np.int8).reshape(p, p)
    want = {ch_l: [(0, 1), (0, -1), (1, 0), (-1, 0)],
            ch_m: [(1, 1), (1, -1), (-1, 1), (-1, -1), (0, 2), (0, -2), (2, 0), (-2, 0)],
            ch_s: [(2, 2), (2, -2), (-2, 2), (-2, -2)]}
    for y, x in np.argwhere(pat == ch_s):
        for c, offsets in want.items():
            if any(pat[(y + dy) % p, (x + dx) % p] != c for dy, dx in offsets):
                return "S-site neighbourhood differs from the paper's LMS CFA"
    yy, xx = np.mgrid[0:p, 0:p]
    is_l = pat == ch_l
    if not (np.all(is_l == ((yy + xx) % 2 == 0)) or np.all(is_l == ((yy + xx) % 2 == 1))):
        return "L does not fill a quincunx"
    return ""


def lattice_shift(cfa: CFA, ch_l: int, ch_s: int) -> tuple[int, int]:
    """(ty, tx) with channel(y, x) = base tile at (y + ty, x + tx) for every pixel, where the base tile
    is LATTICE's; every CFA that passes check_lms_structure is such a translate (docs/model.md section 1, "Phase")."""
    shift = _lattice_shift(cfa._pattern_bytes, cfa.period, ch_l, ch_s)
    if shift is None:
        raise ClispError(f"CFA {cfa.name}: not a translate of the paper's LMS tile")
    return shift


@lru_cache(maxsize=64)
def _lattice_shift(pattern: bytes, p: int, ch_l: int, ch_s: int) -> tuple[int, int] | None:
    """lattice_shift of the (p, p) int8 pattern (its bytes); None when it is no translate."""
    pat = np.frombuffer(pattern, dtype=np.int8).reshape(p, p)
    yy, xx = np.mgrid[0:p, 0:p]
    for ty in range(4):
        for tx in range(4):
            y, x = yy + ty, xx + tx
            is_l = (x + y + LATTICE["L_PAR"]) % 2 == 0
            is_s = ((y + LATTICE["S_Y"]) % 2 == 0) & ((x - y + LATTICE["S_D"]) % 4 == 0)
            if np.array_equal(is_l, pat == ch_l) and np.array_equal(is_s, pat == ch_s):
                return ty, tx
    return None


def valid(a: np.ndarray, r: int, dy: int = 0, dx: int = 0) -> np.ndarray:
    """a shrunk by r on every side, shifted by (dy, dx): a[r+dy : H-r+dy, r+dx : W-r+dx]."""
    h, w = a.shape[:2]
    return a[r + dy:h - r + dy, r + dx:w - r + dx]


def correlate_valid(a: np.ndarray, k: np.ndarray) -> np.ndarray:
    """Valid-region correlation sum_t k[t] a[. + t] with an odd square kernel (zero taps skipped)."""
    r = k.shape[0] // 2
    out = np.zeros((a.shape[0] - 2 * r, a.shape[1] - 2 * r))
    for dy, dx in np.argwhere(k != 0) - r:
        out += k[dy + r, dx + r] * valid(a, r, dy, dx)
    return out


class NoiseFromRaw:
    """Mixin for demosaic dataclasses with fields (cfa, params, noise): build from a RawImage."""

    @classmethod
    def for_raw(cls, raw, params=None):
        """The stage for ``raw``: its CFA, its noise from the metadata's gain and noise model (None
        for noiseless or camera raws), and ``params`` (the stage's defaults when None)."""
        noise = ChannelNoise.from_metadata(raw.metadata, raw.pass1_gains())
        return cls(raw.cfa, noise=noise) if params is None else cls(raw.cfa, params, noise)
