"""Sensor corrections: defective pixels, dark frame, flat field and the DNG's gain opcodes (issue 44).

Two stages, one at each end of the colour pipeline::

    step                   halo  launches  what
    sensor_screen             3         1  first stage, on the raw mosaic (DN in): OpcodeList1's gains,
                                           the dark frame (or the black level), the flat field and
                                           OpcodeList2's gains less their smooth part G; candidates
                                           for the defect test flagged (a bit per pixel)
    sensor_list               0         1  the flagged pixels listed, and (the launch 2 deep) the
                                           window's pixels near the image's edge
    sensor_fix                3         1  each candidate: the defect test against the noise model
                                           (or the known bad pixels), and its replacement
    sensor_shade              0         1  after the chroma stage: G, per camera channel
                                           (out = M diag(G) M^-1 in, M the colour matrix)

Why the smooth gain is applied after the chroma stage: a lens-shading gain raises the corners'
signal, their clip level and their noise alike. The highlight stage compares the demosaiced
values with one clip level per channel and the chroma denoiser reads one noise table, so both
would be wrong in the corners of a gained image. The product is the same where it is applied
(the gain is smooth: a demosaic sees it as a constant over its window), so the per-pixel part
(the flat's PRNU, the difference between a channel's sites) is applied on the mosaic where the
DNG specification places it, and the smooth part G_c(x) (a grid of nodes every GRID_CELL pixels,
bilinear) after the highlight stage and the denoiser: they see the image as the sensor recorded
it, with its own clip level and noise, which is what "the clip level moves per pixel" and "the
noise table follows the gain" mean.

The auto test (``sensor_screen`` and ``sensor_fix``, constants K, K_COLD, HOT_SLOPE, HOT_CAP, ALPHA,
GAMMA, RHO, KR; what each step does and its measurements: README.md and tools/bench_sensor.py): a
pixel is bad where its normalised value lies beyond every same-channel neighbour within RADIUS
(above the highest for a hot pixel by K noise sigmas at that neighbour's level or by HOT_SLOPE
times that level, at most HOT_CAP, whichever is more; below the lowest for a dead one by K_COLD
sigmas at its level) plus ALPHA times their spread, and then, if hot, its 4 nearest pixels carry less than GAMMA of its
excess over the opposite same-channel pair that differs least; if dead, it reads below RHO times
its lowest neighbour by KR sigmas (the lens keeps a live pixel near its neighbours; beside the
image's edge, without a pair, it takes the support test instead). It is replaced by that pair's
mean plus the colour difference of its 4 nearest pixels.

Example: a hot pixel in a flat noiseless Bayer mosaic is found and replaced::

    >>> from clisp.cfa import bayer_cfa
    >>> x = np.full((12, 12), 300.0); x[6, 6] = 1000.0
    >>> st = SensorCorrect(bayer_cfa(), black=np.full(3, 64.0), white=1023.0, test=DefectTest.noiseless(3))
    >>> out = st.reference(x, (0, 0))
    >>> out.shape, float(out[3, 3]), float(out.max())
    ((6, 6), 300.0, 300.0)
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Any

import numpy as np

from ...cfa import CFA
from ...engine.runtime import DeviceImage, Runtime
from ...engine.stage import Stage, as_f32, image_extent
from ...engine.tiling import cfa_mirror_index, gather_window
from ..raw_scale.stage import CfaAffine

HALO = 3
"""Pixels each output reads on every side: the same-channel neighbours within 2 (Bayer R and B: the
nearest same-colour pixels are 2 away), and the 4 nearest pixels of each of them (the replacement's Y)."""

RADIUS = 2
"""Radius of the same-channel neighbourhood."""

K = 6.0
"""Noise sigmas (at the highest neighbour's level) by which a hot pixel lies above every same-channel
neighbour (tools/bench_sensor.py --tune; README.md; a dead pixel's margin is K_COLD)."""

K_COLD = 4.5
"""Noise sigmas (at the lowest neighbour's level) by which a dead pixel lies below every same-channel
neighbour: fewer than K, because a cold pixel must also pass the ratio test (below RHO of its lowest
neighbour by KR sigmas), which keeps texture out and, with this margin, noise; a hot pixel has no
such second test. At gain 16 a dead pixel where its channel reads 0.05 is 4 to 5 sigmas off
(tools/bench_sensor.py --tune --sets deadleaves --k-cold 6,5,4.5,4,3.5: Bayer gain 16 -0.096 /
-0.088 / -0.086 / -0.086 / -0.086 dB, every other cell within 0.003, gain 64 included; README.md).
A dead pixel has no photo-response, so it must also read black: below K_COLD sigmas of the raw's
floor noise (the model's b: read noise and quantisation) plus FLOOR. A live pixel that dark beside
its neighbours is a scene's dark detail where it reads above that (the LMS CFA's sparse S channel,
whose same-channel neighbours lie 2-4 px away; README.md)."""

ALPHA = 0.0
"""Times the same-channel neighbours' spread (their range) a bad pixel must also exceed (texture):
none; the support test keeps texture out (tools/bench_sensor.py --tune: 0.25 and 0.5 lose 0.1-0.2 dB
on raws with defects for 0.07-0.09 dB on raws without)."""

GAMMA = 0.08
"""Largest share of a bad pixel's excess over its pair its 4 nearest pixels may carry (beyond the
pair's own): the optics spread a real point of light to them (the simulated Airy PSF: about 6 %
more than to the pair's), a hot pixel lights none (tools/bench_sensor.py --tune: 0.05 loses 0.03-0.08 dB)."""

RHO = 0.25
"""Largest share of its lowest same-channel neighbour a dead pixel reads: the lens spreads every
point over its neighbours (the simulated Airy PSF keeps 68 % on the pixel itself: a black point one
pixel wide on an even ground reads 0.32 of it), so a live pixel darker than all of them stays near
them (the texture the old support test replaced read 0.57 to 0.81 of it), while a dead one reads
black. Below RHO a cold pixel with a pair is dead without the support test, whose 4 nearest pixels
are darker than the pair's as readily in a texture as beside a dark detail (tools/bench_sensor.py
--tune --sets deadleaves: 0.5 lets LMS texture through; README.md)."""

KR = 2.0
"""Noise sigmas of RHO lo - u (var = a (RHO + RHO^2) lo + (1 + RHO^2) b) by which a dead pixel lies
below RHO times its lowest neighbour: at gain 16 and above a dim live pixel's noise reaches the ratio."""

Z = 1.0
"""Noise sigmas of Y(p) - Y(pair) by which the support must lie below GAMMA: at high gain the noise
of the 4 nearest pixels is larger than the 6 % a lit point gives them, and a glint would look
unsupported (tools/bench_sensor.py --false-positives); 2 cost 0.05-0.1 dB more on raws with defects at
gain 16 (--tune --z)."""

GRID_CELL = 16
"""Pixels between the smooth gain's nodes (bilinear in between): the DNG GainMaps of phones have
their points hundreds of pixels apart, so a 16 px grid follows them to 1e-4."""

TERM_SIZE = 24
"""Floats per packed gain term (sensor.cl: T_*)."""

FLOOR = 1e-3
"""Least excess (normalised units: 0.1 % of the range) of a pixel the auto test replaces: on a
noiseless raw every local extremum would otherwise qualify."""

LANES = 8
"""Pixels of a row per work-item of sensor_screen (its float8 lanes)."""

FIX_ROW = 256
"""sensor_fix's list is launched as rows of this many work-items (a multiple of the work-group's width)."""

EDGE_RUN = 64
"""Pixels of a row each work-item of sensor_list's edge part appends, with one atomic (sensor.cl's SC_EDGE_RUN)."""

HOT_SLOPE = 1.0
"""A hot pixel's least excess over its highest same-channel neighbour follows that neighbour's level:
HOT_SLOPE times it, at most HOT_CAP, where that is more than the noise margin (K sigmas). A hot or
warm pixel's excess is its own (dark current) whatever the ground, while a texture's one-pixel detail
reads about 1.3 times its brightest neighbour: at gain 1, where the noise margin is small, the
search replaced such details as often as it found defects. Slope 1 (twice the ground) still finds a
warm pixel of 0.05 on grounds below 0.05; the tuning sets did not tell slopes 1, 2 and 4 apart
(tools/bench_sensor.py --tune --hot-slope; README.md)."""

HOT_CAP = 0.13
"""Most the level-following margin asks (normalised units): on a bright or textured ground a hot
pixel reads above its highest neighbour by less than its excess, a clipped one by less still
(tools/bench_sensor.py --tune --hot-cap on four sets made in code; README.md)."""

SLACK = 1e-6
"""How much looser sensor_screen's form of the test is than sensor_fix's (added to the excess,
normalised units, and taken off the squared threshold as a share): its squares round differently
from sensor_fix's square root, and a pixel the screen left out would never be replaced."""

LANE_ROWS = 7
"""Rows per CFA phase of sensor_screen's lane table (lane_constants)."""

FOUND = "sensor_found"
"""The Runtime.counter sensor_fix counts the pixels the auto test finds into (RunStats.counts)."""

STRIP_MEMO = 64
"""Windows whose strip launches a sensor stage object keeps (SensorCorrect._strips): a 24 MP run has
6-12 windows; past this many the memo starts over."""

CANDIDATES = 8
"""sensor_fix runs one work-item per CANDIDATES pixels of a window, each taking every so-many-th
entry of the candidates list (the screen passes about 1-5 % of a textured mosaic's pixels at gain
1-16: README.md). The list itself has room for every pixel: a mosaic of noise passes most of them,
and a list that drops some (in the order of the atomic appends) would make the output vary from
run to run."""


# --------------------------------------------------------------------------------------------
# Tables and parameters
# --------------------------------------------------------------------------------------------

def neighbour_tables(cfa: CFA, radius: int = RADIUS) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per CFA phase k = py P + px: the same-channel neighbours within ``radius`` (nb: P^2 x NB x 2
    int8 (dy, dx), nb_n: their counts) and the opposite pairs among them (pairs: P^2 x NP x 2 int8
    indices into nb[k], pairs_n). Memoised per pattern (every build and window asks); read-only.

    >>> from clisp.cfa import bayer_cfa
    >>> nb, n, pairs, pn = neighbour_tables(bayer_cfa())
    >>> n.tolist(), pn.tolist()
    ([8, 12, 12, 8], [4, 6, 6, 4])
    """
    return _neighbour_tables(np.ascontiguousarray(cfa.pattern, dtype=np.int8).tobytes(), cfa.period, radius)


@lru_cache(maxsize=16)
def _neighbour_tables(pattern_bytes: bytes, p: int, radius: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`neighbour_tables` of the (p, p) int8 pattern ``pattern_bytes`` (its bytes)."""
    pattern = np.frombuffer(pattern_bytes, dtype=np.int8).reshape(p, p)
    lists, pair_lists = [], []
    for k in range(p * p):
        ky, kx = divmod(k, p)
        c = pattern[ky, kx]
        offs = [(dy, dx) for dy in range(-radius, radius + 1) for dx in range(-radius, radius + 1)
                if (dy or dx) and pattern[(ky + dy) % p, (kx + dx) % p] == c]
        lists.append(offs)
        pair_lists.append([(i, offs.index((-dy, -dx))) for i, (dy, dx) in enumerate(offs)
                           if (-dy, -dx) in offs and offs.index((-dy, -dx)) > i])
    nmax, pmax = max(1, max(map(len, lists))), max(1, max(map(len, pair_lists)))
    nb = np.zeros((p * p, nmax, 2), np.int8)
    pairs = np.zeros((p * p, pmax, 2), np.int8)
    for k in range(p * p):
        if lists[k]:
            nb[k, :len(lists[k])] = lists[k]
        if pair_lists[k]:
            pairs[k, :len(pair_lists[k])] = pair_lists[k]
    out = (nb, np.array([len(v) for v in lists], np.int8), pairs, np.array([len(v) for v in pair_lists], np.int8))
    for a in out:
        a.setflags(write=False)
    return out


@dataclass(frozen=True)
class DefectTest:
    """The auto search's noise model and constants: var(u) = a_c max(u, 0) + b_c for a normalised
    sample u of CFA channel c ((DN - black) / (white - black)); ``wb`` the pass-1 gains, which put the
    channels on one footing for the support test."""

    noise_a: tuple[float, ...]
    noise_b: tuple[float, ...]
    wb: tuple[float, ...]
    k: float = K
    alpha: float = ALPHA
    gamma: float = GAMMA
    z: float = Z
    rho: float = RHO
    kr: float = KR
    k_cold: float = K_COLD
    hot_slope: float = HOT_SLOPE
    hot_cap: float = HOT_CAP

    @classmethod
    def from_noise(cls, noise: Any, pass1_gains: np.ndarray) -> "DefectTest":
        """From the raw's ChannelNoise (white-balanced units: var_s = shot s + floor, s = w u):
        a = shot / w, b = floor / w^2."""
        w = np.asarray(pass1_gains, dtype=np.float64)
        return cls(tuple(float(v) for v in np.asarray(noise.shot) / w),
                   tuple(float(v) for v in np.asarray(noise.floor) / (w * w)), tuple(float(v) for v in w))

    @classmethod
    def noiseless(cls, n_channels: int, wb: np.ndarray | None = None) -> "DefectTest":
        w = np.ones(n_channels) if wb is None else np.asarray(wb, dtype=np.float64)
        return cls((0.0,) * n_channels, (0.0,) * n_channels, tuple(float(v) for v in w))


@dataclass
class GainTerms:
    """The gain opcodes a mosaic stage applies (GainMap and FixVignetteRadial of OpcodeLists 1 and
    2), placed on the mosaic (clisp.io.opcodes)."""

    ops: list[Any]

    def gain(self, list_no: int, ys: np.ndarray, xs: np.ndarray) -> np.ndarray:
        """Product of list ``list_no``'s gains at mosaic pixels (ys, xs broadcast), float64."""
        from ...io.opcodes import FixVignetteRadial, GainMap, gain_map_at, selects, vignette_at   # a raw with terms
        ys, xs = np.broadcast_arrays(np.asarray(ys), np.asarray(xs))
        out = np.ones(ys.shape)
        for op in self.ops:
            if op.list_no != list_no:
                continue
            if isinstance(op, GainMap):
                out = np.where(selects(op, ys, xs), out * gain_map_at(op, ys, xs, op.plane), out)
            elif isinstance(op, FixVignetteRadial):
                out = out * vignette_at(op, ys, xs)
        return out

    def pack(self) -> tuple[np.ndarray, np.ndarray]:
        """(terms: n x TERM_SIZE float32, maps: the GainMaps' planes, float32) for sensor.cl."""
        from ...io.opcodes import GainMap   # deferred: only raws with DNG opcodes load clisp.io.opcodes (start-up)
        terms, maps = [], []
        offset = 0
        for op in self.ops:
            t = np.zeros(TERM_SIZE)
            oy, ox = op.origin
            height, width = op.image
            t[1] = op.list_no
            if isinstance(op, GainMap):
                pv, ph, mp = op.gains.shape
                top, left, bottom, right = op.area
                t[0] = 1
                t[2:6] = (top + oy, left + ox, bottom + oy, right + ox) if bottom > top and right > left else (0, 0, 0, 0)
                t[6:8] = (op.row_pitch, op.col_pitch)
                t[8:10] = (oy, ox)
                t[10:12] = (1.0 / height, 1.0 / width)
                t[12:14] = (pv, ph)
                t[14:16] = (1.0 / op.spacing[0], 1.0 / op.spacing[1])
                t[16:18] = op.origin_rel
                t[18] = offset
                plane = op.gains[:, :, min(op.plane, mp - 1)].astype(np.float32).reshape(-1)
                maps.append(plane)
                offset += plane.size
            else:
                cy, cx = op.center[1] * height, op.center[0] * width
                t[0] = 2
                t[12:17] = op.k
                t[17:19] = (cy + oy, cx + ox)
                t[19] = 1.0 / max(max(cy, height - cy) ** 2 + max(cx, width - cx) ** 2, 1e-12)
            terms.append(t)
        packed = np.asarray(terms, dtype=np.float32).reshape(-1, TERM_SIZE)
        return packed, (np.concatenate(maps) if maps else np.zeros(1, np.float32))


@dataclass
class SmoothGain:
    """G_c(y, x): per channel, nodes every ``cell`` pixels of the image (node (i, j) at pixel
    (i cell, j cell)), bilinear between them, clamped at the edges; ``grid`` C x GH x GW float32."""

    grid: np.ndarray
    cell: int = GRID_CELL

    def at(self, c: np.ndarray | int, ys: np.ndarray, xs: np.ndarray) -> np.ndarray:
        """G at (ys, xs) (image pixels, floats allowed) of channel(s) c, broadcast; float64."""
        g = self.grid.astype(np.float64)
        gh, gw = g.shape[1:]
        gy = np.clip(np.asarray(ys, dtype=np.float64) / self.cell, 0, gh - 1)
        gx = np.clip(np.asarray(xs, dtype=np.float64) / self.cell, 0, gw - 1)
        i0, j0 = np.minimum(gy.astype(np.int64), max(gh - 2, 0)), np.minimum(gx.astype(np.int64), max(gw - 2, 0))
        i1, j1 = np.minimum(i0 + 1, gh - 1), np.minimum(j0 + 1, gw - 1)
        fy, fx = gy - i0, gx - j0
        c = np.asarray(c)
        return ((g[c, i0, j0] * (1 - fx) + g[c, i0, j1] * fx) * (1 - fy)
                + (g[c, i1, j0] * (1 - fx) + g[c, i1, j1] * fx) * fy)

    @classmethod
    def nodes(cls, shape: tuple[int, int], cell: int = GRID_CELL) -> tuple[np.ndarray, np.ndarray]:
        """The node coordinates (ys, xs) of an image of ``shape``: 0, cell, ... up to the last pixel."""
        return (np.arange(-(-(shape[0] - 1) // cell) + 1) * cell, np.arange(-(-(shape[1] - 1) // cell) + 1) * cell)

    def device(self, rt: Runtime) -> tuple[Any, int, int, float]:
        g = np.ascontiguousarray(self.grid, dtype=np.float32)
        return rt.constant(g), int(g.shape[1]), int(g.shape[2]), 1.0 / self.cell


def window_of(plane: np.ndarray, origin: tuple[int, int], shape: tuple[int, int], period: int) -> np.ndarray:
    """The ``shape`` window of a whole-image ``plane`` at ``origin``, CFA-mirror padded outside the
    image exactly as the engine pads the raw (tiling.gather_window)."""
    return gather_window(plane, int(origin[0]), int(origin[1]), int(shape[0]), int(shape[1]), period)


# --------------------------------------------------------------------------------------------
# The mosaic stage
# --------------------------------------------------------------------------------------------

@dataclass
class SensorCorrect(Stage):
    """Raw mosaic (DN) -> the corrected mosaic, float32 (module doc, kernel ``sensor_correct``).

    black      (C,) black level per channel (DN), the offset where there is no dark frame
    white      white level (DN)
    out_scale, out_offset  (C,) out = w r out_scale + out_offset; (1, black) keeps DN, a following
               normalisation and white balance fold in (:meth:`fuse`)
    test       the auto search (None: off)
    mask       H x W uint16 of the whole image, 1 = known bad pixel (None: none)
    dark       H x W float32 dark level in DN (None: the black level)
    flat       H x W float32 flat-field gain (None: none)
    terms      OpcodeList1 / 2 gain opcodes (None: none)
    smooth     G, divided out here and applied by :class:`SensorShade` (None: none)
    wb         (C,) the pass-1 white balance gains the replacement's colour difference is taken in
               where there is no search (a map alone; the search's ``test.wb`` otherwise); None: 1
    """

    cfa: CFA
    black: np.ndarray
    white: float
    test: DefectTest | None = None
    mask: np.ndarray | None = field(default=None, repr=False, compare=False)
    dark: np.ndarray | None = field(default=None, repr=False, compare=False)
    flat: np.ndarray | None = field(default=None, repr=False, compare=False)
    terms: GainTerms | None = field(default=None, repr=False, compare=False)
    smooth: SmoothGain | None = field(default=None, repr=False, compare=False)
    out_scale: np.ndarray | None = None
    out_offset: np.ndarray | None = None
    wb: tuple[float, ...] | None = None
    name = "sensor"
    in_channels = 1
    out_channels = 1

    def __post_init__(self) -> None:
        n = self.cfa.n_channels
        self.black = np.broadcast_to(np.asarray(self.black, dtype=np.float64), (n,)).copy()
        self.white = float(self.white)
        self.out_scale = np.ones(n) if self.out_scale is None else np.asarray(self.out_scale, dtype=np.float64)
        self.out_offset = self.black.copy() if self.out_offset is None else np.asarray(self.out_offset, dtype=np.float64)
        self._devices: dict[int, dict[str, Any]] = {}
        self._host: dict[Any, Any] = {}             # the launches' host-side constants, made once
        self._strip_memo: dict[Any, Any] = {}        # per window: the strip launches (_strips)

    def __getstate__(self) -> dict[str, Any]:
        """Its parameters, not what a run left on it (device buffers, which do not pickle): a
        schedule's stages, reused by every call of one camera and settings, are pickled for the
        memo keys (executor._kept_metering_name), which were None after a first run."""
        return {k: v for k, v in self.__dict__.items() if k not in ("_devices", "_host", "_strip_memo")}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._devices, self._host, self._strip_memo = {}, {}, {}

    @property
    def halo(self) -> int:
        return HALO

    @property
    def bytes_per_pixel(self) -> float:
        """The output and the windows of the planes it reads (mask 2, dark and flat 4 bytes)."""
        return 4.0 * 2 + 2.0 * (self.mask is not None) + 4.0 * (self.dark is not None) + 4.0 * (self.flat is not None)

    def fuse(self, following: Stage) -> Stage | None:
        """A following per-channel affine (normalisation, white balance pass 1) folds into the output."""
        if isinstance(following, CfaAffine):
            o, s = np.asarray(following.offset, dtype=np.float64), np.asarray(following.scale, dtype=np.float64)
            fused = replace(self, out_scale=self.out_scale * s, out_offset=(self.out_offset - o) * s)
            fused._devices = self._devices        # one device state for both
            return fused
        return None

    # ------------------------------------------------------------------------------- reference

    def reference(self, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
        return self.correct(x, origin)[0]

    def correct(self, x: np.ndarray, origin: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """(the corrected window less the halo, float64; the bool map of the pixels the auto test found)."""
        x = np.asarray(x, dtype=np.float64)
        height, width = x.shape
        oy, ox = int(origin[0]), int(origin[1])
        cfa, p, r = self.cfa, self.cfa.period, HALO
        ch = cfa.channel_map(height, width, origin)
        ys = np.arange(height)[:, None] + oy
        xs = np.arange(width)[None, :] + ox
        g1 = self.terms.gain(1, ys, xs) if self.terms is not None else np.ones((height, width))
        off = window_of(self.dark, origin, x.shape, p).astype(np.float64) if self.dark is not None else self.black[ch]
        raw = x
        mask = window_of(self.mask, origin, x.shape, p) != 0 if self.mask is not None else np.zeros(x.shape, bool)
        extent = image_extent(origin) or (1 << 30, 1 << 30)
        outside = ~(((ys >= 0) & (ys < extent[0])) & ((xs >= 0) & (xs < extent[1])))   # left out as neighbours
        out_h, out_w = height - 2 * r, width - 2 * r
        w_out = np.empty((out_h, out_w))
        found = np.zeros((out_h, out_w), bool)
        nb, nb_n, pairs, pairs_n = neighbour_tables(cfa)
        inv_range = 1.0 / (self.white - self.black)
        for k in range(p * p):
            ky, kx = divmod(k, p)
            rows = np.arange((ky - oy - r) % p, out_h, p) + r           # window rows of this phase
            cols = np.arange((kx - ox - r) % p, out_w, p) + r
            if not len(rows) or not len(cols):
                continue
            c = int(cfa.pattern[ky, kx])
            gp = g1[np.ix_(rows, cols)]

            def w_at(dy: int, dx: int) -> np.ndarray:
                idx = np.ix_(rows + dy, cols + dx)
                return raw[idx] * gp - (off[idx] if np.ndim(off) == 2 else off[idx])

            def masked(dy: int, dx: int) -> np.ndarray:
                idx = np.ix_(rows + dy, cols + dx)
                return mask[idx] | (outside[idx] if (dy or dx) else False)

            w = w_at(0, 0)
            within = ~outside[np.ix_(rows, cols)]               # a pixel beyond the image is not tested
            bad = masked(0, 0) & within
            offs = [tuple(int(v) for v in nb[k, j]) for j in range(nb_n[k])]
            t = self.test or DefectTest.noiseless(cfa.n_channels, self.wb)
            wb = np.asarray(t.wb)

            def y_at(dy: int, dx: int) -> np.ndarray:            # Y: the 4 nearest pixels, white-balanced
                total = 0.0
                for ey, ex in ((-1, 0), (1, 0), (0, -1), (0, 1)):
                    idx = np.ix_(rows + dy + ey, cols + dx + ex)
                    cq = ch[idx]
                    total = total + (raw[idx] * gp - (off[idx] if np.ndim(off) == 2 else off[idx])) * inv_range[cq] * wb[cq]
                return total / 4.0

            est, y_bar, w_bar, paired = self._estimate(w_at, y_at, masked, offs, k, pairs, pairs_n, w, inv_range[c], wb[c])
            if self.test is not None and offs:
                vals = np.stack([np.where(masked(*o), np.nan, w_at(*o)) for o in offs])
                missing = np.isnan(vals)                 # masked, or outside the image
                used = np.any(~missing, axis=0)          # without any (a window outside the image): 0, not tested
                hi = np.where(used, np.max(np.where(missing, -np.inf, vals), axis=0), 0.0)
                lo = np.where(used, np.min(np.where(missing, np.inf, vals), axis=0), 0.0)
                up, uhi, ulo = w * inv_range[c], hi * inv_range[c], lo * inv_range[c]
                spread = t.alpha * (uhi - ulo) + FLOOR
                hot = up - uhi - np.maximum(t.k * np.sqrt(t.noise_a[c] * np.maximum(uhi, 0) + t.noise_b[c]),
                                            np.minimum(t.hot_cap, t.hot_slope * np.maximum(uhi, 0))) - spread
                lo_p = np.maximum(ulo, 0)
                dim = t.rho * lo_p - up - t.kr * np.sqrt(t.noise_a[c] * (t.rho + t.rho ** 2) * lo_p
                                                         + (1 + t.rho ** 2) * t.noise_b[c])
                cold = np.minimum(ulo - up - t.k_cold * np.sqrt(t.noise_a[c] * lo_p + t.noise_b[c]), dim) - spread
                black = up < t.k_cold * np.sqrt(t.noise_b[c]) + FLOOR          # a dead pixel reads black
                cand = ~bad & used & within & ((hot > 0) | ((cold > 0) & black))
                with np.errstate(all="ignore"):
                    excess = (w - w_bar) * inv_range[c] * wb[c]
                    var = wb[c] * t.noise_a[c] * np.maximum(np.nan_to_num(y_bar), 0) + wb[c] ** 2 * t.noise_b[c]
                    lit = (y_at(0, 0) - y_bar) * np.sign(excess) + t.z * np.sqrt(0.375 * var)
                    # a dead pixel between a pair (surrounded): no support test
                    unsupported = np.isnan(y_bar) | ((excess < 0) & paired) | (lit < t.gamma * np.abs(excess))
                new = cand & (np.abs(excess) > 0) & unsupported
                found[np.ix_(rows - r, cols - r)] = new
                bad = bad | new
            if bad.any():
                w = np.where(bad, est, w)
            gain = np.ones_like(w)
            if self.flat is not None:
                gain = gain * window_of(self.flat, origin, x.shape, p)[np.ix_(rows, cols)]
            if self.terms is not None:
                gain = gain * self.terms.gain(2, (rows + oy)[:, None], (cols + ox)[None, :])
            if self.smooth is not None:
                gain = gain / self.smooth.at(c, (rows + oy)[:, None], (cols + ox)[None, :])
            w_out[np.ix_(rows - r, cols - r)] = w * gain * self.out_scale[c] + self.out_offset[c]
        if image_extent(origin) is not None:
            pad_from_image(w_out, (oy + r, ox + r), extent, cfa.period)
        return w_out, found

    @staticmethod
    def _estimate(w_at, y_at, masked, offs, k, pairs, pairs_n, w, inv_range_c, wb_c):
        """(the replacement, the chosen pair's mean Y, its mean w, whether it has a pair) per pixel: along the opposite
        same-channel pair that differs least (in the channel and in Y, the white-balanced mean of
        each member's 4 nearest pixels), the pair's mean plus the colour difference Y(p) - Y(pair)
        (the channel follows the other channels' detail, as a demosaic assumes); without a pair (a
        pixel beside the image's edge or known bad ones) the good neighbours' mean, and their mean Y
        and w stand for the pair's in the support test (NaN and 0 without any good neighbour)."""
        best = np.full(w.shape, np.inf)
        est = np.zeros(w.shape)
        y_bar = np.full(w.shape, np.nan)
        w_bar = np.zeros(w.shape)
        y_p = y_at(0, 0)
        for j in range(pairs_n[k]):
            a, b = offs[pairs[k, j, 0]], offs[pairs[k, j, 1]]
            wa, wb_ = w_at(*a), w_at(*b)
            ya, yb = y_at(*a), y_at(*b)
            d = np.where(masked(*a) | masked(*b), np.inf, np.abs(wa - wb_) * inv_range_c + np.abs(ya - yb) / wb_c)
            better = d < best
            best = np.where(better, d, best)
            mean_y, mean_w = 0.5 * (ya + yb), 0.5 * (wa + wb_)
            est = np.where(better, mean_w + (y_p - mean_y) / (wb_c * inv_range_c), est)
            y_bar = np.where(better, mean_y, y_bar)
            w_bar = np.where(better, mean_w, w_bar)
        if offs:
            good = np.stack([~masked(*o) for o in offs])
            vals = np.stack([w_at(*o) for o in offs])
            ys = np.stack([y_at(*o) for o in offs])
            n = good.sum(axis=0)
            with np.errstate(all="ignore"):
                mean = np.where(n > 0, (vals * good).sum(axis=0) / np.maximum(n, 1), w)
                mean_y = np.where(n > 0, (ys * good).sum(axis=0) / np.maximum(n, 1), np.nan)
            none = np.isinf(best)                     # no pair: the good neighbours' means stand for it
            y_bar = np.where(none, mean_y, y_bar)
            w_bar = np.where(none, mean, w_bar)
        else:
            mean = w
        return np.where(np.isinf(best), mean, est), y_bar, w_bar, ~np.isinf(best)

    # ------------------------------------------------------------------------------- OpenCL

    def defines(self, raw_dtype: np.dtype) -> dict[str, object]:
        nb, _, pairs, _ = neighbour_tables(self.cfa)
        t = self.test
        return {"RAW_T": "ushort" if np.dtype(raw_dtype) == np.uint16 else "float", "CFA_PERIOD": self.cfa.period,
                "SC_HALO": HALO, "SC_RADIUS": RADIUS, "SC_NB_MAX": nb.shape[1], "SC_PAIRS_MAX": pairs.shape[1],
                "SC_DETECT": int(t is not None), "SC_DIAG": int(diagonals_same_channel(self.cfa)),
                "SC_EVEN": int(self.cfa.period == 2),
                "SC_MASK": int(self.mask is not None),
                "SC_DARK": int(self.dark is not None), "SC_FLAT": int(self.flat is not None),
                "SC_TERMS": 0 if self.terms is None else len(self.terms.ops),
                "SC_GRID": int(self.smooth is not None), "SC_TERM_SIZE": TERM_SIZE, "SC_EDGE_RUN": EDGE_RUN,
                "SC_LANE_ROWS": LANE_ROWS, "SC_SLACK": repr(SLACK) + "f",
                "SC_K": repr(float(t.k if t else K)) + "f", "SC_K_COLD": repr(float(t.k_cold if t else K_COLD)) + "f",
                "SC_ALPHA": repr(float(t.alpha if t else ALPHA)) + "f",
                "SC_GAMMA": repr(float(t.gamma if t else GAMMA)) + "f", "SC_Z": repr(float(t.z if t else Z)) + "f",
                "SC_RHO": repr(float(t.rho if t else RHO)) + "f", "SC_KR": repr(float(t.kr if t else KR)) + "f", "SC_FLOOR": repr(float(FLOOR)) + "f",
                "SC_HOT_SLOPE": repr(float(t.hot_slope if t else HOT_SLOPE)) + "f",
                "SC_HOT_CAP": repr(float(t.hot_cap if t else HOT_CAP)) + "f"}

    def lane_constants(self) -> np.ndarray:
        """sensor_screen's per-lane channel constants: for each phase (py, px) of a group's first pixel
        and lane k, the channel's black, 1 / range, noise a, noise b, out scale, out offset, and 1 where
        the screen's cold test may take the noise at its lowest neighbour's level (:func:`cold_at_level`),
        else 0 (float32, P x P x LANE_ROWS x LANES)."""
        p, t = self.cfa.period, self.test or DefectTest.noiseless(self.cfa.n_channels)
        cold = [float(cold_at_level(a, b, t.k_cold)) for a, b in zip(t.noise_a, t.noise_b)]
        per = np.stack([self.black, 1.0 / (self.white - self.black), np.asarray(t.noise_a), np.asarray(t.noise_b),
                        self.out_scale, self.out_offset, cold])                # LANE_ROWS x C
        out = np.zeros((p, p, LANE_ROWS, LANES), np.float32)
        for py in range(p):
            for px in range(p):
                channels = self.cfa.pattern[py, (px + np.arange(LANES)) % p]
                out[py, px] = per[:, channels]
        return out

    def _device(self, rt: Runtime) -> dict[str, Any]:
        """What the kernels read besides the window, once per runtime: the tables, the whole planes
        the device gathers windows from, the packed terms (the count of pixels found is the run's:
        Runtime.counter FOUND)."""
        state = self._devices.get(id(rt))
        if state is not None:
            return state
        nb, nb_n, pairs, pairs_n = neighbour_tables(self.cfa)
        t = self.test or DefectTest.noiseless(self.cfa.n_channels, self.wb)
        state = {"nb": rt.constant(nb), "nb_n": rt.constant(nb_n), "pairs": rt.constant(pairs),
                 "pairs_n": rt.constant(pairs_n), "noise_a": rt.constant(as_f32(t.noise_a)),
                 "noise_b": rt.constant(as_f32(t.noise_b)), "wb": rt.constant(as_f32(t.wb))}
        terms, maps = self.terms.pack() if self.terms is not None else (np.zeros((1, TERM_SIZE), np.float32),
                                                                         np.zeros(1, np.float32))
        state["terms"], state["maps"] = rt.constant(terms), rt.constant(maps)
        if self.smooth is not None:
            state["grid"], state["gh"], state["gw"], state["inv_cell"] = self.smooth.device(rt)
        else:
            state["grid"], state["gh"], state["gw"], state["inv_cell"] = rt.constant(np.ones(1, np.float32)), 1, 1, 1.0
        for key, plane in (("mask", self.mask), ("dark", self.dark), ("flat", self.flat)):
            state[key] = rt.host_source(plane) if plane is not None else None
        if not _metering(rt):
            self._devices[id(rt)] = state
        return state

    def _constants(self, rt: Runtime, state: dict[str, Any]) -> dict[str, Any]:
        """The kernels' arguments that no window changes (the channel constants, the tables), made
        once per runtime and kept on this stage object (its out_scale and out_offset are its own: a
        fused copy shares the device state, not these); not kept while metering."""
        key = ("constants", id(rt))
        constants = self._host.get(key)
        if constants is None:
            constants = dict(pattern=rt.constant(self.cfa.pattern), black=rt.constant(as_f32(self.black)),
                             inv_range=rt.constant(as_f32(1.0 / (self.white - self.black))),
                             out_scale=rt.constant(as_f32(self.out_scale)),
                             out_offset=rt.constant(as_f32(self.out_offset)),
                             **{k: state[k] for k in ("noise_a", "noise_b", "terms", "maps", "grid", "gh", "gw",
                                                      "inv_cell")})
            if not _metering(rt):
                self._host[key] = constants
        return constants

    def _strips(self, rt: Runtime, origin: tuple[int, int], width: int, height: int,
                extent: tuple[int, int]) -> tuple[list[tuple[Any, int, int, int]], list[tuple[Any, int, int, int]]]:
        """The launches of sensor_list's edge part and sensor_mirror for an output window of ``width`` x
        ``height`` at ``origin`` in an image of ``extent``: per launch its strip table on the
        device, the table's rows, the launch's columns and rows (:func:`stacked`). Kept per window
        on this stage object (a run's windows repeat call after call; at most STRIP_MEMO of them)."""
        key = (id(rt), origin[:2], width, height, extent)
        launches = self._strip_memo.get(key)
        if launches is None:
            beyond = beyond_strips(origin, width, height, extent) if image_extent(origin) is not None else []
            launches = tuple([(rt.constant(table), len(table), cols, rows)
                              for table, cols, rows in stacked(strips, by_width)]
                             for strips, by_width in ((edge_strips(origin, width, height, extent), False),
                                                      (beyond, True)))
            if not _metering(rt):
                if len(self._strip_memo) >= STRIP_MEMO:
                    self._strip_memo.clear()
                self._strip_memo[key] = launches
        return launches

    def _lanes(self, rt: Runtime) -> Any:
        """sensor_screen's lane constants (:meth:`lane_constants`) on the device, kept as :meth:`_constants`."""
        key = ("lanes8", id(rt))
        lanes = self._host.get(key)
        if lanes is None:
            lanes = rt.constant(self.lane_constants())
            if not _metering(rt):
                self._host[key] = lanes
        return lanes

    def _window(self, rt: Runtime, state: dict[str, Any], key: str, origin: tuple[int, int], src: DeviceImage,
                dtype: Any) -> tuple[Any, list[DeviceImage]]:
        """The window of plane ``key`` matching ``src`` (a device gather where the device reads the
        plane in place, else gathered on the host and uploaded), or a placeholder buffer."""
        plane = getattr(self, key)
        if plane is None:
            return rt.constant(np.zeros(1, dtype)), []
        whole = state.get(key)
        if _metering(rt):                                    # a metering run: count the buffer only
            img = rt.acquire(1, src.height, src.width, dtype)
        elif whole is not None:
            img = rt.gather_window(whole, int(origin[0]), int(origin[1]), src.height, src.width, self.cfa.period)
        else:
            img = rt.upload(window_of(plane, origin, (src.height, src.width), self.cfa.period))
        return img, [img]

    def enqueue(self, rt: Runtime, src: DeviceImage, origin: tuple[int, int]) -> DeviceImage:
        state = self._device(rt)
        width, height = src.width - 2 * HALO, src.height - 2 * HALO
        extent = image_extent(origin) or (1 << 30, 1 << 30)
        dst = rt.acquire(1, height, width)
        held: list[DeviceImage] = []
        planes = {}
        for key, dtype in (("mask", np.uint16), ("dark", np.float32), ("flat", np.float32)):
            planes[key], extra = self._window(rt, state, key, origin, src, dtype)
            held += extra
        args = dict(self._constants(rt, state), src=src, dst=dst, width=width, height=height, oy=int(origin[0]),
                    ox=int(origin[1]), mask=planes["mask"], dark=planes["dark"], flat=planes["flat"],
                    img_h=extent[0], img_w=extent[1])
        defines = self._host.get(src.dtype.str)
        if defines is None:                         # once per stage object (a schedule's are reused)
            defines = self._host[src.dtype.str] = self.defines(src.dtype)
        screening = self.test is not None or self.mask is not None
        cap = width * height                        # every pixel may be a candidate
        fix_items = max(1024, cap // CANDIDATES)
        if screening:
            count = rt.zeroed(1)                    # on a CPU device no command: see Runtime.zeroed
            candidates = rt.acquire(1, 1, cap, np.uint32)
            args.update(count=count, cap=cap)
            held += [count, candidates]
        else:
            candidates = rt.constant(np.zeros(1, np.uint32))
            args.update(count=rt.constant(np.zeros(1, np.uint32)), cap=0)
        groups = -(-width // LANES)
        flags = rt.acquire(1, height, groups, np.uint8) if screening else None
        rt.launch_named("sensor", "sensor_screen", groups, height,
                        dict(args, list=candidates, lanes8=self._lanes(rt),
                             flags=flags if flags is not None else rt.constant(np.zeros(1, np.uint8))),
                        defines, exact=False)
        edges, beyond = self._strips(rt, origin, width, height, extent)
        if flags is not None:                       # the flagged pixels and the search's edge pixels listed
            table, n, cols, rows = edges[0] if edges else (rt.constant(np.zeros(5, np.int32)), 0, 0, 0)
            rt.launch_named("sensor", "sensor_list", max(-(-groups // 64), -(-cols // EDGE_RUN)), max(height, rows),
                            dict(flags=flags, list=candidates, count=count, cap=cap, width=width, height=height,
                                 groups=groups, oy=int(origin[0]), ox=int(origin[1]), img_h=extent[0],
                                 img_w=extent[1], strips=table, n_strips=n), defines, exact=False,
                            depth=2 if n else 1)
            held.append(flags)
        if screening:
            rt.launch_named("sensor", "sensor_fix", FIX_ROW, -(-fix_items // FIX_ROW), dict(
                args, list=candidates, nb=state["nb"], nb_n=state["nb_n"], pairs=state["pairs"],
                pairs_n=state["pairs_n"], wb=state["wb"],
                found=rt.constant(np.zeros(1, np.uint32)) if _metering(rt) else rt.counter(FOUND)), defines, exact=False)
        for table, n, cols, rows in beyond:        # the corrected image, padded
            rt.launch_named("sensor", "sensor_mirror", cols, rows, dict(
                dst=dst, width=width, height=height, oy=int(origin[0]), ox=int(origin[1]), img_h=extent[0],
                img_w=extent[1], strips=table, n_strips=n), defines, exact=False)
        for img in held:
            rt.release(img)
        return dst


def pad_from_image(out: np.ndarray, at: tuple[int, int], extent: tuple[int, int], period: int) -> None:
    """Set ``out``'s pixels beyond the image (``out``'s pixel (0, 0) is image pixel ``at``; the image
    is ``extent`` = (H, W)) to the value at their CFA-mirror source (tiling.cfa_mirror_index) where
    that source is in ``out``, in place: the corrected image padded as the tile windows are (the
    reference of sensor_mirror).

    >>> out = np.arange(12.0).reshape(3, 4)            # image rows 0..2, columns -1..2 of a 3 x 5 image
    >>> pad_from_image(out, (0, -1), (3, 5), 2); out[:, 0].tolist()    # column -1 is column 1
    [2.0, 6.0, 10.0]
    """
    h, w = out.shape
    ys = np.arange(h) + at[0]
    xs = np.arange(w) + at[1]
    sy = cfa_mirror_index(ys, extent[0], period) - at[0]
    sx = cfa_mirror_index(xs, extent[1], period) - at[1]
    beyond = ((ys < 0) | (ys >= extent[0]))[:, None] | ((xs < 0) | (xs >= extent[1]))[None, :]
    ok = beyond & ((sy >= 0) & (sy < h))[:, None] & ((sx >= 0) & (sx < w))[None, :]
    yy, xx = np.nonzero(ok)
    out[yy, xx] = out[sy[yy], sx[xx]]


def edge_strips(origin: tuple[int, int], width: int, height: int,
                extent: tuple[int, int]) -> list[tuple[int, int, int, int]]:
    """(y0, x0, rows, cols) in output coordinates of the output window's pixels inside the image
    within RADIUS of its edge (an output window of ``width`` x ``height`` whose pixel (0, 0) is image
    pixel origin + HALO): the rows along the top and bottom, then the columns between them, each
    pixel once. The screen leaves these pixels out; sensor_fix tests them with the neighbours inside
    the image only, as the reference does. Pixels beyond the image are not tested: they are padded
    from the corrected image (:func:`beyond_strips`).

    >>> edge_strips((-4, -3), 10, 8, (8, 10))       # one row above the image
    [(1, 0, 2, 10), (7, 0, 1, 10), (3, 0, 4, 2), (3, 8, 4, 2)]
    >>> edge_strips((-3, -3), 10, 8, (8, 10))
    [(0, 0, 2, 10), (6, 0, 2, 10), (2, 0, 4, 2), (2, 8, 4, 2)]
    >>> edge_strips((-13, -13), 30, 28, (8, 10))     # 10 px of margin
    [(10, 10, 2, 10), (16, 10, 2, 10), (12, 10, 4, 2), (12, 18, 4, 2)]
    """
    ty, tx = origin[0] + HALO, origin[1] + HALO

    def span(lo: int, hi: int, base: int, size: int) -> tuple[int, int]:
        """Image coordinates [lo, hi) as output ones, clipped to the window (empty: b <= a)."""
        return max(lo - base, 0), min(hi - base, size)

    out = []
    h, w = extent
    cols = span(0, w, tx, width)                                # the image's columns
    mid = (min(RADIUS, h), max(RADIUS, h - RADIUS))             # the rows the row strips leave
    for lo, hi in ((0, mid[0]), (mid[1], h)):
        a, b = span(lo, hi, ty, height)
        if b > a and cols[1] > cols[0]:
            out.append((a, cols[0], b - a, cols[1] - cols[0]))
    a, b = span(mid[0], mid[1], ty, height)
    for lo, hi in ((0, min(RADIUS, w)), (max(RADIUS, w - RADIUS), w)):
        c0, c1 = span(lo, hi, tx, width)
        if b > a and c1 > c0:
            out.append((a, c0, b - a, c1 - c0))
    return out


def beyond_strips(origin: tuple[int, int], width: int, height: int,
                  extent: tuple[int, int]) -> list[tuple[int, int, int, int]]:
    """(y0, x0, rows, cols) in output coordinates of the output window's pixels beyond the image
    (the margin a later stage's halo reads), each pixel once: the rows above and below it, then
    the columns left and right of it between them. sensor_mirror pads them from the corrected image.

    >>> beyond_strips((-4, -3), 10, 8, (8, 10))       # one row above the image
    [(0, 0, 1, 10)]
    >>> beyond_strips((-13, -13), 30, 28, (8, 10))    # 10 px of margin on every side
    [(0, 0, 10, 30), (18, 0, 10, 30), (10, 0, 8, 10), (10, 20, 8, 10)]
    """
    ty, tx = origin[0] + HALO, origin[1] + HALO
    h, w = extent
    top, bottom = min(max(-ty, 0), height), min(max(h - ty, 0), height)     # output rows [top, bottom) inside
    left, right = min(max(-tx, 0), width), min(max(w - tx, 0), width)
    out = [(0, 0, top, width)] if top > 0 else []
    if bottom < height and bottom >= top:
        out.append((bottom, 0, height - bottom, width))
    if bottom > top:
        if left > 0:
            out.append((top, 0, bottom - top, left))
        if right < width:
            out.append((top, right, bottom - top, width - right))
    return out


def stacked(strips: list[tuple[int, int, int, int]], by_width: bool) -> list[tuple[np.ndarray, int, int]]:
    """The rectangles (y0, x0, rows, cols) as launches over their rows stacked along y (sensor.cl's
    stacked_strip): per launch its table, n x 5 int32 (y0, x0, rows, cols, first stacked row), and
    its extent (the widest cols, the rows summed). ``by_width``: one launch per run of rectangles of
    one width (beyond_strips' rows, then its columns: a launch as wide as the widest would mostly
    idle); else one launch for all (edge_strips, two pixels deep).

    >>> [(t.tolist(), c, r) for t, c, r in stacked([(0, 0, 2, 10), (6, 0, 2, 10), (2, 0, 4, 2)], True)]
    [([[0, 0, 2, 10, 0], [6, 0, 2, 10, 2]], 10, 4), ([[2, 0, 4, 2, 0]], 2, 4)]
    """
    groups: list[list[tuple[int, int, int, int]]] = []
    for strip in strips:
        if groups and (not by_width or groups[-1][-1][3] == strip[3]):
            groups[-1].append(strip)
        else:
            groups.append([strip])
    out = []
    for group in groups:
        firsts = np.cumsum([0] + [rows for _, _, rows, _ in group])
        table = np.array([(*strip, first) for strip, first in zip(group, firsts[:-1])], dtype=np.int32)
        out.append((table, max(cols for *_, cols in group), int(firsts[-1])))
    return out


def _metering(rt: Runtime) -> bool:
    """Whether ``rt`` is in a metering run (Runtime.metering: nothing is allocated or launched)."""
    return getattr(rt, "_meter", None) is not None


def cold_at_level(a: float, b: float, k: float = K) -> bool:
    """Whether the screen's cold test may take the noise at the level of the lowest of the neighbours it
    reads rather than at 0: a dead pixel is cold where lo - u - spread > k sigma(lo), sigma(l) =
    sqrt(a max(l, 0) + b); the left side less the right grows with lo wherever k a / (2 sigma) < 1,
    i.e. sqrt(b) > k a / 2 (with 1 % to spare), so a lower neighbour among those sensor_fix adds (its
    lo is at most the screen's) makes the pixel only less cold. False at high gain, where the shot
    noise dominates the floor.

    >>> cold_at_level(3e-5, 5e-7), cold_at_level(2e-3, 1e-5)
    (True, False)
    """
    return math.sqrt(max(b, 0.0)) > 1.01 * k * max(a, 0.0) / 2


def diagonals_same_channel(cfa: CFA) -> bool:
    """Whether the 4 pixels at (+-2, +-2) have every pixel's own channel (sensor_screen's neighbours):
    true for the Bayer and LMS CFAs and any 2 x 2 one."""
    p = cfa.period
    return all(cfa.pattern[(ky + dy) % p, (kx + dx) % p] == cfa.pattern[ky, kx]
               for ky in range(p) for kx in range(p) for dy in (-2, 2) for dx in (-2, 2))


# --------------------------------------------------------------------------------------------
# The smooth gain, after the chroma stage
# --------------------------------------------------------------------------------------------

@dataclass
class SensorShade(Stage):
    """The smooth gain G on the chroma stage's output (linear sRGB): out = M diag(G) M^-1 in, G_c
    per camera channel at each pixel (kernel ``sensor_shade``, halo 0). ``scale``: raw pixels per
    pixel of its input (2 after the half-size binning)."""

    smooth: SmoothGain = field(repr=False, compare=False)
    matrix: np.ndarray = field(default_factory=lambda: np.eye(3))
    scale: int = 1
    name = "sensor_shade"

    def __post_init__(self) -> None:
        self.matrix = np.asarray(self.matrix, dtype=np.float64).reshape(3, 3)

    def reference(self, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
        height, width = x.shape[:2]
        s = float(self.scale)
        ys = (np.arange(height)[:, None] + origin[0] + 0.5) * s - 0.5
        xs = (np.arange(width)[None, :] + origin[1] + 0.5) * s - 0.5
        cam = np.asarray(x, dtype=np.float64) @ np.linalg.inv(self.matrix).T
        g = np.stack([self.smooth.at(c, ys, xs) for c in range(3)], axis=-1)
        return (cam * g) @ self.matrix.T

    def enqueue(self, rt: Runtime, src: DeviceImage, origin: tuple[int, int]) -> DeviceImage:
        dst = rt.acquire(3, src.height, src.width)
        grid, gh, gw, inv_cell = self.smooth.device(rt)
        rt.launch_named("sensor_shade", "sensor_shade", src.width, src.height, dict(
            src=src, dst=dst, width=src.width, height=src.height, oy=int(origin[0]), ox=int(origin[1]),
            scale=float(self.scale), m=rt.constant(as_f32(self.matrix)),
            m_inv=rt.constant(as_f32(np.linalg.inv(self.matrix))), grid=grid, gh=gh, gw=gw, inv_cell=inv_cell),
            {}, exact=False)
        return dst
