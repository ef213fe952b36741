"""Sensor defects of the simulated camera (issue 44): what a real sensor adds to the ideal one.

Every defect is drawn from its own seeded stream, so the same ``seed`` gives the same sensor (the
fixed pattern) whatever the shot; the shot's noise has the simulation's own seed. Per pixel, in
electrons at analog gain g (N_fs the full-scale electrons, docs/model.md section 3)::

    light(x)  = raw(x) S_c(x) (1 + prnu n(x))             the ideal normalised raw through the lens
                                                           shading S and the photo-response
                                                           non-uniformity (PRNU); 0 on dead pixels
    dark(x)   = rate t m(x) + hot(x) N_fs t / t_shot        dark current (e-/s) over the exposure t with
                                                           its fixed pattern m (mean 1, DSNU), plus the
                                                           hot and warm pixels' excess
    e(x)      = Poisson(light N_fs + dark) + Normal(0, read^2);  DN as the NoiseModel

    S_c(x)    = cos^4(atan(rho tan theta_c)) (1 - a_c rho^2)      rho = distance from the centre over
              cos^4 theta_c = ``shading`` (the corner's relative   the distance to a corner
              illumination); a_c = (1 - shading) COLOUR_SHADING[c]  (colour shading, per channel)

``hot`` and ``warm`` pixels have an excess drawn uniformly from 0.5 to 1.5 times their level (a
share of full scale at the shot's exposure; dark-current defects, so they scale with exposure
time and show in dark frames); dead pixels have no photo-response. The ideal image (``--truth``)
is unchanged: every correction is scored against what a perfect sensor would give.

The matching frames a user would shoot (:func:`dark_frame`, :func:`flat_frame`): a dark frame has
the shot's exposure, gain and fixed pattern and no light; a flat frame is an even light
(FLAT_LEVEL of white at the centre) through the same shading and PRNU, at base gain (1) and
FLAT_TIME_SHARE of the shot's exposure, as one shoots flats: bright and at the lowest ISO.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import asdict, dataclass
from typing import Any, Mapping

import numpy as np

from ..cfa import CFA
from ..errors import ClispError
from .noise import NoiseModel
from ..io.opcodes import FixBadPixelsList, GainMap
from ..io.rawimage import RawImage

COLOUR_SHADING = (0.2, 0.0, 0.12)
"""Extra corner falloff of the first and third CFA channels (R or L, B or S) per unit of luminance
falloff [decision]: a lens and microlenses shade the long and short wavelengths more at the corners
(phone modules: 5-15 % between channels); shading 0.5 leaves R/L at 0.9, B/S at 0.94 of G/M's."""

DSNU = 0.4
"""Standard deviation of the dark current's per-pixel multiplier m (lognormal, mean 1) [decision]."""

FLAT_LEVEL = 0.6
"""Level of a simulated flat frame at the optical centre, as a share of white [decision]."""

FLAT_TIME_SHARE = 0.01
"""Exposure time of a simulated flat frame as a share of the shot's (a bright light, a short
exposure): its dark current and hot pixels scale with it."""

_STREAMS = {"hot": 1, "warm": 2, "dead": 3, "dark": 4, "prnu": 5}


@dataclass(frozen=True)
class SensorDefects:
    """The defects of a simulated sensor (all off by default).

    hot, warm, dead  fractions of the pixels (0..0.5 together).
    hot_level, warm_level   mean excess of hot and warm pixels, share of full scale at ``exposure_time``.
    dark_current     mean dark current in electrons per second (its fixed pattern: DSNU).
    exposure_time    the shot's exposure in seconds.
    shading          relative illumination at the corners (1: no lens shading), cos^4 law plus the
                     colour shading COLOUR_SHADING.
    prnu             standard deviation of the per-pixel response (photo-response non-uniformity).
    seed             seed of the fixed pattern (defect positions, DSNU, PRNU).
    """

    hot: float = 0.0
    hot_level: float = 0.5
    warm: float = 0.0
    warm_level: float = 0.05
    dead: float = 0.0
    dark_current: float = 0.0
    exposure_time: float = 0.01
    shading: float = 1.0
    prnu: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("hot", "warm", "dead", "hot_level", "warm_level", "dark_current", "prnu"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ClispError(f"sensor defects: {name} must be a number >= 0, got {value!r}")
        if self.hot + self.warm + self.dead > 0.5:
            raise ClispError("sensor defects: hot, warm and dead pixels together must be at most half the sensor")
        if not (math.isfinite(self.exposure_time) and self.exposure_time > 0):
            raise ClispError(f"sensor defects: exposure time must be > 0 s, got {self.exposure_time!r}")
        if not (math.isfinite(self.shading) and 0 < self.shading <= 1):
            raise ClispError(f"sensor defects: shading (corner illumination) must be in (0, 1], got {self.shading!r}")
        if self.prnu >= 0.5:
            raise ClispError(f"sensor defects: PRNU {self.prnu:g} is not below 0.5")

    @property
    def any(self) -> bool:
        return bool(self.hot or self.warm or self.dead or self.dark_current or self.shading < 1 or self.prnu)

    def to_dict(self) -> dict[str, Any]:
        return {k: (float(v) if k != "seed" else int(v)) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "SensorDefects":
        names = cls.__dataclass_fields__
        try:
            return cls(**{k: (int(v) if k == "seed" else float(v)) for k, v in d.items() if k in names})
        except (TypeError, ValueError) as exc:
            raise ClispError(f"bad sensor defect metadata: {exc}") from exc


def _rng(defects: SensorDefects, stream: str) -> np.random.Generator:
    return np.random.default_rng([int(defects.seed), _STREAMS[stream]])


def defect_sites(defects: SensorDefects, shape: tuple[int, int], kind: str) -> np.ndarray:
    """Flat indices (into H x W) of the ``kind`` ('hot', 'warm' or 'dead') pixels, sorted; no pixel
    has two defects (drawn as one permutation)."""
    n = shape[0] * shape[1]
    counts = [int(round(getattr(defects, k) * n)) for k in ("hot", "warm", "dead")]
    total = sum(counts)
    if total == 0:
        return np.zeros(0, dtype=np.int64)
    sites = np.random.default_rng([int(defects.seed), 0]).choice(n, size=total, replace=False)
    start = {"hot": 0, "warm": counts[0], "dead": counts[0] + counts[1]}[kind]
    size = counts[("hot", "warm", "dead").index(kind)]
    return np.sort(sites[start:start + size]).astype(np.int64)


def excess(defects: SensorDefects, shape: tuple[int, int]) -> np.ndarray:
    """H x W share of full scale each pixel's dark-current defect adds at the shot's exposure (hot
    and warm pixels: 0.5 to 1.5 times their level; 0 elsewhere)."""
    out = np.zeros(shape[0] * shape[1])
    for kind in ("hot", "warm"):
        sites = defect_sites(defects, shape, kind)
        level = getattr(defects, f"{kind}_level")
        out[sites] = level * _rng(defects, kind).uniform(0.5, 1.5, size=len(sites))
    return out.reshape(shape)


def dead_mask(defects: SensorDefects, shape: tuple[int, int]) -> np.ndarray:
    """H x W bool of the dead pixels."""
    out = np.zeros(shape[0] * shape[1], dtype=bool)
    out[defect_sites(defects, shape, "dead")] = True
    return out.reshape(shape)


def bad_sites(defects: SensorDefects, shape: tuple[int, int]) -> np.ndarray:
    """H x W bool of every hot, warm and dead pixel (the oracle's map)."""
    out = np.zeros(shape[0] * shape[1], dtype=bool)
    for kind in ("hot", "warm", "dead"):
        out[defect_sites(defects, shape, kind)] = True
    return out.reshape(shape)


def shading(defects: SensorDefects, cfa: CFA, shape: tuple[int, int], origin: tuple[int, int] = (0, 0),
            image: tuple[int, int] | None = None, per_channel: bool = False) -> np.ndarray:
    """Lens shading S: H x W at the CFA's sites (``per_channel``: H x W x n_channels, every
    channel's S at every pixel). ``origin`` and ``image`` (H, W of the whole image, default
    ``shape``) place a band of rows in the image."""
    ys = np.arange(origin[0], origin[0] + shape[0], dtype=np.float64)[:, None]
    xs = np.arange(origin[1], origin[1] + shape[1], dtype=np.float64)[None, :]
    per = np.stack([shading_at(defects, c, cfa.n_channels, ys, xs, image or shape)
                    for c in range(cfa.n_channels)], axis=-1)
    if per_channel:
        return per
    channel = cfa.channel_map(shape[0], shape[1], origin)
    return np.take_along_axis(per, channel[..., None].astype(np.int64), axis=-1)[..., 0]


def response(defects: SensorDefects, cfa: CFA, shape: tuple[int, int]) -> np.ndarray:
    """H x W multiplier of the light each pixel records: shading, PRNU, 0 on dead pixels."""
    out = shading(defects, cfa, shape) if defects.shading < 1 else np.ones(shape)
    if defects.prnu:
        out = out * (1.0 + defects.prnu * _rng(defects, "prnu").standard_normal(shape))
    if defects.dead:
        out[dead_mask(defects, shape)] = 0.0
    return out


def dark_electrons(defects: SensorDefects, shape: tuple[int, int], full_scale_e: float,
                   exposure_time: float | None = None) -> np.ndarray:
    """H x W expected dark electrons at ``exposure_time`` (default the shot's): dark current with its
    fixed pattern, and the hot and warm pixels' excess (``full_scale_e``: N_fs at the shot's gain,
    in which their level is given)."""
    t = defects.exposure_time if exposure_time is None else float(exposure_time)
    out = np.zeros(shape)
    if defects.dark_current:
        sigma2 = math.log(1.0 + DSNU ** 2)
        m = _rng(defects, "dark").lognormal(-sigma2 / 2, math.sqrt(sigma2), size=shape)
        out += defects.dark_current * t * m
    if defects.hot or defects.warm:
        out += excess(defects, shape) * full_scale_e * (t / defects.exposure_time)
    return out


def expose(light: np.ndarray, dark_e: np.ndarray, gain: float | None, noise: NoiseModel,
           rng: np.random.Generator) -> np.ndarray:
    """DN of a normalised light mosaic plus dark electrons: uint16, noisy and clipped at ``gain``; for
    ``gain`` None (noiseless) float32, without noise, quantisation or clipping (dark electrons
    counted at gain 1)."""
    if gain is None:
        n_fs = noise.full_scale_electrons(1.0)
        return ((light + dark_e / n_fs) * noise.range_dn + float(noise.black_level)).astype(np.float32)
    n_fs = noise.full_scale_electrons(gain)
    lam = np.clip(light, 0.0, 1.0e6) * n_fs + dark_e
    electrons = rng.poisson(lam).astype(np.float64)
    del lam
    electrons += rng.normal(0.0, noise.read_noise_e, size=light.shape)
    electrons *= noise.dn_per_electron(gain)
    electrons += float(noise.black_level)
    dn = np.rint(electrons, out=electrons)
    np.clip(dn, 0.0, float(noise.white_level), out=dn)
    return dn.astype(np.uint16)


def capture(raw_norm: np.ndarray, defects: SensorDefects, cfa: CFA, gain: float | None, noise: NoiseModel,
            rng: np.random.Generator) -> np.ndarray:
    """The shot through the defective sensor: DN of the ideal normalised mosaic ``raw_norm``. The
    light's noise is drawn as NoiseModel.sample draws it (where the light is the ideal one, no
    shading or PRNU, every pixel that is not defective gets exactly the defect-free raw's value for
    the same seed), the dark signal and the dead pixels' read noise from a stream of their own."""
    shape = raw_norm.shape
    n_fs = noise.full_scale_electrons(1.0 if gain is None else gain)
    light = raw_norm
    if defects.shading < 1 or defects.prnu:
        light = raw_norm * response(dataclasses.replace(defects, dead=0.0), cfa, shape)
    dark = dark_electrons(defects, shape, n_fs)
    if gain is None:
        out = expose(light, dark, None, noise, rng)
        if defects.dead:
            out[dead_mask(defects, shape)] = float(noise.black_level)
        return out
    electrons = rng.poisson(np.clip(light, 0.0, 1.0e6) * n_fs).astype(np.float64)
    electrons += rng.normal(0.0, noise.read_noise_e, size=shape)
    extra = np.random.default_rng([int(defects.seed), 99, int(rng.integers(1 << 31))])
    if dark.any():
        electrons += extra.poisson(dark)
    if defects.dead:
        dead = dead_mask(defects, shape)
        electrons[dead] = extra.normal(0.0, noise.read_noise_e, size=int(dead.sum()))
    electrons *= noise.dn_per_electron(gain)
    electrons += float(noise.black_level)
    dn = np.rint(electrons, out=electrons)
    np.clip(dn, 0.0, float(noise.white_level), out=dn)
    return dn.astype(np.uint16)


def dark_frame(defects: SensorDefects, cfa: CFA, shape: tuple[int, int], gain: float | None,
               noise: NoiseModel, seed: int) -> np.ndarray:
    """A dark frame: the shot's exposure, gain and fixed pattern, no light (noise seeded by ``seed``)."""
    n_fs = noise.full_scale_electrons(1.0 if gain is None else gain)
    return expose(np.zeros(shape), dark_electrons(defects, shape, n_fs), gain, noise, np.random.default_rng(seed))


def expected_dark(defects: SensorDefects, shape: tuple[int, int], gain: float | None, noise: NoiseModel) -> np.ndarray:
    """The noiseless dark frame (expected DN, float64; the oracle's)."""
    g = 1.0 if gain is None else gain
    return float(noise.black_level) + dark_electrons(defects, shape, noise.full_scale_electrons(g)) * noise.dn_per_electron(g)


def flat_frame(defects: SensorDefects, cfa: CFA, shape: tuple[int, int], gain: float | None,
               noise: NoiseModel, seed: int) -> np.ndarray:
    """A flat frame: an even light of FLAT_LEVEL through the shading and PRNU, at base gain 1 and
    FLAT_TIME_SHARE of the shot's exposure (its dark signal scaled by the time)."""
    base = 1.0 if gain is not None else None
    n_fs_shot = noise.full_scale_electrons(1.0 if gain is None else gain)
    dark = dark_electrons(defects, shape, n_fs_shot, defects.exposure_time * FLAT_TIME_SHARE)
    light = np.full(shape, FLAT_LEVEL) * response(defects, cfa, shape)
    return expose(light, dark, base, noise, np.random.default_rng(seed))


GAIN_MAP_POINTS = (25, 33)
"""Map points (vertical, horizontal) of the GainMaps the simulator writes for its lens shading: a
phone writes 13 x 17 or so; 25 x 33 keeps the bilinear map within 0.1 % of the cos^4 shading."""


def shading_at(defects: SensorDefects, channel: int, n_channels: int, ys: np.ndarray, xs: np.ndarray,
               image: tuple[int, int]) -> np.ndarray:
    """S of ``channel`` at (possibly fractional) pixel coordinates (ys, xs) of an ``image`` (H, W)."""
    height, width = image
    corner = float(defects.shading)
    dy, dx = np.asarray(ys, dtype=np.float64) + 0.5 - height / 2, np.asarray(xs, dtype=np.float64) + 0.5 - width / 2
    rho2 = (dy ** 2 + dx ** 2) / ((height / 2) ** 2 + (width / 2) ** 2)
    theta_c = math.acos(corner ** 0.25)
    cos2 = 1.0 / (1.0 + rho2 * math.tan(theta_c) ** 2)
    extra = (1.0 - corner) * (COLOUR_SHADING[channel] if channel < len(COLOUR_SHADING) else 0.0)
    return cos2 * cos2 * (1.0 - extra * rho2)


def gain_map_opcodes(defects: SensorDefects, cfa: CFA, shape: tuple[int, int],
                     points: tuple[int, int] = GAIN_MAP_POINTS) -> list:
    """The lens shading as DNG GainMap opcodes (OpcodeList2), as a phone writes it: one map per CFA
    phase (area from the phase's first pixel, row and column pitch the CFA period), each the inverse
    of its channel's shading at MapPointsV x MapPointsH points spanning the image edge to edge."""
    height, width = shape
    pv, ph = points
    v = np.linspace(0.0, 1.0, pv)
    h = np.linspace(0.0, 1.0, ph)
    ys, xs = v[:, None] * height - 0.5, h[None, :] * width - 0.5        # relative -> pixel centres
    p = cfa.period
    ops = []
    for ky in range(p):
        for kx in range(p):
            c = int(cfa.pattern[ky, kx])
            gains = (1.0 / shading_at(defects, c, cfa.n_channels, ys, xs, shape)).astype(np.float32)[..., None]
            ops.append(GainMap((ky, kx, height, width), 0, 1, p, p, (1.0 / (pv - 1), 1.0 / (ph - 1)), (0.0, 0.0),
                               gains, list_no=2, origin=(0, 0), image=(height, width)))
    return ops


def bad_pixel_list_opcode(defects: SensorDefects, shape: tuple[int, int], bayer_phase: int = 0):
    """The hot, warm and dead pixels as a DNG FixBadPixelsList opcode (OpcodeList1), as a camera
    keeps its factory-mapped defects."""
    rows, cols = np.nonzero(bad_sites(defects, shape))
    return FixBadPixelsList([(int(r), int(c)) for r, c in zip(rows, cols)], [], bayer_phase, list_no=1,
                            origin=(0, 0), image=tuple(shape))


def frames(raw: Any, defects: SensorDefects, kind: str, count: int, gain: float | None, seed: int,
           noise: NoiseModel = NoiseModel()) -> list:
    """``count`` dark or flat frames (``kind``) matching the simulated ``raw`` (a RawImage), as RawImages
    with the raw's levels and metadata: a dark frame the shot's gain and exposure time, a flat frame
    base gain and FLAT_TIME_SHARE of it; frame i's noise seeded by ``seed`` + i."""
    make = dark_frame if kind == "dark" else flat_frame
    out = []
    for i in range(count):
        data = make(defects, raw.cfa, raw.shape, gain, noise, seed + i)
        md = {k: v for k, v in raw.metadata.items() if k != "opcodes"}
        md.update(frame=kind, gain=gain if kind == "dark" or gain is None else 1.0,
                  sensor={**defects.to_dict(),
                          "exposure_time": defects.exposure_time * (FLAT_TIME_SHARE if kind == "flat" else 1.0)})
        out.append(RawImage(data=data, cfa=raw.cfa, black_level=raw.black_level, white_level=raw.white_level,
                            wb=raw.wb, colour_matrix=raw.colour_matrix, exposure=raw.exposure, metadata=md,
                            source=f"simulated {kind} frame {i + 1}"))
    return out


def oracle_frame(raw: Any, defects: SensorDefects, kind: str, gain: float | None,
                 noise: NoiseModel = NoiseModel()) -> Any:
    """The noiseless dark frame (its expected DN) or flat frame (FLAT_LEVEL through the true shading
    and PRNU) of ``raw``, float32: the oracle that tools/bench_sensor.py corrects with."""
    if kind == "dark":
        data = expected_dark(defects, raw.shape, gain, noise)
    else:
        data = float(noise.black_level) + FLAT_LEVEL * response(defects, raw.cfa, raw.shape) * noise.range_dn
    md = {k: v for k, v in raw.metadata.items() if k != "opcodes"}
    md.update(frame=kind)
    return RawImage(data=data.astype(np.float32), cfa=raw.cfa, black_level=raw.black_level,
                    white_level=raw.white_level, wb=raw.wb, colour_matrix=raw.colour_matrix, exposure=raw.exposure,
                    metadata=md, source=f"oracle {kind} frame")
