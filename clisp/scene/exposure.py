"""Automatic exposure (``--auto-exposure``): LibRaw's auto-bright rule, estimated from the raw.

LibRaw (dcraw) brightens its output so that the brightest 1 % of the pixels reach white: per
channel c of the linear output it finds the level v_c that 1 % of the pixels exceed, takes
white = max_c v_c, and maps white to 1.0 (``auto_bright_thr`` 0.01; it never darkens, since no
level is above 1.0). rawpy's default postprocess does this, which is why camera JPEGs and rawpy
look brighter than clisp's colorimetric default.

clisp takes the same rule, measured before processing on the statistics pass's cell thumbnail (at
most 2^19 CFA cells): each cell's mean per CFA channel (black-subtracted, white-normalised, clipped
to [0, 1]), white-balanced (pass 1), through the raw's colour matrix and white balance
pass 2, as the pipeline would take a flat patch. The result is an exposure in EV applied like
``--exposure`` (clisp.pipeline.build_pipeline). On noise and fine texture a tile mean's 1 % level
is below the pixels', so the output's top 1 % can land above white: on dead leaves at a fifth of
white, gain 4, 1.14 of white for LMS (4 x 4 tiles, +0.19 EV), 0.96 for Bayer (2 x 2).
tools/bench_auto_exposure.py compares it with rawpy on camera raws.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from ..io.rawimage import RawImage
from .statistics import thumbnail

AUTO_SHARE = 0.01
"""The share of the pixels that reach white (LibRaw's auto_bright_thr)."""


def auto_exposure_ev(raw: RawImage, gains2: np.ndarray, limit: float, statistics: Any = None) -> float:
    """The exposure in EV (0..``limit``) that takes the level 1 % of the output's pixels exceed, in
    its brightest channel, to white (module docstring). ``gains2``: white balance pass 2's gains
    on linear sRGB (3,). 0 for a raw whose estimate is black. ``statistics``: the raw's
    clisp.scene.statistics.SceneStatistics, whose cell thumbnail then gives the tile colours
    (:func:`thumbnail_colours`), read here when None."""
    colours = thumbnail_colours(raw, statistics)
    matrix = np.asarray(raw.colour_matrix, dtype=np.float64)
    linear = (matrix @ colours.reshape(-1, colours.shape[-1]).T) * np.asarray(gains2, dtype=np.float64)[:, None]
    levels = np.minimum(np.percentile(linear, 100.0 * (1.0 - AUTO_SHARE), axis=1), 1.0)   # per channel row
    white = float(levels.max())
    if not white > 0.0:
        return 0.0
    return min(max(-math.log2(white), 0.0), limit)


def thumbnail_colours(raw: RawImage, statistics: Any = None) -> np.ndarray:
    """White-balanced camera colour (pass 1) of the raw's CFA cells, R x C x n: the statistics
    pass's cell thumbnail (every k-th cell of at most 2^19; ``statistics`` None: read here), each
    cell's channel means clipped to [0, 1] (LibRaw clips each sample first: the two differ only in
    cells that straddle black or white, and the estimate reads the top 1 %), times the pass-1 gains.

    >>> from clisp.sim.simulate import simulate
    >>> sim = simulate(np.full((64, 64, 3), 0.25), "bayer", gain=None, optics="none")
    >>> thumbnail_colours(sim.raw).shape
    (32, 32, 3)
    """
    cells = statistics.thumbnail()[0] if statistics is not None else \
        thumbnail(raw.data, raw.cfa, raw.black_level, raw.white_level)[0]
    return np.clip(cells.astype(np.float64), 0.0, 1.0) * raw.pass1_gains()
