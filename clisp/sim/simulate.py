"""Raw simulation ("inverse ISP", docs/model.md section 2): linear sRGB scene -> CFA mosaic in DN.

Steps, per image::

    x_o  = K * x                             optics (Airy PSF or none), per channel; ground truth
    raw  = k_exp (inv(M) x_o) / WB           camera raw, M and WB from colorimetry.camera_constants
    k_exp = 1 / max_c raw_c(white)           sRGB white reaches full scale on the brightest channel
    mosaic: keep channel cfa.channel_map(y, x) at each pixel
    DN   = raw (WL - BL) + BL                noiseless (float32, no quantisation, no clipping), or
    DN   = NoiseModel.sample(raw, gain)      noisy (uint16, quantised and clipped)

:func:`simulate_large` does the same for the scene repeated (alternate copies mirrored) to any
size, band by band, for test images larger than memory (``clisp simulate --size``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..version import __version__
from ..cfa import CFA, cfa_from_name
from .colorimetry import camera_constants
from ..errors import ClispError
from .noise import NoiseModel, check_gain
from .optics import airy_kernel, blur_channel
from ..io.rawimage import RawImage
from ..engine.tiling import Tile, cfa_mirror_index, grid

if TYPE_CHECKING:
    from .defects import SensorDefects      # imported where a capture has defects (start-up)

OPTICS_KINDS = ("airy", "none")


@dataclass
class SimResult:
    """A simulated capture.

    raw    the mosaic and its processing metadata (RawImage, source 'simulated').
    truth  H x W x 3 float32 linear sRGB after the optics: the reference for metrics.
    """

    raw: RawImage
    truth: np.ndarray


def resolve_cfa(cfa: CFA | str) -> CFA:
    """A CFA instance, or one parsed from a name accepted by ``cfa_from_name``."""
    if isinstance(cfa, CFA):
        return cfa
    if isinstance(cfa, str):
        return cfa_from_name(cfa)
    raise ClispError(f"cfa must be a CFA or a name such as 'lms' or 'bayer-rggb', got {cfa!r}")


def inverse_isp_matrix(kind: str) -> tuple[np.ndarray, float]:
    """(A, k_exp) for spectral kind 'lms' or 'rgb' (or 'bayer'): A (3 x 3) maps linear sRGB to exposed raw channels.

    ``A = k_exp * diag(1/WB) @ inv(M)`` so that ``max_c (A @ [1, 1, 1])_c = 1``.
    k_exp is 0.98951 for LMS and 1.0 for Bayer.
    """
    try:
        matrix, wb = camera_constants(kind)
    except ValueError as exc:
        raise ClispError(f"no camera constants for CFA channels {kind!r} (clisp simulates L, M, S or R, G, B)") from exc
    a = np.linalg.inv(matrix) / np.asarray(wb, dtype=np.float64)[:, None]
    k_exp = 1.0 / float(np.max(a @ np.ones(3)))
    return a * k_exp, k_exp


def _check_scene(scene: Any) -> np.ndarray:
    """Validate an H x W x 3 finite real array (linear sRGB, white = 1.0) and return it."""
    arr = np.asarray(scene)
    if arr.dtype.kind not in "fiu":
        raise ClispError(f"scene must be a real-valued array of linear sRGB, got dtype {arr.dtype}")
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] < 1 or arr.shape[1] < 1:
        raise ClispError(f"scene must be an H x W x 3 linear sRGB array, got shape {arr.shape}")
    if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
        raise ClispError("scene contains NaN or infinite values")
    return arr


def _optics_kernel(optics: str | None, r0: float) -> np.ndarray | None:
    """The optics kernel for ``optics`` ('airy' or 'none'/None), or None for no blur."""
    kind = "none" if optics is None else optics
    if not isinstance(kind, str) or kind.strip().lower() not in OPTICS_KINDS:
        raise ClispError(f"unknown optics {optics!r}; expected one of {', '.join(OPTICS_KINDS)}")
    if kind.strip().lower() == "none":
        return None
    if isinstance(r0, bool) or not isinstance(r0, (int, float, np.integer, np.floating)) \
            or not (math.isfinite(float(r0)) and float(r0) > 0):
        raise ClispError(f"Airy first-zero radius r0 must be a positive number of pixels, got {r0!r}")
    return airy_kernel(float(r0))


def _check_seed(seed: Any) -> int | None:
    """``seed`` as a non-negative int (or None for fresh entropy)."""
    if seed is None:
        return None
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or int(seed) < 0:
        raise ClispError(f"seed must be a non-negative integer or None, got {seed!r}")
    return int(seed)


def optics_and_mosaic(scene: np.ndarray, cfa: CFA, kernel: np.ndarray | None,
                      a: np.ndarray, origin: tuple[int, int] = (0, 0)) -> tuple[np.ndarray, np.ndarray]:
    """Blur the scene and mosaic its raw values, one channel at a time to bound memory.

    scene H x W x 3 linear sRGB whose pixel (0, 0) is image pixel ``origin`` (sets the CFA
    phase); a 3 x 3 sRGB -> raw matrix. Returns (truth H x W x 3 float32, raw mosaic H x W
    float64 normalised, 1.0 = white level).
    """
    height, width = scene.shape[:2]
    channel_of = cfa.channel_map(height, width, origin)
    truth = np.empty((height, width, 3), dtype=np.float32)
    raw = np.zeros((height, width), dtype=np.float64)
    for j in range(3):
        plane = np.asarray(scene[..., j], dtype=np.float64)
        if kernel is not None:
            plane = blur_channel(plane, kernel)
        truth[..., j] = plane
        raw += a[channel_of, j] * plane
    return truth, raw


def _metadata(cfa: CFA, gain: float | None, noise: NoiseModel, kernel: np.ndarray | None,
              r0: float, seed: int | None, k_exp: float) -> dict[str, Any]:
    """JSON-serialisable simulation facts kept in RawImage.metadata."""
    return {
        "cfa": cfa.name,
        "gain": gain,
        "noise": noise.to_dict(),
        "full_scale_electrons": None if gain is None else float(noise.full_scale_electrons(gain)),
        "optics": {"kind": "none", "r0": None} if kernel is None else {"kind": "airy", "r0": float(r0)},
        "seed": seed,
        "k_exp": float(k_exp),
        "simulator": f"clisp {__version__}",
    }


def simulate(scene: np.ndarray, cfa: CFA | str = "lms", gain: float | None = None,
             optics: str | None = "airy", seed: int | None = 0, r0: float = 1.0,
             noise: NoiseModel = NoiseModel(), defects: SensorDefects | None = None) -> SimResult:
    """Simulate a raw capture of a linear sRGB scene (docs/model.md sections 2 and 3).

    scene  H x W x 3 linear sRGB, white = 1.0 (any real dtype; values above 1 are allowed).
    cfa    a CFA or a name ('lms', 'lms@dy,dx', 'bayer', 'bayer-grbg', 'lms-bayer', a pattern string
           such as 'LMMS', ...); its channels pick the camera constants, its pattern the mosaic.
    gain   analog gain in [1, 64]; None = noiseless (float32 DN, unquantised, unclipped).
    optics 'airy' (pixel-integrated Airy PSF, first-zero radius r0 px) or 'none'.
    seed   seed of np.random.default_rng for the noise; the same seed gives identical data.
    noise  the sensor model (black/white level, read noise, conversion gain).
    defects  the sensor's defects (clisp.sim.defects: hot, warm and dead pixels, dark current,
           lens shading, PRNU), kept in ``metadata['sensor']``; the truth stays the ideal sensor's.
    Returns SimResult(raw=RawImage with uint16 (noisy) or float32 (noiseless) H x W DN,
    truth=H x W x 3 float32 blurred linear sRGB).
    """
    scene = _check_scene(scene)
    cfa, gain_value, kernel, seed = _check_options(cfa, gain, optics, r0, seed, noise)
    a, k_exp = inverse_isp_matrix(cfa.spectral)
    truth, raw = optics_and_mosaic(scene, cfa, kernel, a)
    if defects is not None and defects.any:
        from .defects import capture   # deferred: only a simulation with defects loads the defect model (start-up)
        data = capture(raw, defects, cfa, gain_value, noise, np.random.default_rng(seed))
    else:
        data = _digitise(raw, gain_value, noise, np.random.default_rng(seed))
    del raw
    metadata = _metadata(cfa, gain_value, noise, kernel, r0, seed, k_exp)
    if defects is not None and defects.any:
        metadata["sensor"] = defects.to_dict()
    return SimResult(raw=_raw_image(data, cfa, noise, k_exp, metadata), truth=truth)


def _check_options(cfa: CFA | str, gain: float | None, optics: str | None, r0: float, seed: int | None,
                   noise: NoiseModel) -> tuple[CFA, float | None, np.ndarray | None, int | None]:
    """Validated (CFA, gain, optics kernel, seed) for :func:`simulate` and :func:`simulate_large`."""
    cfa = resolve_cfa(cfa)
    gain_value = None if gain is None else check_gain(gain)
    kernel = _optics_kernel(optics, r0)
    seed = _check_seed(seed)
    if not isinstance(noise, NoiseModel):
        raise ClispError(f"noise must be a NoiseModel, got {type(noise).__name__}")
    return cfa, gain_value, kernel, seed


def _digitise(raw: np.ndarray, gain: float | None, noise: NoiseModel, rng: np.random.Generator) -> np.ndarray:
    """DN of a normalised raw mosaic: float32 without noise (gain None), else noisy uint16."""
    if gain is None:
        return (raw * noise.range_dn + float(noise.black_level)).astype(np.float32)
    return noise.sample(raw, gain, rng)


def _raw_image(data: np.ndarray, cfa: CFA, noise: NoiseModel, k_exp: float,
               metadata: dict[str, Any]) -> RawImage:
    """The simulated RawImage around ``data`` (camera constants of the CFA's spectral kind)."""
    matrix, wb = camera_constants(cfa.spectral)
    return RawImage(
        data=data, cfa=cfa,
        black_level=np.full(cfa.n_channels, float(noise.black_level)),
        white_level=float(noise.white_level),
        wb=np.array(wb, dtype=np.float64), colour_matrix=np.array(matrix, dtype=np.float64),
        exposure=1.0 / k_exp, wb2=np.ones(3), metadata=metadata, source="simulated")


# --------------------------------------------------------------------------------------------
# Large captures, band by band
# --------------------------------------------------------------------------------------------

BAND_PIXELS = 2_000_000
"""Pixels per band of :func:`simulate_large` (rows rounded down to a multiple of 16, the raw
file's strip height): about 150 MB of float64 temporaries per band."""


def mirror_repeat_index(idx: np.ndarray, n: int) -> np.ndarray:
    """Source index along a side of ``n`` for the scene repeated with alternate copies mirrored
    (0..n-1, n-1..0, 0..n-1, ...), so the repeat has no seams."""
    m = np.asarray(idx, dtype=np.int64) % (2 * n)
    return np.where(m < n, m, 2 * n - 1 - m)


@dataclass
class LargeSimulation:
    """A capture of a scene repeated (mirrored) to ``header.shape``, computed band by band.

    header  the RawImage metadata; ``header.data`` is a zero-stride placeholder with the full
            shape and dtype (write it with ``rawfile.raw_band_writer``).
    bands   full-width row bands (clisp.engine.tiling.Tile) covering the image, top to bottom.
    Call :meth:`band` for each band's pixels, in any order: the optics read a halo of the
    kernel radius from the repeated scene, so bands join exactly; the noise of band i is drawn
    from ``SeedSequence(seed).spawn(len(bands))[i]``, so a run is reproducible, but it is NOT
    bit-identical to :func:`simulate` of the same scene (which draws one stream for the image).
    """

    header: RawImage
    bands: list[Tile]
    scene: np.ndarray
    kernel: np.ndarray | None
    a: np.ndarray
    gain: float | None
    noise: NoiseModel
    seeds: list[np.random.SeedSequence]

    def band(self, tile: Tile) -> tuple[np.ndarray, np.ndarray]:
        """(DN tile.h x W, uint16 or float32; truth tile.h x W x 3 float32) of one band."""
        height, width = self.header.shape
        r = 0 if self.kernel is None else self.kernel.shape[0] // 2
        rows = cfa_mirror_index(np.arange(tile.y0 - r, tile.y0 + tile.h + r), height, 1)
        rows = mirror_repeat_index(rows, self.scene.shape[0])
        cols = mirror_repeat_index(np.arange(width), self.scene.shape[1])
        part = self.scene[rows][:, cols]
        truth, raw = optics_and_mosaic(part, self.header.cfa, self.kernel, self.a, (tile.y0 - r, 0))
        truth, raw = truth[r:r + tile.h], raw[r:r + tile.h]
        rng = np.random.default_rng(self.seeds[tile.y0 // self.bands[0].h])
        return _digitise(raw, self.gain, self.noise, rng), truth


def simulate_large(scene: np.ndarray, size: tuple[int, int], cfa: CFA | str = "lms",
                   gain: float | None = None, optics: str | None = "airy", seed: int | None = 0,
                   r0: float = 1.0, noise: NoiseModel = NoiseModel()) -> LargeSimulation:
    """:func:`simulate` of ``scene`` repeated to ``size`` = (height, width), band by band.

    The scene (H x W x 3 linear sRGB) is tiled with alternate copies mirrored (no seams); nothing
    of full size is allocated. Each band's pixels come from :meth:`LargeSimulation.band`.
    """
    scene = _check_scene(scene)
    cfa, gain_value, kernel, seed = _check_options(cfa, gain, optics, r0, seed, noise)
    height, width = (int(v) for v in size)
    if min(height, width) < cfa.period:
        raise ClispError(f"size {width}x{height} is smaller than one CFA tile ({cfa.period} px)")
    a, k_exp = inverse_isp_matrix(cfa.spectral)
    rows = max(16, BAND_PIXELS // width // 16 * 16)
    bands = grid(height, width, rows, width)
    metadata = _metadata(cfa, gain_value, noise, kernel, r0, seed, k_exp)
    metadata["repeat"] = {"scene_shape": list(scene.shape[:2]), "mode": "mirror",
                          "noise": f"per band of {rows} rows, SeedSequence(seed).spawn(bands)"}
    placeholder = np.broadcast_to(np.zeros((), np.float32 if gain_value is None else np.uint16), (height, width))
    header = _raw_image(placeholder, cfa, noise, k_exp, metadata)
    seeds = np.random.SeedSequence(seed).spawn(len(bands))
    return LargeSimulation(header, bands, scene, kernel, a, gain_value, noise, seeds)
