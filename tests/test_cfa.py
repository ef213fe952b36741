"""The colour filter arrays: the paper's LMS pattern (docs/model.md section 1) and the Bayer baseline.

Expected values are written out here from the pattern's description (the rule, the 4x4 table, the
densities, the S-site neighbourhood, the carrier table of the spectrum), not from clisp.cfa's own tables.
"""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from clisp.cfa import BAYER_PHASES, LMS_TILE, CFA, bayer_cfa, cfa_from_name, cfa_from_pattern, lms_cfa
from clisp.errors import ClispError

L, M, S = 0, 1, 2

# docs/model.md section 1 as a table, phase (0, 0): tile[y % 4][x % 4].
SPEC_TABLE = [
    "LMLS",
    "MLML",
    "LSLM",
    "MLML",
]

# The carriers (docs/model.md section 1, "Where the colours sit in frequency"): 16 * a_c(w) for
# (w_y, w_x) in units of pi/2 (index mod 4, so -pi/2 is 3 and pi is 2). Channels (L, M, S). The
# other 8 frequencies are zero.
SPEC_CARRIERS = {
    (0, 0): (8, 6, 2),
    (2, 2): (8, -6, -2),
    (0, 2): (0, 2, -2),
    (2, 0): (0, -2, 2),
    (1, 1): (0, -2j, 2j),
    (3, 1): (0, -2j, 2j),
    (3, 3): (0, 2j, -2j),
    (1, 3): (0, 2j, -2j),
}

BAYER_NAMES = ("bayer-rggb", "bayer-grbg", "bayer-gbrg", "bayer-bggr")

# Fujifilm X-Trans 6x6 layout, written with rawpy-style indices into 'RGBG' (0 R, 1 G, 2 B).
XTRANS = np.array([[1, 1, 0, 1, 1, 2],
                   [1, 1, 2, 1, 1, 0],
                   [2, 0, 1, 0, 2, 1],
                   [1, 1, 2, 1, 1, 0],
                   [1, 1, 0, 1, 1, 2],
                   [0, 2, 1, 2, 0, 1]])


def spec_rule(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The rule of docs/model.md section 1: L iff (x + y) even; S iff y even and (x - y) mod 4 == 3; else M."""
    y, x = np.asarray(y), np.asarray(x)
    out = np.full(np.broadcast(y, x).shape, M, dtype=np.int64)
    out[(y % 2 == 0) & ((x - y) % 4 == 3)] = S
    out[(x + y) % 2 == 0] = L
    return out


def rule_map(height: int, width: int, origin: tuple[int, int] = (0, 0),
             phase: tuple[int, int] = (0, 0)) -> np.ndarray:
    """Channel of every pixel of a window from that rule; ``phase`` shifts as lms_cfa documents."""
    y = np.arange(height)[:, None] + origin[0] + phase[0]
    x = np.arange(width)[None, :] + origin[1] + phase[1]
    return spec_rule(y, x)


# ------------------------------------------------------------------------------------------
# the LMS pattern
# ------------------------------------------------------------------------------------------

def test_spec_rule_matches_spec_table():
    """The rule and the table describe the same tile (guards the helpers below)."""
    letters = "LMS"
    for y, x in itertools.product(range(4), range(4)):
        assert letters[int(spec_rule(y, x))] == SPEC_TABLE[y][x], (y, x)


def test_lms_pattern_matches_table_and_rule():
    cfa = lms_cfa()
    table = np.array([["LMS".index(ch) for ch in row] for row in SPEC_TABLE])
    assert cfa.name == "lms" and cfa.kind == "lms"
    assert cfa.channels == ("L", "M", "S")
    assert cfa.period == 4 and cfa.n_channels == 3
    assert cfa.pattern.shape == (4, 4)
    np.testing.assert_array_equal(cfa.pattern, table)
    np.testing.assert_array_equal(LMS_TILE, table)


@pytest.mark.parametrize("origin", [(0, 0), (1, 3), (-2, -5), (5, 2), (-13, 7)])
def test_channel_map_follows_rule_at_any_origin(origin):
    cfa = lms_cfa()
    np.testing.assert_array_equal(cfa.channel_map(19, 23, origin), rule_map(19, 23, origin))


def test_lms_densities():
    cfa = lms_cfa()
    np.testing.assert_allclose(cfa.densities(), [1 / 2, 3 / 8, 1 / 8], rtol=0, atol=1e-15)
    counts = np.bincount(cfa.channel_map(40, 40, (-3, 5)).ravel(), minlength=3)
    np.testing.assert_array_equal(counts, [800, 600, 200])


@pytest.mark.parametrize("phase", [(0, 0), (1, 2), (3, 3)])
def test_s_site_neighbourhood(phase):
    """Around every S site: L at the 4-neighbours, M at the diagonals and at (0,+-2), (+-2,0),
    S at (+-2,+-2) and no other S within the 5x5 window (nearest S at distance 2*sqrt(2))."""
    cfa = lms_cfa(phase)
    ch = cfa.channel_map(24, 24, (-9, -7)).astype(np.int64)
    sites = np.argwhere(ch[2:-2, 2:-2] == S) + 2
    assert len(sites) == 20 * 20 // 8
    expected = np.array([[S, L, M, L, S],          # odd offsets such as (1, 2) are L (quincunx)
                         [L, M, L, M, L],
                         [M, L, S, L, M],
                         [L, M, L, M, L],
                         [S, L, M, L, S]])
    for y, x in sites:
        np.testing.assert_array_equal(ch[y - 2:y + 3, x - 2:x + 3], expected, err_msg=f"S site {(y, x)}")


def test_s_sites_form_the_rotated_lattice():
    """S sites are exactly (0, 3) + {a (2, 2) + b (2, -2)} (the 45-degree S lattice of docs/model.md section 1)."""
    ch = lms_cfa().channel_map(32, 32)
    sites = {tuple(v) for v in np.argwhere(ch == S)}
    lattice = {(2 * a + 2 * b, 3 + 2 * a - 2 * b) for a in range(-20, 20) for b in range(-20, 20)}
    lattice = {(y, x) for y, x in lattice if 0 <= y < 32 and 0 <= x < 32}
    assert sites == lattice


def test_spectrum_matches_spec_carrier_table():
    """a_c(w) = (1/16) sum_tile m_c(y, x) exp(-i (w_y y + w_x x)); 8 of the 16 a_c are non-zero."""
    tile = lms_cfa().pattern
    y, x = np.mgrid[0:4, 0:4]
    checked = 0
    for ky, kx in itertools.product(range(4), range(4)):
        wy, wx = ky * np.pi / 2, kx * np.pi / 2
        phasor = np.exp(-1j * (wy * y + wx * x))
        coeff = np.array([np.sum((tile == c) * phasor) for c in range(3)])      # = 16 a_c(w)
        expected = np.array(SPEC_CARRIERS.get((ky, kx), (0, 0, 0)), dtype=complex)
        np.testing.assert_allclose(coeff, expected, rtol=0, atol=1e-12, err_msg=f"frequency {(ky, kx)}")
        checked += 1
    assert checked == 16 and len(SPEC_CARRIERS) == 8


def test_closed_form_and_inverse():
    """The closed form 8 f = Lum + C1 (-1)^(x+y) + C2 [(-1)^x - (-1)^y] + 2 C2 [sin(pi(x+y)/2) - sin(pi(y-x)/2)]
    reproduces the mosaic of constant planes L, M, S; and L, M, S follow from Lum, C1, C2."""
    rng = np.random.default_rng(3)
    lms = rng.uniform(0.1, 2.0, size=3)
    ch = lms_cfa().channel_map(8, 8)
    mosaic = lms[ch]
    lum = 4 * lms[0] + 3 * lms[1] + lms[2]
    c1 = 4 * lms[0] - 3 * lms[1] - lms[2]
    c2 = lms[1] - lms[2]
    y, x = np.mgrid[0:8, 0:8]
    f8 = (lum + c1 * (-1.0) ** (x + y) + c2 * ((-1.0) ** x - (-1.0) ** y)
          + 2 * c2 * (np.sin(np.pi * (x + y) / 2) - np.sin(np.pi * (y - x) / 2)))
    np.testing.assert_allclose(f8 / 8, mosaic, rtol=0, atol=1e-12)
    np.testing.assert_allclose([(lum + c1) / 8, (lum - c1 + 2 * c2) / 8, (lum - c1 + 2 * c2) / 8 - c2],
                               lms, rtol=0, atol=1e-12)


@pytest.mark.parametrize("phase", [(0, 0), (1, 2), (3, 1), (2, 0), (0, 3), (-1, 6), (5, -2)])
def test_lms_phase_shifts_pattern(phase):
    dy, dx = phase
    cfa = lms_cfa(phase)
    for y, x in itertools.product(range(4), range(4)):
        assert cfa.pattern[y, x] == LMS_TILE[(y + dy) % 4, (x + dx) % 4], (phase, y, x)
    np.testing.assert_array_equal(cfa.channel_map(13, 17, (-5, 2)), rule_map(13, 17, (-5, 2), phase))
    norm = (dy % 4, dx % 4)
    assert cfa.name == ("lms" if norm == (0, 0) else f"lms@{norm[0]},{norm[1]}")
    np.testing.assert_allclose(cfa.densities(), [1 / 2, 3 / 8, 1 / 8])


def test_lms_phases_distinct_up_to_lattice():
    """(2, 2) lies in the S lattice, so a shift by it leaves the pattern unchanged: 8 distinct phases."""
    patterns = {lms_cfa((dy, dx)).pattern.tobytes() for dy in range(4) for dx in range(4)}
    assert len(patterns) == 8
    for dy, dx in itertools.product(range(4), range(4)):
        np.testing.assert_array_equal(lms_cfa((dy, dx)).pattern, lms_cfa((dy + 2, dx + 2)).pattern)
        np.testing.assert_array_equal(lms_cfa((dy, dx)).pattern, lms_cfa((dy + 2, dx - 2)).pattern)


# ------------------------------------------------------------------------------------------
# Bayer
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("phase", BAYER_PHASES)
def test_bayer_phases(phase):
    cfa = bayer_cfa(phase)
    assert cfa.kind == "bayer" and cfa.channels == ("R", "G", "B") and cfa.period == 2
    assert cfa.name == f"bayer-{phase.lower()}"
    assert "".join("RGB"[v] for v in cfa.pattern.ravel()) == phase
    np.testing.assert_allclose(cfa.densities(), [1 / 4, 1 / 2, 1 / 4])
    # G on one quincunx, R and B on the rows/columns of the other
    ch = cfa.channel_map(6, 8, (-1, 3))
    y, x = np.mgrid[0:6, 0:8]
    g_parity = (y + x)[ch == 1] % 2
    assert len(set(g_parity.tolist())) == 1
    assert len(set((y[ch == 0] % 2).tolist())) == 1 and len(set((x[ch == 0] % 2).tolist())) == 1
    assert [cfa.covering_radius(c) for c in range(3)] == [1, 1, 1]


def test_bayer_rggb_layout():
    cfa = bayer_cfa("RGGB")
    np.testing.assert_array_equal(cfa.pattern, [[0, 1], [1, 2]])        # R at (0,0), B at (1,1)


def test_bayer_rejects_unknown_phase():
    with pytest.raises(ClispError, match="RGBG"):
        bayer_cfa("RGBG")


# ------------------------------------------------------------------------------------------
# names and patterns
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("name, expected_name, pattern", [
    ("lms", "lms", LMS_TILE),
    ("  LMS ", "lms", LMS_TILE),
    ("lms@1,2", "lms@1,2", np.roll(LMS_TILE, (-1, -2), axis=(0, 1))),
    ("lms@-1,6", "lms@3,2", np.roll(LMS_TILE, (1, -6), axis=(0, 1))),
    ("lms@0,0", "lms", LMS_TILE),
    ("bayer", "bayer-rggb", [[0, 1], [1, 2]]),
    ("bayer-rggb", "bayer-rggb", [[0, 1], [1, 2]]),
    ("Bayer-GRBG", "bayer-grbg", [[1, 0], [2, 1]]),
    ("bayer-gbrg", "bayer-gbrg", [[1, 2], [0, 1]]),
    ("BAYER-BGGR", "bayer-bggr", [[2, 1], [1, 0]]),
])
def test_cfa_from_name(name, expected_name, pattern):
    cfa = cfa_from_name(name)
    assert cfa.name == expected_name
    np.testing.assert_array_equal(cfa.pattern, pattern)


@pytest.mark.parametrize("name, named", [
    ("", "''"), ("xtrans", "'xtrans'"), ("rgbw", "'rgbw'"), ("bayer_rggb", "'bayer_rggb'"),
    ("lmml", "'lmml'"), ("lmm/sl", "'lmm/sl'"), ("lms-bayer-lmms", "'LMMS'"),
    ("lms@1", "'lms@1'"), ("lms@a,b", "'lms@a,b'"), ("lms@1,2,3", "'lms@1,2,3'"), ("lms@", "'lms@'"),
    ("bayer-rgbg", "'RGBG'"), ("bayer-", "''"),
])
def test_cfa_from_name_errors(name, named):
    """Bad names raise ClispError (never a bare ValueError) whose message names the bad part."""
    with pytest.raises(ClispError) as info:
        cfa_from_name(name)
    assert named in str(info.value)


@pytest.mark.parametrize("phase", BAYER_PHASES)
def test_cfa_from_pattern_bayer(phase):
    # rawpy describes colours as 'RGBG': index 3 is the second green
    index = {"R": 0, "B": 2}
    greens = iter([1, 3])
    pattern = np.array([index[c] if c != "G" else next(greens) for c in phase]).reshape(2, 2)
    cfa = cfa_from_pattern(pattern, "RGBG")
    assert cfa.name == f"bayer-{phase.lower()}"
    np.testing.assert_array_equal(cfa.pattern, bayer_cfa(phase).pattern)


def test_cfa_from_pattern_rejects_xtrans():
    letters = "".join("RGBG"[v] for v in XTRANS.ravel())
    with pytest.raises(ClispError) as info:
        cfa_from_pattern(XTRANS, "RGBG")
    message = str(info.value)
    assert "6x6" in message
    assert letters in message


def test_cfa_from_pattern_rejects_non_bayer_2x2():
    with pytest.raises(ClispError, match="2x2 'RGBG'"):
        cfa_from_pattern(np.array([[0, 1], [2, 3]]), "RGBG")


# ------------------------------------------------------------------------------------------
# covering radii
# ------------------------------------------------------------------------------------------

def brute_covering_radius(cfa: CFA, channel: int) -> int:
    """Smallest r with a sample of ``channel`` in every (2r+1)^2 window, by brute force on a big map."""
    ch = cfa.channel_map(3 * cfa.period + 8, 3 * cfa.period + 8, (-4, -4))
    for r in range(8):
        mask = (ch == channel).astype(int)
        found = np.zeros_like(mask)
        for dy in range(-r, r + 1):
            for dx in range(-r, r + 1):
                found |= np.roll(mask, (dy, dx), axis=(0, 1))
        if found[4:-4, 4:-4].all():
            return r
    raise AssertionError("no radius")


@pytest.mark.parametrize("name, radii", [
    ("lms", [1, 1, 2]), ("lms@1,2", [1, 1, 2]), ("lms@3,1", [1, 1, 2]),
    ("bayer-rggb", [1, 1, 1]), ("bayer-grbg", [1, 1, 1]), ("bayer-gbrg", [1, 1, 1]), ("bayer-bggr", [1, 1, 1]),
])
def test_covering_radii(name, radii):
    cfa = cfa_from_name(name)
    assert [cfa.covering_radius(c) for c in range(3)] == radii
    assert [brute_covering_radius(cfa, c) for c in range(3)] == radii


def test_covering_radius_of_missing_channel():
    cfa = CFA(name="two", kind="bayer", channels=("R", "G", "B"), pattern=np.array([[0, 1], [1, 0]], np.int8))
    with pytest.raises(ClispError, match="no samples"):
        cfa.covering_radius(2)


def test_dng_pattern_bytes():
    assert lms_cfa().dng_pattern == bytes(LMS_TILE.ravel().tolist())
    assert bayer_cfa("GBRG").dng_pattern == bytes([1, 2, 0, 1])
