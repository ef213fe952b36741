"""Flat fields through clisp.sim.simulate against the noise model (docs/model.md section 3).

For each CFA, gain and grey level, a 512 x 512 flat grey scene (no optics) is simulated; per CFA
channel the measured DN mean and variance are compared with the model's expectation
(``NoiseModel.expected_dn_mean_var``), as z-scores: (measured - expected) / standard error
(the variance's standard error from the sample's fourth moment). |z| < 5 passes.

    python tools/check_noise_model.py
"""
from __future__ import annotations

import sys

import numpy as np

import toolkit  # noqa: F401  (before clisp: puts this checkout on sys.path)

import clisp
from clisp.sim.noise import NoiseModel
from clisp.sim.simulate import inverse_isp_matrix

GAINS = (1, 8, 64)
LEVELS = (0.05, 0.5)
SIZE = 512


def channel_stats(dn: np.ndarray) -> tuple[float, float, float, float]:
    """(mean, variance, standard error of the mean, standard error of the variance)."""
    x = dn.astype(np.float64)
    n = x.size
    mean, var = x.mean(), x.var(ddof=1)
    m4 = ((x - mean) ** 4).mean()
    return mean, var, np.sqrt(var / n), np.sqrt(max(m4 - var ** 2 * (n - 3) / (n - 1), 1e-30) / n)


def main() -> int:
    model = NoiseModel()
    worst = 0.0
    print(f"{'cfa':<6}{'gain':>5}{'grey':>6}{'ch':>4}{'mean DN':>10}{'model':>10}{'z':>7}"
          f"{'var DN^2':>11}{'model':>10}{'z':>7}")
    for cfa in ("lms", "bayer"):
        a, _ = inverse_isp_matrix("lms" if cfa == "lms" else "bayer")
        for gain in GAINS:
            for level in LEVELS:
                sim = clisp.simulate(np.full((SIZE, SIZE, 3), level), cfa=cfa, gain=gain, optics="none",
                                     seed=gain * 100 + int(level * 100))
                channel = sim.raw.cfa.channel_map(SIZE, SIZE)
                raw_values = a @ np.full(3, level)
                for c, name in enumerate(sim.raw.cfa.channels):
                    mean, var, se_mean, se_var = channel_stats(sim.raw.data[channel == c])
                    exp_mean, exp_var = model.expected_dn_mean_var(raw_values[c], gain)
                    z_mean, z_var = (mean - exp_mean) / se_mean, (var - exp_var) / se_var
                    worst = max(worst, abs(z_mean), abs(z_var))
                    print(f"{cfa:<6}{gain:>5}{level:>6.2f}{name:>4}{mean:>10.2f}{float(exp_mean):>10.2f}{z_mean:>7.2f}"
                          f"{var:>11.2f}{float(exp_var):>10.2f}{z_var:>7.2f}")
    print(f"largest |z| = {worst:.2f} (pass: < 5)")
    return 0 if worst < 5 else 1


if __name__ == "__main__":
    sys.exit(main())
