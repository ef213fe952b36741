"""RI Bayer demosaic (one-pass adaptive residual interpolation) as a Stage: the quality preset's
Bayer demosaic. Reference, algorithm and citations: reference.py beside this file (float64 NumPy,
the definition of correct); kernels: demosaic_ri.cl (one ``ri_<step>`` per step); schedule and
measurements: README.md.

Steps (radius = the halo the step reads; their sum is the stage's halo, 19; launches per window)::

    green_fit          4  4  per direction and fit, the weighted guided-filter fit of the G line
                             from the chroma line or the converse over 7 pixels (12 planes)
    green_apply        3  4  the coefficients' 1 / RMSE-weighted means along the line: the
                             tentatives t_g, t_c per direction (4 planes)
    green_residual     1  2  G - C along rows and along columns: the tentative plus the residual
                             interpolated along the line (2 planes)
    green_merge        4  1  G: the GBTF merge of the two differences at the chroma sites
    chroma_laplacians  2  1  the Laplacians of G and of the mosaic (2 planes)
    chroma_fit         2  8  per colour and pixel class, the weighted MLRI fit of R (B) from G over
                             5 x 5 windows, its slope regularised by the raw's noise (6 planes)
    chroma_apply       2  1  the tentative R and B (2 planes)
    complete_rgb       1  1  R, G, B: the tentatives plus the bilinear residual, times a fused matrix

Input: a white-balanced Bayer mosaic window, H x W (float32, or uint16 as a first stage), any of the
four phases; output: 3 x (H - 38) x (W - 38) float32 in the mosaic's units (or H x W x 3 with
``interleaved``). Nothing is clipped.

Example: a flat mosaic stays flat::

    >>> from clisp.cfa import bayer_cfa
    >>> out = DemosaicRI(bayer_cfa("GRBG")).reference(np.full((40, 41), 0.5), (0, 0))
    >>> out.shape, bool(np.allclose(out, 0.5))
    ((2, 3, 3), True)
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import lru_cache
from itertools import accumulate
from types import MappingProxyType

import numpy as np

from ...cfa import CFA
from ...engine.runtime import DeviceImage, Runtime, group_within
from ...engine.stage import Stage, as_f32
from ...sim.noise import ChannelNoise
from ..common.fused_matrix import FusedColourMatrix
from ..demosaic_ari.reference import EPS, MLRI_FLOOR, RMSE_FLOOR, SCALE, WEIGHT_REG
from ..demosaic_malvar.stage import channel_order, check_bayer
from .reference import CHROMA_NOISE_K, CHROMA_RADIUS, HALO, LINE_RADIUS, MERGE_REG, STEP_RADII, demosaic, smooth_taps


@lru_cache(maxsize=16)
def program_defines(raw_dtype: np.dtype, interleaved: bool) -> Mapping[str, object]:
    """The defines of demosaic_ri.cl: the reference's constants (8-bit units) and radii, the input
    type and the output layout (read-only; memoised: asked at every window)."""
    taps = "{" + ",".join(f"{float(v)!r}f" for v in smooth_taps()) + "}"
    return MappingProxyType({"RAW_T": raw_type(raw_dtype), "RI_SCALE": SCALE, "RI_EPS": EPS,
                             "RI_RMSE_FLOOR": RMSE_FLOOR, "RI_WEIGHT_REG": WEIGHT_REG, "RI_MERGE_REG": MERGE_REG,
                             "RI_LINE_R": LINE_RADIUS, "RI_CHROMA_R": CHROMA_RADIUS, "RI_SMOOTH": taps,
                             "INTERLEAVED": int(interleaved)})


@lru_cache(maxsize=64)
def chroma_fit_defines(raw_dtype: np.dtype, off_y: int, off_x: int) -> Mapping[str, object]:
    """The defines of demosaic_ri_chroma_fit.cl for one pixel class: its offsets (0 or 1) to the
    fitted colour's rows and columns, the constants and the window radius (read-only; memoised)."""
    return MappingProxyType({"RAW_T": raw_type(raw_dtype), "RI_SCALE": SCALE, "RI_RMSE_FLOOR": RMSE_FLOOR,
                             "RI_MLRI_FLOOR": MLRI_FLOOR, "RI_CHROMA_R": CHROMA_RADIUS, "RI_OFF_Y": off_y,
                             "RI_OFF_X": off_x})


def raw_type(dtype: np.dtype) -> str:
    """The kernels' mosaic type: ushort when the demosaic is the first stage of a uint16 raw."""
    return "ushort" if np.dtype(dtype) == np.uint16 else "float"


@dataclass
class DemosaicRI(FusedColourMatrix, Stage):
    """H x W white-balanced Bayer mosaic -> (H - 38) x (W - 38) x 3 camera RGB (module doc).

    noise        the raw's noise (white-balanced units; None or zero: noiseless): regularises the
                 chroma slope (reference.CHROMA_NOISE_K)
    matrix       3 x 3 applied to the output (identity unless a following ColourMatrix was fused in;
                 a schedule choice that saves one pass over the image)
    interleaved  write H x W x 3 (the host layout) instead of planes, when this is the last stage
    """

    cfa: CFA
    noise: ChannelNoise | None = None
    matrix: np.ndarray | None = field(default=None, compare=False)
    interleaved: bool = False
    name = "demosaic_ri"
    cfa_kinds = ("bayer",)
    in_channels = 1
    out_channels = 3

    def __post_init__(self) -> None:
        check_bayer(self.cfa, "the RI demosaic")

    @classmethod
    def for_raw(cls, raw) -> "DemosaicRI":
        """The stage for ``raw``: its CFA and its noise from the metadata's gain and noise model (None
        for noiseless simulations and camera raws without a gain)."""
        return cls(raw.cfa, ChannelNoise.from_metadata(raw.metadata, raw.pass1_gains()))

    def green_noise(self) -> tuple[float, float]:
        """(shot, floor) of the G samples' noise variance in the mosaic's units; zeros without noise."""
        if self.noise is None:
            return 0.0, 0.0
        g = self.cfa.bayer_roles[1]     # the doubled channel of the Bayer layout (check_bayer): G, M or L
        return float(self.noise.shot[g]), float(self.noise.floor[g])

    @property
    def halo(self) -> int:
        return HALO

    @property
    def bytes_per_pixel(self) -> float:
        """Device bytes per input pixel, 24 float32 planes: at the peak (ri_green_apply) the 12 fit
        planes and the 4 tentatives are alive; the later images (2 differences, G, 2 Laplacians, 6
        chroma fits, 2 tentatives, 3 outputs) reuse the pool as it allows (the smallest free buffer
        that fits: the differences take the fits' buffer, so G and the chroma images need new ones).
        Metered from an empty pool: 67 B/px on 120 x 120, 83 B/px on 300 x 1500
        (test_device_memory_within_declared)."""
        return 4.0 * 24

    def r_parity(self, origin: tuple[int, int], margin: int,
                 site: tuple[int, int] | None = None) -> tuple[int, int]:
        """(ry, rx) of the kernels for an output grid ``margin`` inside a window at ``origin``: its
        pixel (y, x) is an R site when y + ry and x + rx are even. ``site``: :meth:`r_site`, where the
        caller has it (a window asks 15 times; kept off the stage, whose pickle is a memo key)."""
        y0, x0 = self.r_site() if site is None else site
        return (origin[0] + margin - y0) % 2, (origin[1] + margin - x0) % 2

    def r_site(self) -> tuple[int, int]:
        """The first site of the R role (CFA.bayer_roles: R, L or M) in the CFA's tile."""
        return self.cfa.first_site(self.cfa.bayer_roles[0])

    def reference(self, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
        out = demosaic(np.asarray(x, dtype=np.float64), self.cfa.role_cfa().channel_map(2, 2, (0, 0)), origin,
                       self.green_noise())
        return self.apply_output_matrix(channel_order(out, self.cfa))

    # -- OpenCL ------------------------------------------------------------------------------
    def enqueue(self, rt: Runtime, src: DeviceImage, origin: tuple[int, int]) -> DeviceImage:
        defines = program_defines(src.dtype, self.interleaved)
        matrix = self.output_matrix() @ self.cfa.role_matrix()       # roles to channel order, then the matrix
        margins = dict(zip(STEP_RADII, accumulate(STEP_RADII.values())))   # step -> its output's margin
        site = self.r_site()

        def image(step: str, prev: DeviceImage, channels: int) -> DeviceImage:
            r = STEP_RADII[step]
            return rt.acquire(channels, prev.height - 2 * r, prev.width - 2 * r)

        def run(step: str, out: DeviceImage, args: dict[str, object], mosaic: bool = True, depth: int = 1) -> None:
            """Launch ri_<step> over ``out`` with ``args``, the output and (``mosaic``) the mosaic
            and the site parities of the step's grid; ``depth``: the line directions the launch
            does at once (the work-groups' third index)."""
            m = margins[step]
            ry, rx = self.r_parity(origin, m, site)
            args = {"out": out, "w": out.width, "h": out.height, **args}
            if mosaic:
                args.update(raw=src, raw_w=src.width, raw_m=m, ry=ry, rx=rx)
            rt.launch_named("demosaic_ri", f"ri_{step}", out.width, out.height, args, defines, inward=True,
                            depth=depth)

        def planes(name: str, img: DeviceImage, margin: int) -> dict[str, object]:
            """An input image's arguments: buffer, pitch, plane size and margin around the output."""
            return {name: img, f"{name}_w": img.width, f"{name}_plane": img.width * img.height,
                    f"{name}_m": margin}

        def plane(name: str, img: DeviceImage, margin: int) -> dict[str, object]:
            return {name: img, f"{name}_w": img.width, f"{name}_m": margin}

        # G along rows (along_x 1: planes 0-5, 0-1, 0) and columns (0: planes 6-11, 2-3, 1);
        # swap 0: G from the chroma line (t_g), 1: the chroma line from G (t_c): the four directions
        # (and the two residuals) one launch each, the direction the work-groups' third index
        fits = image("green_fit", src, 12)
        run("green_fit", fits, {}, depth=4)
        tent = image("green_apply", fits, 4)
        run("green_apply", tent, planes("fits", fits, STEP_RADII["green_apply"]), depth=4)
        rt.release(fits)
        dif = image("green_residual", tent, 2)
        run("green_residual", dif, planes("tent", tent, STEP_RADII["green_residual"]), depth=2)
        rt.release(tent)
        green = image("green_merge", dif, 1)
        run("green_merge", green, planes("dif", dif, STEP_RADII["green_merge"]))
        rt.release(dif)
        g_at = margins["green_merge"]
        laps = image("chroma_laplacians", green, 2)
        run("chroma_laplacians", laps, plane("g", green, STEP_RADII["chroma_laplacians"]))
        cfits = image("chroma_fit", laps, 6)
        self._chroma_fits(rt, src, green, laps, cfits, origin, margins)
        rt.release(laps)
        tent = image("chroma_apply", cfits, 2)
        run("chroma_apply", tent, {**planes("fits", cfits, STEP_RADII["chroma_apply"]),
                                   **plane("g", green, margins["chroma_apply"] - g_at)}, mosaic=False)
        rt.release(cfits)
        rgb = image("complete_rgb", tent, 3)
        run("complete_rgb", rgb, {**planes("tent", tent, STEP_RADII["complete_rgb"]),
                                  **plane("g", green, margins["complete_rgb"] - g_at),
                                  "m": rt.constant(as_f32(matrix))})
        rt.release(tent)
        rt.release(green)
        rgb.interleaved = self.interleaved
        return rgb

    def _chroma_fits(self, rt: Runtime, src: DeviceImage, green: DeviceImage, laps: DeviceImage,
                     out: DeviceImage, origin: tuple[int, int], margins: dict[str, int]) -> None:
        """ri_chroma_fit (its own program, demosaic_ri_chroma_fit.cl) over the four pixel classes of
        the output grid, R and B: a class's offsets to the colour's lattice are compile-time
        (RI_OFF_Y, RI_OFF_X: four small programs); a launch 2 deep covers the pixels (2 gy + sy,
        2 gx + sx) of R's class (sy, sx) and B's class (1 - sy, 1 - sx), whose offsets are the same."""
        m = margins["chroma_fit"]
        ry, rx = self.r_parity(origin, m, self.r_site())  # R rows: y + ry even
        shot, floor = self.green_noise()
        k = CHROMA_NOISE_K * 20.0
        args = {"reg_shot": k * shot * SCALE, "reg_floor": k * floor * SCALE * SCALE,
                "raw": src, "raw_w": src.width, "raw_m": m, "g": green, "g_w": green.width,
                "g_m": m - margins["green_merge"], "laps": laps, "laps_w": laps.width,
                "laps_plane": laps.width * laps.height, "laps_m": STEP_RADII["chroma_fit"], "out": out,
                "w": out.width, "h": out.height}
        for sy in (0, 1):
            for sx in (0, 1):                   # R's class (sy, sx) and B's (1 - sy, 1 - sx): the same offsets
                defines = chroma_fit_defines(src.dtype, (sy + ry) % 2, (sx + rx) % 2)
                n_y = [(out.height - cy + 1) // 2 for cy in (sy, 1 - sy)]    # rows of R's class, of B's
                n_x = [(out.width - cx + 1) // 2 for cx in (sx, 1 - sx)]
                # one launch 2 deep, its groups within the smaller class (every class has pixels: the
                # fits' image carries chroma_apply's and complete_rgb's halos, 3 px a side at least)
                rt.launch_named("demosaic_ri_chroma_fit", "ri_chroma_fit", max(n_x), max(n_y),
                                {**args, "sy0": sy, "sx0": sx, "base0": 0}, defines,
                                group=group_within(min(n_x), min(n_y)), inward=True, depth=2)
