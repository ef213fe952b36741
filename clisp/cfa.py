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

A CFA has two independent properties, and each stage reads the one it depends on:

* ``spectral`` ('lms' or 'rgb', from the channel names): which filters the sensor has. It picks
  the colour pipeline: the simulated camera's constants (colour matrix, white balance), the
  chroma denoiser's space.
* ``layout`` (from the pattern): 'bayer' (2 x 2 with one channel doubled on a diagonal, the other
  two once each: any channel may be the doubled one), 'lms' (the paper's 4 x 4, any phase) or
  'other'. It picks the demosaic.

``kind`` names the pair: 'lms' (LMS on the 4 x 4), 'bayer' (RGB on 2 x 2, G doubled), 'lms-bayer'
(L, M, S on the Bayer layout: L where R was, M where G was, S where B was), 'lms-bayer-double-l'
(the Bayer layout with L doubled, the paper's "double L" step applied there: ``ML/LS``), likewise
'<spectral>-bayer-double-<letter>' for another doubled channel, else '<spectral>-<layout>'.

The Bayer demosaics read a Bayer layout by *roles* (:meth:`CFA.bayer_roles`): the doubled channel
plays G, the other two R and B (in channel order). RGB Bayer and lms-bayer have the roles of their
channel order (R, G, B and L, M, S); ``ML/LS`` reads L as G, M as R, S as B. A demosaic works on
the CFA relabelled by roles (:meth:`CFA.role_cfa`) and hands its output back in the CFA's channel
order (:meth:`CFA.role_matrix`).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from .errors import ClispError

LMS_TILE = np.array(
    [[0, 1, 0, 2],
     [1, 0, 1, 0],
     [0, 2, 0, 1],
     [1, 0, 1, 0]], dtype=np.int8)
"""The paper's 4x4 LMS tile at phase (0, 0); 0 = L, 1 = M, 2 = S."""

BAYER_PHASES = ("RGGB", "GRBG", "GBRG", "BGGR")

CHANNEL_SETS: dict[str, tuple[str, ...]] = {"lms": ("L", "M", "S"), "rgb": ("R", "G", "B")}
"""The spectral kinds and their channels, in index order (index 1, M or G, is the Bayer layout's
doubled channel)."""

LAYOUTS = ("bayer", "lms", "other")
"""The layouts a CFA's pattern can have (module doc)."""


@dataclass(frozen=True)
class CFA:
    """A periodic colour filter array.

    ``pattern`` is a (p, p) int8 array of channel indices into ``channels``; ``kind`` names the
    pair (``spectral``, ``layout``) (module doc): 'lms', 'bayer', 'lms-bayer', ...
    """

    name: str
    kind: str
    channels: tuple[str, ...]
    pattern: np.ndarray = field(repr=False, compare=False)

    @property
    def _pattern_bytes(self) -> bytes:
        """The pattern as int8 bytes: the key of the lookups memoised per pattern."""
        return np.ascontiguousarray(self.pattern, dtype=np.int8).tobytes()

    @property
    def period(self) -> int:
        """Side of the repeating tile in pixels (2 for Bayer, 4 for LMS)."""
        return int(self.pattern.shape[0])

    @property
    def n_channels(self) -> int:
        return len(self.channels)

    @property
    def spectral(self) -> str:
        """'lms' or 'rgb' (the channel names, CHANNEL_SETS), else 'other': picks the colour pipeline."""
        return spectral_of(self.channels)

    @property
    def layout(self) -> str:
        """'bayer', 'lms' or 'other' (LAYOUTS): the arrangement of the pattern, which picks the demosaic.
        Memoised per pattern (asked several times in every build of a pipeline)."""
        return _layout(self._pattern_bytes, self.pattern.shape)

    def bayer_phase(self, origin: tuple[int, int] = (0, 0)) -> str:
        """The Bayer phase name (RGGB, GRBG, GBRG or BGGR) of a window whose pixel (0, 0) is image pixel
        ``origin``, the channels read by their roles (:meth:`bayer_roles`: L, M, S on lms-bayer as R, G,
        B; on ``ML/LS`` M, L, S). ClispError unless the layout is 'bayer'."""
        roles = self.role_cfa()
        return "".join("RGB"[int(c)] for c in roles.channel_map(2, 2, origin).ravel())

    @property
    def bayer_roles(self) -> tuple[int, int, int]:
        """(r, g, b): the channel indices a Bayer demosaic reads as R, G and B: g the channel doubled on a
        diagonal, r and b the other two in channel order. (0, 1, 2) for RGB Bayer and lms-bayer, (1, 0, 2)
        for ``ML/LS``. ClispError unless the layout is 'bayer'.

        >>> cfa_from_name("ML/LS").bayer_roles
        (1, 0, 2)
        """
        if self.layout != "bayer":
            raise ClispError(f"CFA {self.name} does not have the Bayer layout (2x2, one channel doubled on a diagonal)")
        return _bayer_roles(self._pattern_bytes)

    def first_site(self, channel: int) -> tuple[int, int]:
        """(y, x) of ``channel``'s first site in the pattern, in row order; memoised per pattern (a
        demosaic asks it at every step of every tile).

        >>> cfa_from_name("ML/LS").first_site(0)
        (0, 1)
        """
        return _first_site(self._pattern_bytes, self.pattern.shape, channel)

    def role_cfa(self) -> "CFA":
        """This CFA with each channel replaced by its role index (:meth:`bayer_roles`; 0 R, 1 G, 2 B) and
        channels named in role order: what a Bayer demosaic reads. ``self`` when the roles are the
        channel order (RGB Bayer, lms-bayer)."""
        roles = self.bayer_roles
        if roles == (0, 1, 2):
            return self
        role_of = np.argsort(roles)                        # channel -> its role
        pattern = role_of[self.pattern].astype(np.int8)
        channels = tuple(self.channels[c] for c in roles)
        return CFA(name=f"{self.name} (roles {''.join(channels)})", kind="bayer", channels=("R", "G", "B"),
                   pattern=pattern)

    def role_matrix(self) -> np.ndarray:
        """(3, 3) permutation taking a Bayer demosaic's output in role order (R, G, B) to this CFA's
        channel order: out[c] = sum_k role_matrix[c, k] roles_out[k]; the identity for RGB Bayer and
        lms-bayer."""
        perm = np.zeros((3, 3))
        for role, channel in enumerate(self.bayer_roles):
            perm[channel, role] = 1.0
        return perm

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
        """Smallest r such that every (2r+1)^2 window holds a sample of ``channel`` (Chebyshev metric).
        Memoised per pattern: the bilinear demosaic asks for it in every halo query, and the search
        cost 12 ms of a 0.26 MP LMS call."""
        radius = _covering_radius(self._pattern_bytes, self.period, int(channel))
        if radius < 0:
            raise ClispError(f"CFA {self.name}: channel {self.channels[channel]} has no samples")
        return radius

    @property
    def dng_pattern(self) -> bytes:
        """CFAPattern tag bytes with DNG colour codes (0 red/L, 1 green/M, 2 blue/S)."""
        return bytes(int(v) for v in self.pattern.ravel())


@lru_cache(maxsize=64)
def _covering_radius(pattern: bytes, p: int, channel: int) -> int:
    """:meth:`CFA.covering_radius` of the (p, p) int8 pattern ``pattern`` (its bytes); -1 when the
    channel has no samples."""
    sites = np.argwhere(np.frombuffer(pattern, dtype=np.int8).reshape(p, p) == channel)
    if not len(sites):
        return -1
    ys, xs = np.divmod(np.arange(p * p), p)
    dy = np.abs((sites[:, 0][:, None] - ys[None, :] + p // 2) % p - p // 2)
    dx = np.abs((sites[:, 1][:, None] - xs[None, :] + p // 2) % p - p // 2)
    return int(np.maximum(dy, dx).min(axis=0).max())       # the farthest pixel from its nearest site


@lru_cache(maxsize=64)
def _layout(pattern: bytes, shape: tuple[int, ...]) -> str:
    """:func:`layout_of` of the int8 pattern ``pattern`` (its bytes) of ``shape``."""
    return layout_of(np.frombuffer(pattern, dtype=np.int8).reshape(shape))


@lru_cache(maxsize=64)
def _bayer_roles(pattern: bytes) -> tuple[int, int, int]:
    """:meth:`CFA.bayer_roles` of the 2 x 2 int8 pattern ``pattern`` (its bytes), whose layout is 'bayer'."""
    g = doubled_channel(np.frombuffer(pattern, dtype=np.int8).reshape(2, 2))
    r, b = (c for c in range(3) if c != g)
    return r, g, b


@lru_cache(maxsize=64)
def _first_site(pattern: bytes, shape: tuple[int, ...], channel: int) -> tuple[int, int]:
    """:meth:`CFA.first_site` of the int8 pattern ``pattern`` (its bytes) of ``shape``."""
    ys, xs = np.nonzero(np.frombuffer(pattern, dtype=np.int8).reshape(shape) == channel)
    if not len(ys):
        raise ClispError(f"channel {channel} has no site in the CFA pattern")
    return int(ys[0]), int(xs[0])


def spectral_of(channels: tuple[str, ...]) -> str:
    """'lms' or 'rgb' for channels named as in CHANNEL_SETS (in that order), else 'other'."""
    return next((name for name, names in CHANNEL_SETS.items() if tuple(channels) == names), "other")


def doubled_channel(pattern: np.ndarray) -> int | None:
    """The channel of a 2 x 2 pattern of indices 0, 1, 2 that sits twice on a diagonal while the other
    two sit once each, else None (another shape, a channel missing, the pair on a row or column)."""
    pattern = np.asarray(pattern)
    if pattern.shape != (2, 2):
        return None
    counts = np.bincount(pattern.ravel().astype(np.int64), minlength=3)
    if len(counts) != 3 or sorted(counts.tolist()) != [1, 1, 2]:
        return None
    g = int(np.argmax(counts))
    return g if pattern[0, 0] == pattern[1, 1] == g or pattern[0, 1] == pattern[1, 0] == g else None


def layout_of(pattern: np.ndarray) -> str:
    """The layout of a (p, p) pattern of channel indices 0, 1, 2: 'bayer' (2 x 2, one channel twice on a
    diagonal, the other two once: the Bayer demosaics read them by role, CFA.bayer_roles), 'lms' (a
    translate of LMS_TILE: channel 0 on half the pixels, 1 on 3/8, 2 on 1/8) or 'other' (any other
    pattern, such as L twice on a row of the 2 x 2: the any-CFA demosaic serves it)."""
    pattern = np.asarray(pattern)
    if pattern.shape == (2, 2):
        return "bayer" if doubled_channel(pattern) is not None else "other"
    if pattern.shape == (4, 4):
        for dy in range(4):
            for dx in range(4):
                if np.array_equal(np.roll(LMS_TILE, (-dy, -dx), axis=(0, 1)), pattern):
                    return "lms"
    return "other"


def make_kind(channels: tuple[str, ...], pattern: np.ndarray) -> str:
    """The ``kind`` of a CFA with these channels and pattern (module doc): 'lms', 'bayer', 'lms-bayer',
    '<spectral>-bayer-double-<letter>' (the Bayer layout with another channel than the second doubled:
    'lms-bayer-double-l' for ``ML/LS``), else '<spectral>-<layout>'."""
    spectral = spectral_of(channels)
    layout = layout_of(pattern)
    if layout == "bayer" and doubled_channel(pattern) != 1:
        return f"{spectral}-bayer-double-{channels[doubled_channel(pattern)].lower()}"
    named = {("lms", "lms"): "lms", ("rgb", "bayer"): "bayer", ("lms", "bayer"): "lms-bayer"}
    return named.get((spectral, layout), f"{spectral}-{layout}")


def kind_before_issue45(cfa: CFA) -> str:
    """The kind clisp gave ``cfa`` before the Bayer layout took any doubled channel (issue 45): a 2 x 2
    with L (or R, B) doubled on a diagonal was '<spectral>-other'. Raw files written then store it;
    their reader accepts it (clisp.io.rawfile)."""
    if cfa.layout == "bayer" and doubled_channel(cfa.pattern) != 1:
        return f"{cfa.spectral}-other"
    return cfa.kind


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


def lms_bayer_cfa(phase: str = "RGGB") -> CFA:
    """L, M, S on the 2 x 2 Bayer layout (kind 'lms-bayer'): L where the Bayer phase has R, M where it
    has G, S where it has B. Named 'lms-bayer' for RGGB, else 'lms-bayer-<phase>'."""
    phase = phase.upper()
    if phase not in BAYER_PHASES:
        raise ClispError(f"unsupported Bayer phase {phase!r}; expected one of {', '.join(BAYER_PHASES)}")
    base = bayer_cfa(phase)
    name = "lms-bayer" if phase == "RGGB" else f"lms-bayer-{phase.lower()}"
    return CFA(name=name, kind="lms-bayer", channels=("L", "M", "S"), pattern=base.pattern.copy())


def cfa_from_string(text: str) -> CFA:
    """A CFA from a pattern string: the channel letters of each row, rows joined by '/' (``LMLS/MLML/LSLM/MLML``)
    or written in one run when the pattern is square (``LMMS`` = 2 x 2, 16 letters = 4 x 4). The letters
    are L, M, S or R, G, B, each of the three at least once. A pattern that is a named CFA returns that
    CFA (``RGGB`` -> bayer-rggb, ``LMMS`` -> lms-bayer, the 4 x 4 LMS tile -> lms or lms@dy,dx); any other is
    named by its string, upper case with '/' between rows."""
    letters = text.strip().upper()
    rows = letters.split("/") if "/" in letters else None
    if rows is None:
        side = int(round(len(letters) ** 0.5))
        rows = [letters[i * side:(i + 1) * side] for i in range(side)] if side * side == len(letters) else []
    spectral = next((name for name, names in CHANNEL_SETS.items() if set(letters.replace("/", "")) == set(names)), None)
    if not rows or spectral is None or any(len(row) != len(rows) for row in rows):
        raise ClispError(f"bad CFA pattern {text!r}: expected a square of L, M, S or of R, G, B letters, "
                         f"rows joined by '/' (e.g. LMMS, RGGB, LMLS/MLML/LSLM/MLML)")
    channels = CHANNEL_SETS[spectral]
    pattern = np.array([[channels.index(c) for c in row] for row in rows], dtype=np.int8)
    for candidate in ([bayer_cfa(p) for p in BAYER_PHASES] + [lms_bayer_cfa(p) for p in BAYER_PHASES]
                      + [lms_cfa((dy, dx)) for dy in range(4) for dx in range(4)]):
        if candidate.channels == channels and np.array_equal(candidate.pattern, pattern):
            return candidate
    name = "/".join(rows)
    return CFA(name=name, kind=make_kind(channels, pattern), channels=channels, pattern=pattern)


def cfa_from_name(name: str) -> CFA:
    """Parse ``lms``, ``lms@dy,dx``, ``bayer`` (= RGGB), ``bayer-<phase>``, ``lms-bayer`` (= L, M, S on
    RGGB), ``lms-bayer-<phase>`` or a pattern string (:func:`cfa_from_string`)."""
    key = name.strip().lower()
    if key == "lms-bayer":
        return lms_bayer_cfa("RGGB")
    if key.startswith("lms-bayer-"):
        return lms_bayer_cfa(key[10:])
    if key and set(key) <= set("lmsrgb/") and len(key.replace("/", "")) >= 4:
        return cfa_from_string(name)
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
    raise ClispError(f"unknown CFA {name!r}; expected lms, lms@dy,dx, bayer, bayer-<RGGB|GRBG|GBRG|BGGR>, "
                     f"lms-bayer, lms-bayer-<phase> or a pattern string such as LMMS")


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
