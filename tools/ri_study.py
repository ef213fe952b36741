"""The NumPy variants of issue 27's study (docs/RESULTS.md, "A fast residual interpolation"): which
parts of ARI carry its accuracy inside the pipeline. Each is a ``--numpy`` candidate of
tools/bench_demosaic_quality.py, ``func(mosaic, pattern) -> H x W x 3`` (pattern a Bayer phase name),
for example::

    python tools/bench_demosaic_quality.py --sets kodak,mcmaster,deadleaves --subset 6 --dead-leaves 4 \\
        --settings noiseless,noiseless-sharp --bayer '' --numpy ri_study:g1c1_gbtf,ri_study:ri_1d7

Built from clisp/modules/demosaic_ari/reference.py (ARI, its line fits, the GBTF merge, MLRI's
chroma) and clisp/modules/demosaic_ri/reference.py (the chosen one). Run 1 (v1 in docs/ri_study.csv):
``g<N>c<M>_<merge>[_mlric]``; run 2 (w1): ``w_*``; run 3 (w2): ``ri_*``; run 4 (n2): ``ri_mad``.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

import toolkit  # noqa: F401  (puts this checkout on sys.path)

from clisp.modules.demosaic_ari import reference as ari
from clisp.modules.demosaic_ri.reference import HALO, demosaic

Array = np.ndarray
Chroma = Callable[[Array, "ari.Sites", Array, float, float], tuple[Array, Array, Array]]


# ------------------------------------------------------------------- run 1: ARI's own options

def _ari(**options) -> Callable[[Array, str], Array]:
    def f(mosaic: Array, pattern: str = "RGGB") -> Array:
        return ari.demosaic_ari(mosaic, pattern, clip=None, **options)
    return f


g1c1_gbtf = _ari(green_iterations=1, chroma_iterations=1, green_merge="gbtf")
g1c1_mean = _ari(green_iterations=1, chroma_iterations=1, green_merge="mean")
g2c1_gbtf = _ari(green_iterations=2, chroma_iterations=1, green_merge="gbtf")
g2c1_mean = _ari(green_iterations=2, chroma_iterations=1, green_merge="mean")
g2c1_crit = _ari(green_iterations=2, chroma_iterations=1)
g1c1_gbtf_mlric = _ari(green_iterations=1, chroma_iterations=1, green_merge="gbtf", chroma="mlri")
g2c2_crit_mlric = _ari(green_iterations=2, chroma_iterations=2, chroma="mlri")


# ------------------------------------------------------------------- runs 2 and 3: one G iteration, GBTF merge

def ari_chroma(raw: Array, sites: "ari.Sites", green: Array, lo: float, hi: float) -> tuple[Array, Array, Array]:
    """ARI's steps 2 and 3, one iteration."""
    red, blue = ari._ari_rb(raw, sites, green, lo, hi, 1, ("ri", "mlri"))
    return red, green, blue


def mlri_chroma(radius: int, weighted: bool = True, laplacian: bool = True) -> Chroma:
    """MLRI's chroma step on a (2 radius + 1)^2 window; ``laplacian`` False: the plain RI slope."""
    def chroma(raw, sites, green, lo, hi):
        def gf(guide, target, mask):
            if laplacian:
                return ari.guided_filter(guide, target, mask, ("box", radius, radius), eps=0.0,
                                         laplacian=ari.LAPLACIAN_2D, lap_mask=mask, weighted=weighted,
                                         lap_floor=ari.MLRI_FLOOR)
            return ari.guided_filter(guide, target, mask, ("box", radius, radius), eps=ari.EPS, weighted=weighted)
        red, blue = ari._rb_by_ri(raw, sites, green, lo, hi, gf)
        return red, green, blue
    return chroma


def mean_chroma(a: Chroma, b: Chroma) -> Chroma:
    def chroma(raw, sites, green, lo, hi):
        x, y = a(raw, sites, green, lo, hi), b(raw, sites, green, lo, hi)
        return 0.5 * (x[0] + y[0]), green, 0.5 * (x[2] + y[2])
    return chroma


def one_iteration(chroma: Chroma, kinds: tuple[str, ...] = ("ri", "mlri"),
                  ri_window: tuple[int, int] | None = None) -> Callable[[Array, str], Array]:
    """ARI's step 1 with one iteration of ``kinds`` (``ri_window``: the RI kind's (along, across)
    radii instead of ARI's (2, 1)), the GBTF merge, then ``chroma``."""
    def f(mosaic: Array, pattern: str = "RGGB") -> Array:
        def core(raw, sites, lo, hi):
            saved = dict(ari.KINDS)
            if ri_window is not None:
                ari.KINDS["ri"] = ri_window
            try:
                lines = ari._ari_green(raw, sites, 1, kinds)
            finally:
                ari.KINDS.clear()
                ari.KINDS.update(saved)
            green = np.where(sites.g, raw, ari._merge_green(raw, sites, lines, "gbtf"))
            return chroma(raw, sites, green, lo, hi)
        return ari._run(mosaic, pattern, None, core)
    return f


w_ari_chroma = one_iteration(ari_chroma)
w_mlri5 = one_iteration(mlri_chroma(2))
w_mlri7 = one_iteration(mlri_chroma(3))
w_mean = one_iteration(mean_chroma(ari_chroma, mlri_chroma(5)))
w_ri5 = one_iteration(mlri_chroma(2, laplacian=False))
w_ri_only = one_iteration(ari_chroma, ("ri",))
w_mlri_only = one_iteration(ari_chroma, ("mlri",))

ri_2d = one_iteration(mlri_chroma(2), ("ri",))
ri_1d5 = one_iteration(mlri_chroma(2), ("ri",), (2, 0))
ri_1d7 = one_iteration(mlri_chroma(2), ("ri",), (3, 0))          # the chosen one: clisp's RI
ri_chroma3 = one_iteration(mlri_chroma(1), ("ri",))
ri_unweighted = one_iteration(mlri_chroma(2, weighted=False), ("ri",))


# ------------------------------------------------------------------- run 4: noise

def mad_noise_variance(mosaic: Array) -> float:
    """The mosaic's noise variance (its units^2) from the median absolute deviation of the
    same-channel Laplacian (taps 4 and -1 two pixels away: 20 sigma^2 on white noise)."""
    m = np.asarray(mosaic, dtype=np.float64)
    lap = 4 * m[2:-2, 2:-2] - m[:-4, 2:-2] - m[4:, 2:-2] - m[2:-2, :-4] - m[2:-2, 4:]
    sigma = 1.4826 * np.median(np.abs(lap - np.median(lap))) / np.sqrt(20.0)
    return float(sigma * sigma)


def ri_mad(mosaic: Array, pattern: str = "RGGB") -> Array:
    """clisp's RI reference (mirror-padded) with the chroma slope regularised by a global noise
    variance estimated from the mosaic (run 4's "c, K = 4"; the stage takes the sensor model's at
    the window's mean G instead). Its K = 16 and "g" rows were one-line edits of
    reference.CHROMA_NOISE_K and of green_fit's eps (+ K sigma^2)."""
    padded = np.pad(np.asarray(mosaic, dtype=np.float64), HALO, mode="reflect")
    return demosaic(padded, pattern, (-HALO, -HALO), noise=(0.0, mad_noise_variance(mosaic)))
