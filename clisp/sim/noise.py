"""Sensor noise model of the simulated camera (docs/model.md section 3).

Paper: 1 um pixel CMOS, read noise 1.5 e-, 0.14 counts/e-, 10-bit ADC. Interpretation [decision]:
0.14 DN/e- is the conversion gain at unity analog gain and gain g multiplies it; exposure is
lowered with g so that raw = 1.0 still maps to the white level::

    N_fs(g) = (WL - BL) / (0.14 g)                 electrons at raw = 1.0
    e       = Poisson(max(raw, 0) N_fs) + Normal(0, 1.5^2)
    DN      = clip(round(0.14 g e + BL), 0, WL)

Units: "raw" is black-subtracted, white-normalised (raw = (DN - BL) / (WL - BL)); electrons e-;
DN = ADC counts including the black pedestal.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Mapping

import numpy as np

from ..errors import ClispError

GAIN_MIN = 1.0
"""Smallest analog gain the simulator accepts."""
GAIN_MAX = 64.0
"""Largest analog gain the simulator accepts (the paper's highest)."""

_RAW_CAP = 1.0e6
"""Raw values above this many full scales are treated as this value before the Poisson draw.
They saturate anyway; the cap only keeps numpy's Poisson sampler within its range."""


def check_gain(gain: Any) -> float:
    """Return ``gain`` as a float after checking it is a finite number in [GAIN_MIN, GAIN_MAX]."""
    if isinstance(gain, bool) or not isinstance(gain, (int, float, np.integer, np.floating)):
        raise ClispError(f"analog gain must be a number in [{GAIN_MIN:g}, {GAIN_MAX:g}] or None "
                         f"(noiseless), got {gain!r}")
    value = float(gain)
    if not (math.isfinite(value) and GAIN_MIN <= value <= GAIN_MAX):
        raise ClispError(f"analog gain {value:g} is outside the supported range "
                         f"[{GAIN_MIN:g}, {GAIN_MAX:g}]; gain=None simulates without noise")
    return value


def _positive_gain(gain: Any) -> float:
    """Return ``gain`` as a float after checking it is finite and > 0 (model-level check)."""
    try:
        value = float(gain)
    except (TypeError, ValueError) as exc:
        raise ClispError(f"analog gain must be a positive number, got {gain!r}") from exc
    if not (math.isfinite(value) and value > 0.0):
        raise ClispError(f"analog gain must be a positive number, got {gain!r}")
    return value


@dataclass(frozen=True)
class NoiseModel:
    """Photon shot noise + Gaussian read noise + ADC quantisation and clipping.

    read_noise_e     read noise standard deviation in electrons.
    conversion_gain  DN per electron at unity analog gain (gain g gives conversion_gain * g).
    adc_bits         ADC resolution; white_level must fit in it.
    black_level      black pedestal in DN.
    white_level      saturation level in DN.
    """

    read_noise_e: float = 1.5
    conversion_gain: float = 0.14
    adc_bits: int = 10
    black_level: float = 64
    white_level: float = 1023

    def __post_init__(self) -> None:
        if not (math.isfinite(self.read_noise_e) and self.read_noise_e >= 0):
            raise ClispError(f"read noise must be >= 0 electrons, got {self.read_noise_e!r}")
        if not (math.isfinite(self.conversion_gain) and self.conversion_gain > 0):
            raise ClispError(f"conversion gain must be > 0 DN/e-, got {self.conversion_gain!r}")
        if isinstance(self.adc_bits, bool) or not isinstance(self.adc_bits, (int, np.integer)) \
                or not 1 <= int(self.adc_bits) <= 16:
            raise ClispError(f"ADC bits must be an integer in [1, 16], got {self.adc_bits!r}")
        adc_max = 2 ** int(self.adc_bits) - 1
        if not 0 <= self.black_level < self.white_level <= adc_max:
            raise ClispError(f"need 0 <= black level < white level <= {adc_max} (ADC maximum), "
                             f"got black {self.black_level!r}, white {self.white_level!r}")

    @property
    def range_dn(self) -> float:
        """White level minus black level in DN (the DN span of raw = 0..1)."""
        return float(self.white_level) - float(self.black_level)

    def dn_per_electron(self, gain: float) -> float:
        """Conversion gain at analog gain ``gain`` in DN/e-."""
        return self.conversion_gain * _positive_gain(gain)

    def full_scale_electrons(self, gain: float) -> float:
        """Electrons at raw = 1.0: N_fs = (WL - BL) / (conversion_gain * gain)."""
        return self.range_dn / self.dn_per_electron(gain)

    def sample(self, raw: np.ndarray, gain: float, rng: np.random.Generator) -> np.ndarray:
        """Noisy, quantised, clipped DN of a normalised raw array; same shape, uint16.

        raw: any shape, float, black-subtracted and white-normalised (1.0 = white level);
        negative values carry no signal (only read noise). The Poisson draw comes before the
        Gaussian draw, so a seeded ``rng`` reproduces the result exactly.
        """
        if not isinstance(rng, np.random.Generator):
            raise ClispError("noise sampling needs a numpy Generator (np.random.default_rng), "
                             f"got {type(rng).__name__}")
        raw = np.asarray(raw, dtype=np.float64)
        if not np.all(np.isfinite(raw)):
            raise ClispError("raw values for noise sampling contain NaN or infinite values")
        n_fs = self.full_scale_electrons(gain)
        lam = np.clip(raw, 0.0, _RAW_CAP) * n_fs
        shot = rng.poisson(lam)
        del lam
        electrons = rng.normal(0.0, self.read_noise_e, size=raw.shape)
        electrons += shot
        del shot
        electrons *= self.dn_per_electron(gain)
        electrons += float(self.black_level)
        dn = np.rint(electrons, out=electrons)
        np.clip(dn, 0.0, float(self.white_level), out=dn)
        return dn.astype(np.uint16)

    def variance(self, s: np.ndarray | float, gain: float, wb: np.ndarray | float = 1.0) -> np.ndarray:
        """Per-pixel noise variance in normalised, white-balanced units; float64, broadcast shape.

        ``var(s) = (w s N_fs + w^2 (read^2 + D^2/12)) / N_fs^2`` with D = 1/(conversion_gain g)
        electrons per DN (quantisation). ``s`` is the expected white-balanced signal (raw * w;
        negative s is treated as 0), ``w`` the total multiplier applied to the normalised raw
        channel (pass this RawImage.pass1_gains() to include the exposure factor 1/k_exp).
        """
        n_fs = self.full_scale_electrons(gain)
        w = np.asarray(wb, dtype=np.float64)
        step_e = 1.0 / self.dn_per_electron(gain)
        floor_e2 = self.read_noise_e ** 2 + step_e ** 2 / 12.0
        signal = np.maximum(np.asarray(s, dtype=np.float64), 0.0)
        return (w * signal * n_fs + w * w * floor_e2) / (n_fs * n_fs)

    def expected_dn_mean_var(self, raw_value: np.ndarray | float,
                             gain: float) -> tuple[np.ndarray, np.ndarray]:
        """Model (mean, variance) of DN at normalised raw level(s), ignoring clipping; float64.

        mean = BL + c N, var = c^2 (N + read^2) + 1/12 with c = conversion_gain g DN/e- and
        N = max(raw, 0) N_fs electrons. The 1/12 DN^2 rounding term (Sheppard) is accurate when
        the DN standard deviation is above ~0.5 DN.
        """
        c = self.dn_per_electron(gain)
        n = np.maximum(np.asarray(raw_value, dtype=np.float64), 0.0) * self.full_scale_electrons(gain)
        mean = float(self.black_level) + c * n
        var = c * c * (n + self.read_noise_e ** 2) + 1.0 / 12.0
        return mean, var

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready description (plain Python numbers) for raw-file metadata."""
        d = asdict(self)
        return {"read_noise_e": float(d["read_noise_e"]), "conversion_gain": float(d["conversion_gain"]),
                "adc_bits": int(d["adc_bits"]), "black_level": float(d["black_level"]),
                "white_level": float(d["white_level"])}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "NoiseModel":
        """Inverse of ``to_dict``; missing keys take the defaults, unknown keys are ignored."""
        if not isinstance(d, Mapping):
            raise ClispError(f"noise model metadata must be a mapping, got {type(d).__name__}")
        kwargs: dict[str, Any] = {}
        try:
            for key in ("read_noise_e", "conversion_gain", "black_level", "white_level"):
                if key in d:
                    kwargs[key] = float(d[key])
            if "adc_bits" in d:
                kwargs["adc_bits"] = int(d["adc_bits"])
        except (TypeError, ValueError) as exc:
            raise ClispError(f"bad noise model metadata {dict(d)!r}: {exc}") from exc
        return cls(**kwargs)


@dataclass(frozen=True)
class ChannelNoise:
    """Noise of one white-balanced, normalised sample of CFA channel c at expected level s::

        var_c(s) = shot[c] * max(s, 0) + floor[c]        (units: white-balanced signal^2, white ~ 1)

    From docs/model.md section 3: shot = w / N_fs, floor = w^2 (read^2 + step^2 / 12) / N_fs^2, w the pass-1
    multiplier of the channel (white balance times exposure). ``source``: 'model' (from the sensor
    model), 'estimate' (measured on the raw, clisp.scene.noise) or 'none' (noiseless).
    """

    shot: tuple[float, ...]
    floor: tuple[float, ...]
    source: str = "model"

    def __post_init__(self) -> None:
        if len(self.shot) != len(self.floor):
            raise ClispError("noise: shot and floor need one value per CFA channel")
        if any(not math.isfinite(v) or v < 0 for v in (*self.shot, *self.floor)):
            raise ClispError(f"noise: shot and floor must be finite and >= 0, got {self.shot}, {self.floor}")

    @classmethod
    def zero(cls, n_channels: int = 3) -> "ChannelNoise":
        """No noise (noiseless simulation): every variance 0."""
        return cls((0.0,) * n_channels, (0.0,) * n_channels, "none")

    @classmethod
    def from_model(cls, model: NoiseModel, gain: float, pass1_gains: np.ndarray) -> "ChannelNoise":
        """From the sensor model at analog gain ``gain`` and the pass-1 multipliers per CFA channel."""
        w = np.asarray(pass1_gains, dtype=np.float64)
        floor = model.variance(0.0, gain, w)
        shot = model.variance(1.0, gain, w) - floor
        return cls(tuple(float(v) for v in shot), tuple(float(v) for v in floor), "model")

    @classmethod
    def from_metadata(cls, metadata: Mapping[str, Any], pass1_gains: np.ndarray) -> "ChannelNoise | None":
        """From RawImage.metadata: its ``gain`` (None = noiseless -> None) and ``noise`` dict (a
        NoiseModel; the default model when absent). Camera raws without a gain give None."""
        gain = metadata.get("gain") if metadata else None
        if gain is None:
            return None
        model = NoiseModel.from_dict(metadata.get("noise") or {})
        return cls.from_model(model, float(gain), pass1_gains)

    @property
    def is_zero(self) -> bool:
        return not any(self.shot) and not any(self.floor)

    def variance(self, channel: int, level: np.ndarray | float) -> np.ndarray:
        """var of a WB'd sample of ``channel`` at expected WB'd level(s) ``level``; float64."""
        return self.shot[channel] * np.maximum(np.asarray(level, dtype=np.float64), 0.0) + self.floor[channel]

    def scaled(self, factor: float) -> "ChannelNoise":
        """The same noise with every standard deviation multiplied by ``factor``."""
        f2 = float(factor) ** 2
        return ChannelNoise(tuple(v * f2 for v in self.shot), tuple(v * f2 for v in self.floor), self.source)


NOISELESS = ChannelNoise.zero(3)
"""Three noiseless channels: what the demosaics use when a raw carries no noise description."""
