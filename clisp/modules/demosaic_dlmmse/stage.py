"""DLMMSE demosaic (Bayer only): directional linear minimum mean square-error estimation.

L. Zhang and X. Wu, "Color demosaicking via directional linear minimum mean square-error
estimation", IEEE Trans. Image Processing 14(12), 2167-2178, 2005; as documented by P. Getreuer,
"Zhang-Wu directional LMMSE image demosaicking", IPOL 1 (2011) 117-126, doi:10.5201/ipol.2011.g_zwld
(reference C code ``dmzhangwu.c``). Input: white-balanced Bayer mosaic in [0, 1].

Steps, each a function below and a kernel ``dlmmse_<step>`` in ``clisp/modules/demosaic_dlmmse/demosaic_dlmmse.cl``
(radius = the halo the step reads, along its direction)::

    directional_differences  r 2   Hamilton-Adams 1-D interpolation F_H (rows), F_V (columns) with
                                   [-1/4, 1/2, 1/2, 1/2, -1/4]; differences G - X:
                                   d = cfa - F at G sites, d = F - cfa at R/B sites
    smooth                   r 4   s = d smoothed along its own direction, [4,9,15,23,26,23,15,9,4]/128
    lmmse_fuse               r 4   at R/B sites, per direction over the 2M+1 = 9 samples along it:
                                   mu = s (centre; ``local_mean='window'``: the window mean of s),
                                   sx2 = sum s^2 / (2M) - (sum s)^2 / (2M (2M+1)),
                                   sv2 = mean (s - d)^2 + eps,
                                   u = mu + sx2 / (sx2 + sv2) (d - mu),
                                   e = sx2 - sx2^2 / (sx2 + sv2) + eps;
                                   fused Delta = (e_V u_H + e_H u_V) / (e_H + e_V) = G - X
    complete_rgb             r 2   G = X + Delta at R/B sites; Delta_GR at R and Delta_GB at B sites
                                   are Delta; the missing one at R/B sites is the mean of the 4
                                   diagonal neighbours; at G sites both are the mean of the 4 axial
                                   neighbours; R = G - Delta_GR, B = G - Delta_GB

Total halo 2 + 4 + 4 + 2 = 12. Measured samples are kept exactly (G at G sites, R at R sites,
B at B sites). Every step's radius is even, so all intermediate windows share the input's CFA phase.

Example: a flat mosaic is returned flat::

    >>> from clisp.cfa import bayer_cfa
    >>> out = DemosaicDLMMSE(bayer_cfa("RGGB")).reference(np.full((26, 27), 0.5), (0, 0))
    >>> out.shape, bool(np.allclose(out, 0.5))
    ((2, 3, 3), True)
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from ...cfa import CFA
from ...errors import ClispError
from ...engine.runtime import DeviceImage, Runtime, launch_exact
from ...engine.stage import Stage, as_f32
from ..common.fused_matrix import FusedColourMatrix
from ..demosaic_malvar.stage import channel_order, check_bayer

R, G, B = 0, 1, 2

INTERPOLATION = np.array([-1, 2, 2, 2, -1]) / 4.0
"""Hamilton-Adams 1-D interpolation along a row or column (step ``directional_differences``): neighbour mean plus half
the second difference of the centre channel."""

SMOOTHING = np.array([4, 9, 15, 23, 26, 23, 15, 9, 4]) / 128.0
"""Smoothing of the difference signals along their direction (step ``smooth``), about Gaussian sigma 2."""

WINDOW_RADIUS = 4
"""M: the LMMSE statistics use the 2M+1 = 9 smoothed samples along the direction (step ``lmmse_fuse``)."""

EPSILON = 0.1 / 255.0 ** 2
"""eps added to the noise variance and the error variance (step ``lmmse_fuse``): avoids 0/0 on flat areas."""

LOCAL_MEANS = ("centre", "window")

STEP_RADII = {
    "directional_differences": len(INTERPOLATION) // 2,
    "smooth": len(SMOOTHING) // 2,
    "lmmse_fuse": WINDOW_RADIUS,
    "complete_rgb": 2,          # diagonal fill (1) then axial fill (1)
}
"""Halo of each step; the stage's halo is their sum (12)."""


# -------------------------------------------------------------------------------------- steps

def correlate_valid(a: np.ndarray, weights: np.ndarray, axis: int) -> np.ndarray:
    """1-D correlation along ``axis`` (1: rows, x; 0: columns, y), valid part only; the other axis is
    cropped by the same radius, so the result is ``a`` shrunk by r = len(weights) // 2 on every side."""
    r = len(weights) // 2
    n = a.shape[axis] - 2 * r
    out = sum(w * np.take(a, np.arange(k, k + n), axis=axis) for k, w in enumerate(weights))
    return crop(out, r, axis=1 - axis)


def crop(a: np.ndarray, r: int, axis: int | None = None) -> np.ndarray:
    """``a`` less r pixels on both ends of ``axis`` (None: of both axes)."""
    if r == 0:
        return a
    if axis is None:
        return a[r:-r, r:-r]
    return a[r:-r] if axis == 0 else a[:, r:-r]


def directional_differences(x: np.ndarray, green: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(d_H, d_V): G - X observed along rows and along columns; halo 2.

    F = Hamilton-Adams interpolation of the other channel; d = cfa - F at G sites, F - cfa elsewhere."""
    r = STEP_RADII["directional_differences"]
    centre, is_green = crop(x, r), crop(green, r)
    out = []
    for axis in (1, 0):
        f = correlate_valid(x, INTERPOLATION, axis)
        out.append(np.where(is_green, centre - f, f - centre))
    return out[0], out[1]


def smooth(d_h: np.ndarray, d_v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(s_H, s_V): each difference smoothed along its own direction; halo 4."""
    return correlate_valid(d_h, SMOOTHING, 1), correlate_valid(d_v, SMOOTHING, 0)


def lmmse_direction(s: np.ndarray, d: np.ndarray, axis: int,
                    local_mean: str) -> tuple[np.ndarray, np.ndarray]:
    """(u, e): LMMSE estimate of G - X along one direction and its error variance; halo 4.

    ``s`` is on the same grid as the output of this step plus 4 on every side, ``d`` plus 8."""
    m = WINDOW_RADIUS
    n = 2 * m + 1
    s_win = crop(sliding_window_view(s, n, axis=axis), m, axis=1 - axis)        # (h, w, 9)
    d_win = crop(sliding_window_view(crop(d, m), n, axis=axis), m, axis=1 - axis)
    s_sum, s_sq = s_win.sum(axis=-1), (s_win ** 2).sum(axis=-1)
    mu = s_win[..., m] if local_mean == "centre" else s_sum / n
    sx2 = s_sq / (2 * m) - s_sum ** 2 / (2 * m * n)
    sv2 = ((s_win - d_win) ** 2).mean(axis=-1) + EPSILON
    u = mu + sx2 / (sx2 + sv2) * (d_win[..., m] - mu)
    e = sx2 - sx2 ** 2 / (sx2 + sv2) + EPSILON
    return u, e


def lmmse_fuse(s_h: np.ndarray, s_v: np.ndarray, d_h: np.ndarray, d_v: np.ndarray,
               not_green: np.ndarray, local_mean: str = "centre") -> np.ndarray:
    """Delta = G - X at R/B sites (NaN at G sites): the two directional estimates fused by inverse
    error variance; halo 4 (``not_green`` on the output grid)."""
    u_h, e_h = lmmse_direction(s_h, d_h, 1, local_mean)
    u_v, e_v = lmmse_direction(s_v, d_v, 0, local_mean)
    return np.where(not_green, (e_v * u_h + e_h * u_v) / (e_h + e_v), np.nan)


def diagonal_mean(a: np.ndarray) -> np.ndarray:
    """Mean of the 4 diagonal neighbours; halo 1."""
    return (a[:-2, :-2] + a[:-2, 2:] + a[2:, :-2] + a[2:, 2:]) / 4.0


def axial_mean(a: np.ndarray) -> np.ndarray:
    """Mean of the 4 axial neighbours; halo 1."""
    return (a[:-2, 1:-1] + a[2:, 1:-1] + a[1:-1, :-2] + a[1:-1, 2:]) / 4.0


def complete_rgb(x: np.ndarray, delta: np.ndarray, channel: np.ndarray) -> np.ndarray:
    """R, G, B from the mosaic ``x`` and Delta = G - X at R/B sites; halo 2 (``x``, ``channel`` on
    the grid of ``delta``)."""
    green = x + np.where(channel == G, 0.0, delta)
    out = []
    for c, other in ((R, B), (B, R)):
        diff = np.where(channel == c, delta, np.nan)                   # G - c, measured at c sites
        diff = np.where(crop(channel, 1) == other, diagonal_mean(diff), crop(diff, 1))
        diff = np.where(crop(channel, 2) == G, axial_mean(diff), crop(diff, 1))
        out.append(np.where(crop(channel, 2) == c, crop(x, 2), crop(green, 2) - diff))
    return np.stack([out[0], crop(green, 2), out[1]], axis=-1)


# -------------------------------------------------------------------------------------- stage

@dataclass
class DemosaicDLMMSE(FusedColourMatrix, Stage):
    """H x W white-balanced Bayer mosaic -> (H-24) x (W-24) x 3 camera RGB (Zhang-Wu DLMMSE).

    local_mean  mu of the LMMSE estimate: 'centre' (the smoothed difference at the pixel, Zhang's
                MATLAB code and Getreuer's default; ours) or 'window' (its mean over the
                9-sample window, as in the paper).
    matrix      3 x 3 applied to the output (identity unless a following ColourMatrix was fused in;
                a schedule choice for the OpenCL path that saves one pass over the image).
    interleaved write H x W x 3 (the host layout) instead of planes, when this is the last stage.
    """

    cfa: CFA
    local_mean: str = "centre"
    matrix: np.ndarray | None = field(default=None, compare=False)
    interleaved: bool = False
    name = "demosaic_dlmmse"
    in_channels = 1
    out_channels = 3

    def __post_init__(self) -> None:
        check_bayer(self.cfa, "the DLMMSE demosaic")
        if self.local_mean not in LOCAL_MEANS:
            raise ClispError(f"DLMMSE local_mean must be one of {', '.join(LOCAL_MEANS)}, "
                             f"got {self.local_mean!r}")

    @property
    def halo(self) -> int:
        return sum(STEP_RADII.values())

    @property
    def bytes_per_pixel(self) -> float:
        """Pooled device planes per input pixel: d_H, d_V, s_H, s_V, Delta and R, G, B (float32)."""
        return 4.0 * (2 + 2 + 1 + 3)

    def reference(self, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
        h, w = x.shape
        x = x.astype(np.float64)
        channel = self.cfa.role_cfa().channel_map(h, w, origin)          # roles: R, G, B (check_bayer)
        r1, r2, r3, _ = STEP_RADII.values()
        d_h, d_v = directional_differences(x, channel == G)
        s_h, s_v = smooth(d_h, d_v)
        core = crop(channel, r1 + r2 + r3)
        delta = lmmse_fuse(s_h, s_v, d_h, d_v, core != G, self.local_mean)
        out = complete_rgb(crop(x, r1 + r2 + r3), delta, core)
        return self.apply_output_matrix(channel_order(out, self.cfa))

    # -- OpenCL ----------------------------------------------------------------------------
    def defines(self, origin: tuple[int, int], raw_dtype: np.dtype) -> dict[str, object]:
        """Build options: the CFA as seen from the input window (its pattern rolled so that entry
        [0][0] is the channel of window pixel (0, 0); the same for every step's window, as all
        radii are even) and the algorithm's constants."""
        def floats(values: np.ndarray) -> str:
            return "{" + ",".join(f"{float(v)!r}f" for v in values) + "}"

        window_pattern = np.roll(self.cfa.role_cfa().pattern, (-origin[0], -origin[1]), axis=(0, 1))
        return {
            "CFA_PATTERN": "{" + ",".join(str(int(v)) for v in window_pattern.ravel()) + "}",
            "CFA_PERIOD": 2, "RED": R, "GREEN": G, "BLUE": B,   # the pattern in roles (CFA.role_cfa)
            "RAW_T": "ushort" if raw_dtype == np.uint16 else "float",
            "INTERP_RADIUS": STEP_RADII["directional_differences"], "INTERP_WEIGHTS": floats(INTERPOLATION),
            "SMOOTH_RADIUS": STEP_RADII["smooth"], "SMOOTH_WEIGHTS": floats(SMOOTHING),
            "WINDOW_RADIUS": WINDOW_RADIUS, "EPSILON": float(EPSILON),
            "WINDOW_MEAN": int(self.local_mean == "window"), "FILL_RADIUS": STEP_RADII["complete_rgb"],
            "INTERLEAVED": int(self.interleaved),
        }

    def enqueue(self, rt: Runtime, src: DeviceImage, origin: tuple[int, int]) -> DeviceImage:
        defines = self.defines(origin, src.dtype)
        matrix = self.output_matrix() @ self.cfa.role_matrix()       # roles to channel order, then the matrix

        def step(name: str, prev: DeviceImage, channels: int) -> tuple[object, DeviceImage]:
            """The step's kernel and its output image: ``prev`` shrunk by the step's radius."""
            r = STEP_RADII[name]
            out = rt.acquire(channels, prev.height - 2 * r, prev.width - 2 * r)
            return rt.kernel("demosaic_dlmmse", f"dlmmse_{name}", defines), out

        i32 = np.int32
        kernel, diff = step("directional_differences", src, 2)                # d_H, d_V
        launch_exact(rt, kernel, diff.width, diff.height,
                  src.buffer, diff.buffer, i32(src.width), i32(diff.width), i32(diff.height), inward=True)
        kernel, smoothed = step("smooth", diff, 2)                             # s_H, s_V
        launch_exact(rt, kernel, smoothed.width, smoothed.height, diff.buffer, smoothed.buffer,
                  i32(diff.width), i32(diff.height), i32(smoothed.width), i32(smoothed.height), inward=True)
        kernel, delta = step("lmmse_fuse", smoothed, 1)                        # G - X at R/B sites
        launch_exact(rt, kernel, delta.width, delta.height, smoothed.buffer, diff.buffer, delta.buffer,
                  i32(smoothed.width), i32(smoothed.height), i32(diff.width), i32(diff.height),
                  i32(delta.width), i32(delta.height), inward=True)
        rt.release(smoothed)
        rt.release(diff)
        kernel, rgb = step("complete_rgb", delta, 3)
        launch_exact(rt, kernel, rgb.width, rgb.height, src.buffer, delta.buffer, rgb.buffer,
                  i32(src.width), i32(delta.width), i32(rgb.width), i32(rgb.height),
                  rt.constant(as_f32(matrix)), inward=True)
        rt.release(delta)
        rgb.interleaved = self.interleaved
        return rgb
