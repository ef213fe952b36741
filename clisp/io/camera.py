"""Camera raws (CR2, CRW, NEF, DNG, KDC, ...) through rawpy / LibRaw.

Only Bayer sensors are supported. The mosaic is LibRaw's *visible* area (``raw_image_visible``:
a DNG's ActiveArea, or the camera's masked margins, removed). The crop the file declares (a DNG's
DefaultCrop, inside the ActiveArea; for other raws the maker's crop as LibRaw reports it) is
``metadata["crop"]`` = [top, left, height, width] in the mosaic's coordinates; ``clisp process``
applies it to its output (``--no-crop`` keeps the whole mosaic). The shot's EXIF (make, model,
lens, exposure, ISO, date; clisp.io.exif, read with exiv2) is ``metadata["exif"]``.

CFA phase: rawpy's ``raw_pattern`` is indexed from the top-left of the *full* raw
(``raw_pattern[y, x] = COLOR(y - top_margin, x - left_margin)``), so the pattern of the visible area
is ``raw_pattern`` rolled by (-top_margin, -left_margin). LibRaw's colour indices are positions in
``color_desc`` (b'RGBG' for RGB Bayer cameras; index 3 is the second green).
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import tifffile

from ..cfa import CFA, cfa_from_pattern
from ..sim.colorimetry import XYZ_TO_SRGB
from ..errors import ClispError, clip, library_output, one_line
from .exif import ISO, read_exif
from .rawimage import NO_CAMERA_WB, RawImage
from .opcode_pages import page_opcodes
from ..engine.streaming import aligned_copy

CFA_LETTERS = "RGB"
"""Our CFA channel order for Bayer raws."""


def read_camera_raw(path: str | os.PathLike[str]) -> RawImage:
    """Read a Bayer camera raw with rawpy.

    Returns a RawImage with data = visible mosaic (H x W uint16 DN, copied), per-channel black level
    and white level in DN, WB pass-1 multipliers normalised to G = 1, exposure 1 and a colour matrix
    mapping WB-balanced camera RGB to linear sRGB. Raises ClispError naming the file on failure.
    """
    import rawpy                 # deferred: rawpy is only for camera raws (not at `import clisp`)

    p = Path(path)
    said = None
    try:
        with library_output() as said, rawpy.RawPy() as raw:   # LibRaw's stderr: into our message
            raw.open_file(str(p))
            _check_size(raw, p)
            raw.unpack()
            return _from_rawpy(raw, p)
    except ClispError as exc:
        if said is not None and said.text and str(p) in str(exc):
            raise ClispError(f"{exc}{said.note(50, str(p))}") from exc
        raise
    except rawpy.LibRawError as exc:
        raise ClispError(f"cannot read raw file '{p}': {_libraw_problem(exc)}{said.note(50, str(p))}") from exc
    except (OSError, RuntimeError, NotImplementedError, ValueError, TypeError, MemoryError,
            IndexError, KeyError, ZeroDivisionError, OverflowError, np.linalg.LinAlgError) as exc:
        raise ClispError(f"cannot read raw file '{p}': {type(exc).__name__}: {clip(one_line(exc))}") from exc


MAX_RAW_PIXELS = 2**28
"""Largest camera raw (pixels of LibRaw's full raw area) clisp decodes: 268 MP."""

MAX_BITS_PER_BYTE = 64
"""Most raw pixels one byte of a camera raw file may encode; lossless raw compression reaches
about 8 (1 bit a pixel on a black frame): a header declaring more is corrupt and refused before
LibRaw allocates the mosaic."""


def _check_size(raw: Any, p: Path) -> None:
    """ClispError when the opened raw declares more pixels than MAX_RAW_PIXELS or than its file
    could hold (checked after LibRaw read the header, before it unpacks the pixels)."""
    s = raw.sizes
    pixels = int(s.raw_height) * int(s.raw_width)
    size = p.stat().st_size
    if pixels <= 0:
        raise ClispError(f"cannot read raw file '{p}': no image ({s.raw_width}x{s.raw_height} pixels)")
    if pixels > MAX_RAW_PIXELS or pixels > MAX_BITS_PER_BYTE * size + 2**20:
        raise ClispError(f"cannot read raw file '{p}': declares {s.raw_width}x{s.raw_height} pixels, "
                         f"more than a file of {size} bytes holds (corrupt header)")


def _from_rawpy(raw: Any, p: Path) -> RawImage:
    """Build the RawImage from an open rawpy.RawPy."""
    sizes = raw.sizes
    colours = _colour_letters(raw.color_desc)
    pattern = visible_pattern(raw.raw_pattern, sizes.top_margin, sizes.left_margin, p)
    try:
        cfa = cfa_from_pattern(pattern, colours)
    except ClispError as exc:
        raise ClispError(f"cannot read raw file '{p}': {exc}") from exc
    visible = raw.raw_image_visible
    if visible is None or visible.ndim != 2:
        raise ClispError(f"cannot read raw file '{p}': not a flat CFA raw ({raw.raw_type})")
    data = aligned_copy(visible, np.uint16)         # rawpy's buffer goes with the file; aligned: read in place
    black = channel_values(raw.black_level_per_channel, pattern, colours, cfa)
    wb, wb_source = pick_wb(raw.camera_whitebalance, pattern, colours, cfa)
    daylight = _wb_candidate(raw.daylight_whitebalance, pattern, colours, cfa)
    if wb is None:                                  # reading decides nothing: the run estimates the light
        wb = daylight if daylight is not None else np.ones(cfa.n_channels)
        wb_source = NO_CAMERA_WB
    matrix, matrix_source = pick_colour_matrix(np.asarray(raw.color_matrix, dtype=np.float64),
                                               np.asarray(raw.rgb_xyz_matrix, dtype=np.float64))
    if matrix_source.startswith("identity"):
        probed = probe_libraw_matrix(p)
        if probed is not None:
            matrix, matrix_source = probed, "probed from LibRaw (not exposed by rawpy)"
    metadata = _camera_metadata(raw, p, wb_source, matrix_source)
    if daylight is not None:
        metadata["daylight_multipliers"] = [float(v) for v in daylight]
    linear_max = _linear_max(raw, pattern, colours, cfa)
    if linear_max is not None:
        metadata["linear_max"] = linear_max
    if p.suffix.lower() == ".dng":                  # LibRaw applies no opcode: read them here
        try:
            ops = dng_opcodes(p, (int(sizes.top_margin), int(sizes.left_margin)),
                              (int(sizes.raw_height), int(sizes.raw_width)), data.shape)
        except ClispError as exc:
            metadata["opcodes_unreadable"] = clip(exc, 120)
            ops = []
        if ops:
            metadata["opcodes"] = ops
    return RawImage(data=data, cfa=cfa, black_level=black, white_level=float(raw.white_level),
                    wb=wb, colour_matrix=matrix, exposure=1.0, metadata=metadata, source=str(p))


def dng_opcodes(p: Path, margins: tuple[int, int], raw_shape: tuple[int, int],
                shape: tuple[int, int]) -> list:
    """The OpcodeList1-3 of a camera DNG's raw image (the largest CFA image among its IFDs and
    SubIFDs), placed on the mosaic LibRaw returns (clisp.io.opcodes): OpcodeList1 acts on the
    stored raw, whose (0, 0) lies ``margins`` (LibRaw's top and left margin: the ActiveArea)
    above and left of the mosaic, lists 2 and 3 on the ActiveArea, the mosaic itself."""
    with library_output(), tifffile.TiffFile(p) as tif:
        pages = []
        for page in tif.pages:
            pages.append(page)
            pages.extend(getattr(page, "pages", None) or [])
        cfa_pages = [pg for pg in pages if int(getattr(pg, "photometric", 0) or 0) == tifffile.PHOTOMETRIC.CFA]
        if not cfa_pages:
            return []
        page = max(cfa_pages, key=lambda pg: int(pg.shape[0]) * int(pg.shape[-1]))
        return page_opcodes(page, str(p), (-margins[0], -margins[1]), raw_shape, tuple(shape))


def _linear_max(raw: Any, pattern: np.ndarray, colours: str, cfa: CFA) -> list[float] | None:
    """Per CFA channel clip level in DN (LibRaw's ``color.linear_max``: the camera's per-channel
    saturation, rawpy's camera_white_level_per_channel), or None when the file gives none. The
    highlight stage clips each channel at its own level (clisp.modules.highlights.stage)."""
    levels = getattr(raw, "camera_white_level_per_channel", None)
    if levels is None:
        return None
    values = np.asarray(levels, dtype=np.float64).reshape(-1)
    if values.size < 3 or not np.all(values[:3] > 0):
        return None
    if values.size < 4 or values[3] <= 0:
        values = np.concatenate([values[:3], values[1:2]])
    return [float(v) for v in channel_values(values[:4], pattern, colours, cfa)]


def _colour_letters(color_desc: bytes) -> str:
    """rawpy's colour description as letters, the second green (index 3 of 'RGBG') mapped to G."""
    letters = bytes(color_desc).decode("ascii", "replace").rstrip("\0")
    letters = (letters + "????")[:4]
    if letters[:3] == "RGB" and letters[3] == "G":
        letters = "RGBG"
    return letters


def visible_pattern(raw_pattern: np.ndarray | None, top_margin: int, left_margin: int,
                    p: Path | str = "") -> np.ndarray:
    """CFA pattern (colour indices) of the visible area from rawpy's full-raw ``raw_pattern``.

    A 4 x 4 pattern that repeats with period 2 is reduced to 2 x 2. Raises ClispError naming the
    file for raws without a CFA (linear DNG, Foveon, monochrome).
    """
    if raw_pattern is None:
        raise ClispError(f"cannot read raw file '{p}': no CFA pattern (linear/demosaiced DNG or "
                         f"layered sensor such as Foveon); only Bayer raws are supported")
    pattern = np.asarray(raw_pattern)
    if pattern.ndim != 2 or pattern.shape[0] != pattern.shape[1] or pattern.shape[0] < 2:
        raise ClispError(f"cannot read raw file '{p}': unsupported CFA pattern of shape "
                         f"{pattern.shape} (monochrome or unknown sensor); only Bayer raws are supported")
    n = pattern.shape[0]
    pattern = np.roll(pattern, shift=(-int(top_margin) % n, -int(left_margin) % n), axis=(0, 1))
    if n == 4 and np.array_equal(np.tile(pattern[:2, :2], (2, 2)), pattern):
        pattern = pattern[:2, :2]
    return pattern.copy()


def channel_values(values: Any, pattern: np.ndarray, colours: str, cfa: CFA) -> np.ndarray:
    """Per CFA channel mean of rawpy's per-colour-index ``values`` over the indices in ``pattern``.

    Shape (cfa.n_channels,). For 'RGBG' the G entry averages indices 1 and 3 when both occur.
    """
    vals = np.asarray(values, dtype=np.float64)
    out = np.zeros(cfa.n_channels)
    for c, name in enumerate(cfa.channels):
        idx = [int(i) for i in np.unique(pattern) if colours[int(i)] == name]
        out[c] = float(np.mean(vals[idx]))
    return out


def pick_wb(camera: Any, pattern: np.ndarray, colours: str, cfa: CFA) -> tuple[np.ndarray | None, str]:
    """The camera's (as shot) WB pass-1 multipliers per CFA channel, normalised to G = 1, or
    (None, reason) when the file has none usable.

    A candidate is rejected when any value for a colour index used by the pattern is <= 0 or not
    finite (the Canon D30 CRW reports R = -1); the raw is then read with ``wb_source``
    NO_CAMERA_WB (its daylight multipliers, or ones, as placeholders) and a run's ``--wb camera``
    estimates the light from the scene's grey pixels (clisp.scene.white_balance.with_white_balance),
    as LibRaw falls back to its auto WB, rather than guess daylight for an unknown scene.
    LibRaw stores 0 for the second green when it equals the first, so index 3 falls back to index 1.
    """
    wb = _wb_candidate(camera, pattern, colours, cfa)
    return (wb, "camera") if wb is not None else (None, "none")


def _wb_candidate(values: Any, pattern: np.ndarray, colours: str, cfa: CFA) -> np.ndarray | None:
    """Normalised multipliers from one rawpy 4-vector, or None when unusable."""
    if values is None:
        return None
    vals = np.asarray(values, dtype=np.float64).copy()
    if vals.shape != (4,):
        return None
    if vals[3] == 0 and colours[3] == colours[1]:
        vals[3] = vals[1]
    used = [int(i) for i in np.unique(pattern)]
    if not np.all(np.isfinite(vals[used])) or np.any(vals[used] <= 0):
        return None
    wb = channel_values(vals, pattern, colours, cfa)
    green = wb[list(cfa.channels).index("G")] if "G" in cfa.channels else wb.min()
    return wb / green


def pick_colour_matrix(rgb_cam: np.ndarray, cam_xyz: np.ndarray) -> tuple[np.ndarray, str]:
    """3 x 3 matrix WB-balanced camera RGB -> linear sRGB, and its source.

    ``rgb_cam`` is rawpy's ``color_matrix`` (3 x 4; LibRaw fills it for DNGs), ``cam_xyz`` is
    ``rgb_xyz_matrix`` (4 x 3, XYZ -> camera). Falls back to dcraw's derivation from cam_xyz
    (cam_rgb = cam_xyz @ sRGB->XYZ, rows normalised to sum 1, inverted), then to identity.
    """
    m = rgb_cam[:3, :3] if rgb_cam.ndim == 2 and rgb_cam.shape[0] >= 3 and rgb_cam.shape[1] >= 3 else None
    if m is not None and np.all(np.isfinite(m)) and np.any(m != 0):
        return m.copy(), "file (LibRaw rgb_cam)"
    derived = rgb_cam_from_cam_xyz(cam_xyz[:3] if cam_xyz.ndim == 2 and cam_xyz.shape[0] >= 3 else None)
    if derived is not None:
        return derived, "derived from rgb_xyz_matrix (dcraw method)"
    return np.eye(3), "identity (file has none)"


PROBE_BASE = 0.25
PROBE_STEP = 0.1
"""Probe mosaics: a flat grey at 25% of the raw range, plus 10% more in one channel."""


def probe_libraw_matrix(path: Path) -> np.ndarray | None:
    """The camera -> sRGB matrix LibRaw applies, measured by processing flat probe mosaics.

    For cameras whose matrix LibRaw keeps internally (rawpy exposes neither ``color_matrix`` nor
    ``rgb_xyz_matrix``, e.g. the Kodak DC50), LibRaw still converts to sRGB. Processing a flat grey
    mosaic and the same grey with a step in one CFA channel (unit WB, linear output) gives that
    channel's column. Returns None if LibRaw cannot process the file or the result is not finite.
    """
    import rawpy                 # deferred: rawpy is only for camera raws (not at `import clisp`)
    try:
        with rawpy.imread(str(path)) as raw:
            colours = np.where(raw.raw_colors == 3, 1, raw.raw_colors)
            black = np.asarray(raw.black_level_per_channel, dtype=np.float64)[raw.raw_colors]
            scale = float(raw.white_level) - black

            def process(levels: np.ndarray) -> np.ndarray:
                raw.raw_image[...] = np.round(black + levels[colours] * scale).astype(raw.raw_image.dtype)
                rgb = raw.postprocess(user_wb=[1.0, 1.0, 1.0, 1.0], no_auto_bright=True, gamma=(1, 1),
                                      output_bps=16, output_color=rawpy.ColorSpace.sRGB, user_flip=0,
                                      demosaic_algorithm=rawpy.DemosaicAlgorithm.LINEAR)
                h, w = rgb.shape[:2]
                return rgb[h // 4:3 * h // 4, w // 4:3 * w // 4].reshape(-1, 3).mean(axis=0) / 65535.0

            base = process(np.full(3, PROBE_BASE))
            columns = [(process(PROBE_BASE + PROBE_STEP * np.eye(3)[c]) - base) / PROBE_STEP for c in range(3)]
    except (rawpy.LibRawError, OSError, ValueError):
        return None
    matrix = np.stack(columns, axis=1)
    return matrix if np.all(np.isfinite(matrix)) and np.any(matrix != np.eye(3)) else None


def rgb_cam_from_cam_xyz(cam_xyz: np.ndarray | None) -> np.ndarray | None:
    """dcraw's rgb_cam from a 3 x 3 XYZ -> camera matrix; None when absent or singular."""
    if cam_xyz is None or cam_xyz.shape != (3, 3) or not np.all(np.isfinite(cam_xyz)) or not np.any(cam_xyz):
        return None
    cam_rgb = cam_xyz @ np.linalg.inv(XYZ_TO_SRGB)
    sums = cam_rgb.sum(axis=1, keepdims=True)
    if np.any(np.abs(sums) < 1e-12):
        return None
    try:
        rgb_cam = np.linalg.inv(cam_rgb / sums)
    except np.linalg.LinAlgError:
        return None
    return rgb_cam if np.all(np.isfinite(rgb_cam)) else None


def _camera_metadata(raw: Any, p: Path, wb_source: str, matrix_source: str) -> dict[str, Any]:
    """JSON-friendly facts about the camera raw kept in RawImage.metadata."""
    s = raw.sizes
    md: dict[str, Any] = {
        "flip": int(s.flip),
        "wb_source": wb_source,
        "colour_matrix_source": matrix_source,
        "camera_wb": [float(v) for v in raw.camera_whitebalance],
        "daylight_wb": [float(v) for v in raw.daylight_whitebalance],
        "raw_size": [int(s.raw_height), int(s.raw_width)],
        "visible_origin": [int(s.top_margin), int(s.left_margin)],
        "color_desc": bytes(raw.color_desc).decode("ascii", "replace").rstrip("\0"),
    }
    if int(s.crop_width) > 0 and int(s.crop_height) > 0:
        md["default_crop"] = [int(s.crop_top_margin), int(s.crop_left_margin),
                              int(s.crop_height), int(s.crop_width)]
        crop = visible_crop(md["default_crop"], (int(s.top_margin), int(s.left_margin)),
                            (int(s.height), int(s.width)))
        if crop is not None:
            md["crop"] = crop
    md["exif"] = _exif(raw, p)
    return md


def visible_crop(default_crop: Any, visible_origin: tuple[int, int],
                 visible_shape: tuple[int, int]) -> list[int] | None:
    """The file's crop [top, left, height, width] in the visible mosaic's coordinates, from LibRaw's
    crop in full-raw coordinates (``sizes.crop_*``: a DNG's ActiveArea origin plus its
    DefaultCropOrigin), clipped to the visible area; None when it is the whole visible area or
    does not overlap it."""
    top, left, height, width = (int(v) for v in default_crop)
    y0, x0 = max(top - visible_origin[0], 0), max(left - visible_origin[1], 0)
    y1 = min(top - visible_origin[0] + height, visible_shape[0])
    x1 = min(left - visible_origin[1] + width, visible_shape[1])
    if y1 <= y0 or x1 <= x0 or (y0, x0, y1, x1) == (0, 0, *visible_shape):
        return None
    return [y0, x0, y1 - y0, x1 - x0]


def _exif(raw: Any, p: Path) -> dict[str, Any]:
    """The shot's EXIF (clisp.io.exif.read_exif), with LibRaw's ISO where the tags give none (the
    Kodak DC50 keeps it in its maker notes)."""
    exif = read_exif(p)
    if ISO not in exif:
        try:
            iso = float(raw.other.iso_speed)
        except (AttributeError, TypeError, ValueError):
            iso = 0.0
        if iso >= 1:
            exif[ISO] = int(round(iso))
    return exif


def _libraw_problem(exc: BaseException) -> str:
    """A short description of a rawpy exception."""
    text = one_line(exc)
    name = type(exc).__name__
    if name == "LibRawFileUnsupportedError":
        return f"not a raw file LibRaw can read ({text})"
    if name in ("LibRawIOError", "LibRawDataError"):
        return f"damaged or truncated raw data ({text})"
    return f"{name}: {text}"


