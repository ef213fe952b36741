"""Half-size binning (``--half-size``): one output pixel per 2 x 2 block of the mosaic, no demosaic.

The preview path, as LibRaw's ``half_size``: the output has half the mosaic's width and height
(rounded up). Normalisation and white balance pass 1 are folded in, so the output is what a
demosaic's would be (white-balanced camera channels, H x W x 3, LMS in LMS space), on a grid twice
as coarse; the pipeline's later stages (highlights, colour matrix, white balance pass 2, exposure,
tone curve) run on it unchanged.

The rule, one for every CFA: output pixel (i, j) stands for the 2 x 2 block at mosaic (2i, 2j).
Each channel k is the mean of the normalised, white-balanced samples of channel k in the smallest
window centred on the block that holds every channel at every block position: the 2 + 2r square,
r = :func:`window_radius` (the stage's halo, in mosaic pixels)::

    v(p)     = (raw(p) - offset[c(p)]) * gain[c(p)]            c(p) the CFA channel of sample p
    out_k    = sum_{p in W, c(p) = k} v(p) / #{p in W : c(p) = k}

* Bayer (2 x 2 CFA): r = 0, W is the CFA cell itself: its R, the mean of its two G, its B, with
  no interpolation (LibRaw's half_size; it keeps one of the two G, we average both: less noise).
* LMS (the paper's 4 x 4 CFA, clisp.cfa): a 2 x 2 block holds L and M but S only at every other
  block, so r = 1: the 4 x 4 window centred on the block, which holds one whole CFA period (8 L,
  6 M, 2 S samples at every position). A box binning: every sample in the window counts once for
  its channel, without weights by distance. Why: it is the smallest symmetric window in which
  every output pixel sees every channel, so all pixels are made alike (no pixel interpolates a
  channel another measured); equal weights keep it a plain mean (the noise of an average, a flat
  field stays flat, and it is exactly what "bin" means). Its price: each channel's samples are
  centred up to 1 px (S: the 2 samples of a period) off the block's centre, a sub-pixel shift of
  the output's grid (half a pixel at most), and the 4 x 4 window overlaps its neighbours: L, M a
  little softer than a 2 x 2 mean would be. Preview quality, by design.

Any other CFA clisp reads is one of these two kinds (clisp.cfa: the four Bayer phases, LMS at any
phase); the same rule serves them, its window from :func:`window_radius`.

Steps (kernel ``half_size.cl``, one per step)::

    half_size_bin   r = window_radius(cfa)   the per-channel means above (a table of weights per
                                             block phase from the host)

Fused into the same kernel, as a schedule choice (the reference runs the stages one by one): the
stages that follow it on the preview path, each per pixel, halo 0 (:meth:`HalfSize.fuse`): the
highlight clamp (out_k <- min(out_k, cap_k)), the colour matrix and white balance pass 2 (one 3 x 3
m), the tone curve (sRGB encoding, 16-bit codes). The whole preview path is then one pass that
reads the raw once and writes the host's band (measured: docs/RESULTS.md, "Half size").

Example: a flat field of DN 600 with black 100, white 1100 and gains 1, 2, 4::

    >>> from clisp.cfa import bayer_cfa
    >>> stage = HalfSize(bayer_cfa("RGGB"), np.full(3, 100.0), np.array([1.0, 2.0, 4.0]) / 1000)
    >>> out = stage.reference(np.full((4, 6), 600.0), (0, 0))
    >>> out.shape, out[0, 0].tolist()
    ((2, 3, 3), [0.5, 1.0, 2.0])
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import lru_cache

import numpy as np

from ...cfa import CFA
from ...errors import ClispError
from ...engine.runtime import DeviceImage, Runtime
from ...engine.stage import Stage, as_f32
from ...sim.colorimetry import SRGB_ENCODING, quantize16, srgb_encode
from ..colour.stage import ColourMatrix, ToneCurve, srgb_source
from ..common.fused_matrix import FusedColourMatrix
from ..highlights.stage import HighlightClamp

BLOCK = 2
"""Mosaic pixels per output pixel along each axis (the stage's ``downscale``)."""


@lru_cache(maxsize=16)
def window_radius(cfa: CFA) -> int:
    """r: the smallest margin around a BLOCK x BLOCK block at every block position (even image
    coordinates) whose (BLOCK + 2 r) square holds every channel of ``cfa`` (Bayer 0, LMS 1).
    ClispError for a CFA whose period is not a multiple of BLOCK (none clisp reads)."""
    p = cfa.period
    if p % BLOCK:
        raise ClispError(f"--half-size bins {BLOCK}x{BLOCK} blocks: CFA {cfa.name} has an odd period {p}")
    for r in range(p):
        if all(len(np.unique(_window_channels(cfa, by, bx, r))) == cfa.n_channels
               for by in range(0, p, BLOCK) for bx in range(0, p, BLOCK)):
            return r
    raise ClispError(f"CFA {cfa.name}: a channel has no samples")


def _window_channels(cfa: CFA, by: int, bx: int, r: int) -> np.ndarray:
    """The channels of the (BLOCK + 2 r) square around the block at image (by, bx)."""
    side = BLOCK + 2 * r
    return cfa.channel_map(side, side, (by - r, bx - r))


@lru_cache(maxsize=16)
def phase_weights(cfa: CFA, r: int) -> np.ndarray:
    """(P, P, n_channels, side, side) float64, P = period / BLOCK block phases per axis, side =
    BLOCK + 2 r: the weight of window sample (dy, dx) in channel k's mean for a block at image
    (BLOCK by, BLOCK bx) with (by % P, bx % P) the phase: 1 / (channel k's samples in the window)
    where the sample is of channel k, else 0. Each channel's weights sum to 1."""
    p, n, side = cfa.period, cfa.n_channels, BLOCK + 2 * r
    phases = p // BLOCK
    table = np.zeros((phases, phases, n, side, side))
    for py in range(phases):
        for px in range(phases):
            channels = _window_channels(cfa, BLOCK * py, BLOCK * px, r)
            for k in range(n):
                mask = channels == k
                table[py, px, k] = mask / mask.sum()
    table.flags.writeable = False          # cached: shared by every call
    return table


def check_blocks(origin: tuple[int, int], r: int) -> None:
    """ValueError unless the blocks of a window at ``origin`` with halo ``r`` lie on even image
    coordinates (the planner's windows always do: clisp.engine.stage.advance)."""
    if (origin[0] + r) % BLOCK or (origin[1] + r) % BLOCK:
        raise ValueError(f"half size: window origin {tuple(origin)} + halo {r} is not on the {BLOCK}x{BLOCK} blocks")


@dataclass
class HalfSize(FusedColourMatrix, Stage):
    """H x W raw mosaic (DN) -> (H - 2r) / 2 x (W - 2r) / 2 x 3: each channel's mean over the
    (2 + 2r) window around each 2 x 2 block, normalised and white-balanced (module docstring).

    cfa         the raw's CFA (3 channels)
    offset      (3,) DN subtracted per CFA channel (the black level)
    gain        (3,) multiplier per CFA channel after it: white balance pass 1 / (white - black)
    cap         (3,) a fused HighlightClamp's caps (out_k <- min(out_k, cap_k), before the matrix),
                None: no clamp
    matrix      3 x 3 applied to the output (a following ColourMatrix fused in), None: identity
    tone        a fused ToneCurve's output: None (linear), 'float' (sRGB-encoded) or 'uint16'
                (16-bit codes)
    interleaved write H x W x 3 (the host layout) instead of planes, when this is the last stage
    """

    cfa: CFA
    offset: np.ndarray
    gain: np.ndarray
    cap: np.ndarray | None = field(default=None, compare=False)
    matrix: np.ndarray | None = field(default=None, compare=False)
    tone: str | None = None
    interleaved: bool = False
    name = "half_size"
    in_channels = 1
    out_channels = 3
    writes_into = True

    def __post_init__(self) -> None:
        if self.cfa.n_channels != 3:
            raise ClispError(f"--half-size needs a 3-channel CFA, not {self.cfa.name}")
        self.offset = np.asarray(self.offset, dtype=np.float64).reshape(3)
        self.gain = np.asarray(self.gain, dtype=np.float64).reshape(3)

    @classmethod
    def for_raw(cls, raw) -> "HalfSize":
        """Normalisation (black, white) and white balance pass 1 of ``raw`` folded into the binning,
        as clisp.modules.raw_scale applies them before a demosaic."""
        black = np.asarray(raw.black_level, dtype=np.float64)
        return cls(raw.cfa, black, np.asarray(raw.pass1_gains(), dtype=np.float64) / (float(raw.white_level) - black))

    @property
    def halo(self) -> int:
        return window_radius(self.cfa)

    @property
    def downscale(self) -> int:
        return BLOCK

    @property
    def out_dtype(self) -> np.dtype:
        return np.dtype(np.uint16 if self.tone == "uint16" else np.float32)

    @property
    def bytes_per_pixel(self) -> float:
        """Device bytes per input pixel: the 3 output planes (float32) on a grid of a quarter the pixels."""
        return 4.0 * 3 / BLOCK ** 2

    def reference(self, x: np.ndarray, origin: tuple[int, int]) -> np.ndarray:
        """The per-channel box means, from masked sums: ``x`` an H x W window whose (0, 0) is image
        pixel ``origin`` (``origin + halo`` even: the planner's), out (H - 2r) / 2 x (W - 2r) / 2 x 3."""
        r = self.halo
        check_blocks(origin, r)
        side = BLOCK + 2 * r
        h, w = (x.shape[0] - 2 * r) // BLOCK, (x.shape[1] - 2 * r) // BLOCK
        channel = self.cfa.channel_map(x.shape[0], x.shape[1], origin)
        v = (x.astype(np.float64) - self.offset[channel]) * self.gain[channel]
        out = np.empty((h, w, 3))
        for k in range(3):
            mask = (channel == k).astype(np.float64)
            sums, counts = np.zeros((h, w)), np.zeros((h, w))
            for dy in range(side):
                for dx in range(side):
                    rows = slice(dy, dy + BLOCK * h, BLOCK)
                    cols = slice(dx, dx + BLOCK * w, BLOCK)
                    sums += (v * mask)[rows, cols]
                    counts += mask[rows, cols]
            out[..., k] = sums / counts
        if self.cap is not None:
            out = np.minimum(out, np.asarray(self.cap, dtype=np.float64))
        out = self.apply_output_matrix(out)
        if self.tone is not None:
            out = srgb_encode(out)
        return quantize16(out) if self.tone == "uint16" else out

    def fuse(self, following: Stage) -> Stage | None:
        """The preview path's per-pixel stages folded into the binning's kernel, in their order: a
        HighlightClamp (its caps, and its fused matrix), ColourMatrix and WhiteBalance2 (one
        matrix), then a ToneCurve; None for anything else or out of that order."""
        if self.tone is not None or self.interleaved:
            return None
        if isinstance(following, HighlightClamp) and self.cap is None and self.matrix is None:
            return replace(self, cap=following.white * following.neutral, matrix=following.matrix)
        if isinstance(following, ColourMatrix):
            return super().fuse(following)
        if isinstance(following, ToneCurve) and following.bits == 16:      # 8-bit codes: the curve's own kernel
            return replace(self, tone="uint16" if following.quantize else "float",
                           interleaved=following.interleaved)
        return None

    # -- OpenCL ----------------------------------------------------------------------------
    def enqueue(self, rt: Runtime, src: DeviceImage, origin: tuple[int, int],
                out: DeviceImage | None = None) -> DeviceImage:
        r = self.halo
        check_blocks(origin, r)
        phases = self.cfa.period // BLOCK
        out_h, out_w = self.output_shape(src.height, src.width)
        dst = out if out is not None else rt.acquire(3, out_h, out_w, self.out_dtype)
        defines = {"RAW_T": "ushort" if src.dtype == np.uint16 else "float", "HS_BLOCK": BLOCK,
                   "HS_SIDE": BLOCK + 2 * r, "HS_PHASES": phases, "HS_CAP": int(self.cap is not None),
                   "ENCODE_SRGB": int(self.tone is not None), "QUANTIZE": int(self.tone == "uint16"),
                   "INTERLEAVED": int(self.interleaved)}
        generated = ""
        if self.tone is not None:
            defines.update(SRGB_ENCODING)
            generated = srgb_source(rt)
        block_y, block_x = ((origin[0] + r) // BLOCK) % phases, ((origin[1] + r) // BLOCK) % phases
        cap = np.zeros(3) if self.cap is None else self.cap
        rt.launch_named("half_size", "half_size_bin", out_w, out_h,
                        dict(raw=src, dst=dst, raw_w=src.width, out_w=out_w, out_h=out_h,
                             block_y=block_y, block_x=block_x, weights=rt.constant(as_f32(phase_weights(self.cfa, r))),
                             offset=rt.constant(as_f32(self.offset)), gain=rt.constant(as_f32(self.gain)),
                             cap=rt.constant(as_f32(cap)), m=rt.constant(as_f32(self.output_matrix()))),
                        defines, generated)
        dst.interleaved = self.interleaved
        return dst
