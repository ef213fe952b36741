"""Reading and writing raw files.

clisp writes its own raws as DNG-style TIFFs (one uncompressed CFA image in contiguous strips of
``ROWS_PER_STRIP`` rows, so that tile streaming can read just the rows of a tile: see
``read_raw(path, lazy=True)``; :func:`raw_band_writer` writes one band by band). Besides the
standard DNG tags the file carries clisp's exact metadata as JSON in DNGPrivateData (tag 50740,
prefixed with ``b"clisp\\0"``), so :func:`read_raw` rebuilds the :class:`RawImage` bit for bit.
Any other file is handed to :func:`clisp.io.camera.read_camera_raw` (rawpy / LibRaw).

Every failure surfaces as a one-line :class:`ClispError` that names the file.
"""
from __future__ import annotations

import json
import math
import os
import tempfile
from contextlib import contextmanager
from fractions import Fraction
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np
import tifffile

from ..cfa import CFA, cfa_from_name, kind_before_issue45
from ..sim.colorimetry import XYZ_TO_SRGB
from ..errors import ClispError, clip, library_output, one_line
from .exif import camera_make_model, simulated_model_name
from .opcode_pages import page_opcodes
from .rawimage import RawImage, check_levels

ROWS_PER_STRIP = 16
"""Rows per uncompressed strip in files we write."""

PRIVATE_PREFIX = b"clisp\0"
"""Start of our DNGPrivateData payload; the JSON follows."""

FORMAT_NAME = "clisp-raw"
FORMAT_VERSION = 1

SOURCE_CLISP = "clisp-dng"
SOURCE_CAMERA = "camera (rawpy)"

D65_XYZ = np.array([0.95047, 1.0, 1.08883])
"""CIE XYZ of the D65 white point with Y = 1."""

# TIFF / DNG tag codes and TIFF field types.
TAG_MAKE = 271
TAG_MODEL = 272
TAG_CFA_REPEAT_PATTERN_DIM = 33421
TAG_CFA_PATTERN = 33422
TAG_DNG_VERSION = 50706
TAG_DNG_BACKWARD_VERSION = 50707
TAG_UNIQUE_CAMERA_MODEL = 50708
TAG_CFA_PLANE_COLOR = 50710
TAG_CFA_LAYOUT = 50711
TAG_BLACK_LEVEL_REPEAT_DIM = 50713
TAG_BLACK_LEVEL = 50714
TAG_WHITE_LEVEL = 50717
TAG_DEFAULT_CROP_ORIGIN = 50719
TAG_DEFAULT_CROP_SIZE = 50720
TAG_COLOR_MATRIX1 = 50721
TAG_AS_SHOT_NEUTRAL = 50728
TAG_BASELINE_EXPOSURE = 50730
TAG_DNG_PRIVATE_DATA = 50740
TAG_CALIBRATION_ILLUMINANT1 = 50778
PHOTOMETRIC_CFA = 32803
ILLUMINANT_D65 = 21
T_BYTE, T_ASCII, T_SHORT, T_LONG, T_RATIONAL, T_SRATIONAL = 1, 2, 3, 4, 5, 10

MAX_PIXELS = 2**30
"""Largest mosaic a raw file may declare (1 gigapixel): checked before anything is allocated."""

_INT32_MAX = 2**31 - 1
_UINT32_MAX = 2**32 - 1


# --------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------

def write_raw(path: str | os.PathLike[str], raw: RawImage) -> None:
    """Write ``raw`` as a DNG-style TIFF at ``path``, atomically.

    The mosaic (H x W, uint16 DN or float32 DN for noiseless data) is stored uncompressed in
    strips of ROWS_PER_STRIP rows with its dtype kept. The file appears only when complete: it is
    written under a temporary name in the same folder and renamed; on any failure the temporary
    file is removed and ClispError is raised (an existing file at ``path`` is left untouched).
    """
    target = Path(path)
    data = np.ascontiguousarray(raw.data, dtype=_checked_dtype(raw, target))
    with _atomic_raw_file(target) as tmp_name:
        tifffile.imwrite(tmp_name, data, extratags=dng_tags(raw), **_TIFF_LAYOUT)


@contextmanager
def raw_band_writer(path: str | os.PathLike[str], header: RawImage) -> Iterator[Callable[[int, np.ndarray], None]]:
    """Write a raw file whose rows arrive in bands, never holding the whole mosaic.

    ``header`` supplies the metadata; of ``header.data`` only shape and dtype are used (pass a
    zero-stride ``np.broadcast_to`` array, which costs no memory). Yields ``write(y0, rows)`` that
    stores ``rows`` (h x W, the header's dtype) as rows y0..y0+h. The file layout equals
    :func:`write_raw`'s (tifffile writes the header and reserves the contiguous strips, the bands
    are written at their offsets), and so does the atomicity; ClispError if a row is missing.
    """
    target = Path(path)
    dtype = _checked_dtype(header, target)
    height, width = header.shape
    with _atomic_raw_file(target) as tmp_name:
        offset, _ = tifffile.imwrite(tmp_name, shape=(height, width), dtype=dtype, returnoffset=True,
                                     extratags=dng_tags(header), **_TIFF_LAYOUT)
        written = np.zeros(height, dtype=bool)
        fd = os.open(tmp_name, os.O_WRONLY)
        try:
            def write(y0: int, rows: np.ndarray) -> None:
                block = np.ascontiguousarray(rows, dtype=dtype)
                if block.ndim != 2 or block.shape[1] != width or not 0 <= y0 <= height - block.shape[0]:
                    raise ValueError(f"band of shape {block.shape} at row {y0} does not fit {height}x{width}")
                _pwrite_all(fd, memoryview(block.reshape(-1).view(np.uint8)), offset + y0 * width * dtype.itemsize)
                written[y0:y0 + block.shape[0]] = True
            yield write
        finally:
            os.close(fd)
        if not written.all():
            raise ValueError(f"rows {int(np.argmin(written))} and on were never written")


_TIFF_LAYOUT: dict[str, Any] = dict(photometric=PHOTOMETRIC_CFA, rowsperstrip=ROWS_PER_STRIP, subfiletype=0,
                                    compression=None, metadata=None, software="clisp")
"""tifffile.imwrite arguments of our raw files: uncompressed CFA strips, no tifffile metadata."""


@contextmanager
def _atomic_raw_file(target: Path) -> Iterator[str]:
    """Yield a temporary file name beside ``target``; rename it to ``target`` on success, remove
    it on any failure (raised as a one-line ClispError naming ``target``)."""
    folder = target.parent if str(target.parent) else Path(".")
    try:
        fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=folder)
    except OSError as exc:
        raise ClispError(f"cannot write raw file '{target}': {one_line(exc)}") from exc
    os.close(fd)
    try:
        yield tmp_name
        _chmod_default(tmp_name)
        os.replace(tmp_name, target)
    except BaseException as exc:
        _remove_quietly(tmp_name)
        if isinstance(exc, Exception) and not isinstance(exc, ClispError):
            raise ClispError(f"cannot write raw file '{target}': {one_line(exc)}") from exc
        raise


def _pwrite_all(fd: int, data: memoryview, offset: int) -> None:
    """os.pwrite until every byte of ``data`` is at ``offset`` (a large write may be split)."""
    while len(data):
        n = os.pwrite(fd, data, offset)
        data, offset = data[n:], offset + n


def dng_tags(raw: RawImage) -> list[tuple[int, int, int, Any, bool]]:
    """The DNG tags for ``raw`` as tifffile ``extratags`` tuples (code, type, count, value, once)."""
    cfa = raw.cfa
    p = cfa.period
    is_float = raw.data.dtype == np.float32
    black_tile = [float(raw.black_level[c]) for c in cfa.pattern.ravel()]
    model = simulated_model_name(cfa)
    make, camera = camera_make_model(raw)
    tags: list[tuple[int, int, int, Any, bool]] = [
        (code, T_ASCII, 0, text, True) for code, text in ((TAG_MAKE, make), (TAG_MODEL, camera)) if text
    ] + [
        (TAG_DNG_VERSION, T_BYTE, 4, bytes((1, 4, 0, 0)), True),
        (TAG_DNG_BACKWARD_VERSION, T_BYTE, 4, bytes((1, 4, 0, 0) if is_float else (1, 1, 0, 0)), True),
        (TAG_UNIQUE_CAMERA_MODEL, T_ASCII, 0, model, True),
        (TAG_CFA_REPEAT_PATTERN_DIM, T_SHORT, 2, (p, p), True),
        (TAG_CFA_PATTERN, T_BYTE, p * p, cfa.dng_pattern, True),
        (TAG_CFA_PLANE_COLOR, T_BYTE, 3, bytes((0, 1, 2)), True),
        (TAG_CFA_LAYOUT, T_SHORT, 1, 1, True),
        (TAG_BLACK_LEVEL_REPEAT_DIM, T_SHORT, 2, (p, p), True),
        (TAG_BLACK_LEVEL, T_RATIONAL, p * p, _rationals(black_tile, signed=False), True),
        (TAG_WHITE_LEVEL, T_LONG, 1, _clamp_int(raw.white_level, 0, _UINT32_MAX), True),
        (TAG_COLOR_MATRIX1, T_SRATIONAL, 9, _rationals(dng_colour_matrix(raw).ravel(), signed=True), True),
        (TAG_CALIBRATION_ILLUMINANT1, T_SHORT, 1, ILLUMINANT_D65, True),
        (TAG_AS_SHOT_NEUTRAL, T_RATIONAL, 3, _rationals(as_shot_neutral(raw), signed=False), True),
        (TAG_BASELINE_EXPOSURE, T_SRATIONAL, 1, _rationals([_baseline_exposure(raw)], signed=True), True),
    ]
    crop = raw.metadata.get("crop")
    if isinstance(crop, (list, tuple)) and len(crop) == 4:     # (x, y) and (width, height)
        tags += [(TAG_DEFAULT_CROP_ORIGIN, T_LONG, 2, (int(crop[1]), int(crop[0])), True),
                 (TAG_DEFAULT_CROP_SIZE, T_LONG, 2, (int(crop[3]), int(crop[2])), True)]
    if raw.metadata.get("opcodes"):                      # OpcodeList1-3 (GainMap, bad pixels): tags, not JSON
        from .opcodes import opcode_tags, opcodes_of
        tags += opcode_tags(opcodes_of(raw.metadata))
    private = PRIVATE_PREFIX + json.dumps(_metadata_json(raw), default=_json_default).encode("utf-8")
    tags.append((TAG_DNG_PRIVATE_DATA, T_BYTE, len(private), private, True))
    return tags


def dng_colour_matrix(raw: RawImage) -> np.ndarray:
    """DNG ColorMatrix1: XYZ (D65) -> camera native channels, 3 x 3.

    camera_native = diag(1/wb) @ inv(colour_matrix) @ XYZ_TO_SRGB, scaled so that the D65 white
    with Y = 1 maps to a largest channel value of 1 (as DNG expects).
    """
    wb = np.where(raw.wb > 0, raw.wb, 1.0)
    try:
        m = np.diag(1.0 / wb) @ np.linalg.inv(raw.colour_matrix) @ XYZ_TO_SRGB
    except np.linalg.LinAlgError:
        m = np.diag(1.0 / wb) @ XYZ_TO_SRGB
    peak = float(np.max(m @ D65_XYZ))
    return m / peak if np.isfinite(peak) and peak > 0 else m


def as_shot_neutral(raw: RawImage) -> np.ndarray:
    """DNG AsShotNeutral: 1/wb per CFA channel, scaled so the largest entry is 1, shape (3,)."""
    wb = np.where(raw.wb > 0, raw.wb, 1.0)
    neutral = 1.0 / wb
    return neutral / neutral.max()


def _baseline_exposure(raw: RawImage) -> float:
    """DNG BaselineExposure in EV: log2(raw.exposure) (0 when the exposure is not positive)."""
    return math.log2(raw.exposure) if raw.exposure > 0 and math.isfinite(raw.exposure) else 0.0


def _checked_dtype(raw: RawImage, target: Path) -> np.dtype:
    """The file dtype for ``raw.data``: native uint16 or float32; ClispError for anything else."""
    dtype = raw.data.dtype
    if dtype.kind == "u" and dtype.itemsize == 2:
        out_dtype = np.dtype(np.uint16)
    elif dtype.kind == "f" and dtype.itemsize == 4:
        out_dtype = np.dtype(np.float32)
    else:
        raise ClispError(f"cannot write raw file '{target}': data must be uint16 or float32, got {dtype}")
    if raw.cfa.n_channels != 3:
        raise ClispError(f"cannot write raw file '{target}': CFA {raw.cfa.name} has "
                         f"{raw.cfa.n_channels} channels, DNG CFAPlaneColor needs 3")
    return out_dtype


def _calibration(raw: RawImage) -> dict[str, Any]:
    """The raw's levels, white balance, exposure and colour matrices as JSON values (in the order
    our DNG's private data and ``clisp info`` list them)."""
    return {
        "black_level": [float(v) for v in raw.black_level],
        "white_level": float(raw.white_level),
        "wb": [float(v) for v in raw.wb],
        "exposure": float(raw.exposure),
        "colour_matrix": raw.colour_matrix.tolist(),
        "wb2": [float(v) for v in raw.wb2],
    }


def _metadata_json(raw: RawImage) -> dict[str, Any]:
    """Everything needed to rebuild ``raw`` exactly (except the pixels and ``source``)."""
    return {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "dtype": str(np.dtype(raw.data.dtype).newbyteorder("=")),
        "shape": list(raw.shape),
        "cfa": {"name": raw.cfa.name, "kind": raw.cfa.kind, "channels": list(raw.cfa.channels),
                "pattern": raw.cfa.pattern.tolist()},
        **_calibration(raw),
        "metadata": {k: v for k, v in raw.metadata.items() if k != "opcodes"},   # the opcodes are tags
    }


def _json_default(obj: Any) -> Any:
    """JSON fallback for numpy values in ``raw.metadata`` (arrays become lists)."""
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, (set, frozenset, tuple)):
        return list(obj)
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"metadata value of type {type(obj).__name__} is not JSON serialisable")


def _rationals(values: Any, signed: bool) -> tuple[int, ...]:
    """Flatten ``values`` into TIFF (numerator, denominator) pairs; SRATIONAL when ``signed``."""
    out: list[int] = []
    for v in np.asarray(values, dtype=np.float64).ravel():
        num, den = _rational(float(v), signed)
        out += [num, den]
    return tuple(out)


def _rational(v: float, signed: bool) -> tuple[int, int]:
    """Closest fraction to ``v`` whose terms fit a TIFF (S)RATIONAL."""
    if not math.isfinite(v):
        return (0, 1)
    if not signed:
        v = max(v, 0.0)
    top = _INT32_MAX if signed else _UINT32_MAX
    if abs(v) >= top:
        return (top if v > 0 else -top, 1)
    max_den = max(1, min(top, int(top / max(abs(v), 1.0))))
    f = Fraction(v).limit_denominator(max_den)
    return (int(f.numerator), int(f.denominator))


def _clamp_int(v: float, lo: int, hi: int) -> int:
    return int(min(max(round(v), lo), hi)) if math.isfinite(v) else hi


def _chmod_default(name: str) -> None:
    """Give the temporary file ordinary permissions (mkstemp makes it 0600)."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(name, 0o666 & ~umask)


def _remove_quietly(name: str) -> None:
    try:
        os.unlink(name)
    except OSError:
        pass


# --------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------

RAW_SUFFIXES = frozenset(
    ".dng .tif .tiff .cr2 .cr3 .crw .nef .nrw .arw .srf .sr2 .raf .orf .rw2 .pef .srw .x3f .3fr .erf "
    ".kdc .dcr .mos .mrw .iiq .rwl .raw".split())
"""Suffixes of raw files: ours (.dng, .tif, .tiff) and cameras' (what LibRaw reads)."""

PHOTOMETRIC_LINEAR_RAW = 34892
TAG_DNG_VERSION = 50706


def is_raw_file(path: str | os.PathLike[str]) -> bool:
    """Whether ``path`` holds a raw mosaic rather than an image: a camera raw's suffix (RAW_SUFFIXES
    but .tif and .tiff), or a TIFF (also .dng) whose first page is a CFA or linear-raw image or
    carries a DNG version (ours, a camera's DNG). A file that cannot be read is not called raw
    (its reader then says what is wrong).

    >>> is_raw_file("scene.png"), is_raw_file("shot.CR2")
    (False, True)
    """
    p = Path(path)
    suffix = p.suffix.lower()
    if suffix in RAW_SUFFIXES and suffix not in (".tif", ".tiff", ".dng"):
        return True
    if suffix not in (".tif", ".tiff", ".dng"):
        return False
    try:
        with library_output(), tifffile.TiffFile(p) as tif:
            page = tif.pages[0]
            return (int(page.photometric) in (PHOTOMETRIC_CFA, PHOTOMETRIC_LINEAR_RAW)
                    or TAG_DNG_VERSION in page.tags)
    except Exception:  # noqa: BLE001 - not a TIFF tifffile reads: not called raw here
        return suffix == ".dng"


def read_raw(path: str | os.PathLike[str], lazy: bool = False) -> RawImage:
    """Read a raw file: one of ours exactly (``source`` = str(path)), else a camera raw via rawpy.

    ``lazy``: for our (uncompressed, contiguous) files ``data`` is a read-only ``np.memmap``, so
    the pixels stay on disk until read; tile streaming then reads only each tile's rows (see
    clisp.engine.streaming.window_source). Camera raws are always decoded whole.
    """
    raw, _ = _load(path, lazy)
    return raw


def raw_info(path: str | os.PathLike[str]) -> dict[str, Any]:
    """Summary of a raw file for ``clisp info RAW``: sizes, CFA, levels (DN), WB, matrix, gain."""
    raw, kind = _load(path, lazy=True)            # the pixels are not needed
    md = raw.metadata
    info: dict[str, Any] = {
        "path": str(path),
        "source_kind": kind,
        "width": raw.shape[1],
        "height": raw.shape[0],
        "dtype": str(raw.data.dtype),
        "cfa": raw.cfa.name,
        "cfa_kind": raw.cfa.kind,
        "channels": list(raw.cfa.channels),
        **_calibration(raw),
        "gain": md.get("gain"),
    }
    make, model = camera_make_model(raw)
    info["make"], info["model"] = make or None, model or None
    exif = md.get("exif") if isinstance(md.get("exif"), dict) else {}
    for key, name in _INFO_EXIF.items():
        if key in exif:
            info[name] = exif[key]
    for key in ("wb_source", "colour_matrix_source", "flip", "crop", "sensor"):
        if key in md:
            info[key] = md[key]
    if md.get("opcodes"):
        from .opcodes import opcodes_of   # deferred: only raws with DNG opcodes load clisp.io.opcodes (start-up)
        ops = opcodes_of(md)
        counts: dict[str, int] = {}
        for op in ops:
            key = f"{op.name} (OpcodeList{op.list_no})"
            counts[key] = counts.get(key, 0) + 1
        info["opcodes"] = [f"{k} x{n}" if n > 1 else k for k, n in counts.items()]
    return info


_INFO_EXIF = {"Exif:LensModel": "lens", "ExposureTime": "exposure_time_s", "FNumber": "f_number",
              "Exif:PhotographicSensitivity": "iso", "Exif:DateTimeOriginal": "captured"}
"""The shot's EXIF (clisp.io.exif names) that ``clisp info`` shows, and under which key."""


def _load(path: str | os.PathLike[str], lazy: bool = False) -> tuple[RawImage, str]:
    """Read ``path`` and say whether it was one of ours (SOURCE_CLISP) or a camera raw."""
    p = Path(path)
    _check_readable(p)
    ours, tiff_error = _try_read_clisp(p, lazy)
    if ours is not None:
        return ours, SOURCE_CLISP
    from .camera import read_camera_raw        # deferred: io.camera costs 3 ms of start-up (rawpy on use)
    try:
        return read_camera_raw(p), SOURCE_CAMERA
    except ClispError as exc:
        kind = _sniff_kind(p)
        if kind is not None and kind != "TIFF":
            article = "an" if kind[0] in "AEIOU" else "a"
            raise ClispError(f"cannot read raw file '{p}': it is {article} {kind}, not a raw file") from exc
        if kind == "TIFF" and tiff_error is not None:
            raise ClispError(f"cannot read raw file '{p}': damaged or truncated TIFF ({tiff_error})") from exc
        raise


def _check_readable(p: Path) -> None:
    """Raise ClispError for a missing, unreadable, non-regular or empty file."""
    try:
        st = p.stat()
    except FileNotFoundError as exc:
        raise ClispError(f"cannot read raw file '{p}': no such file") from exc
    except OSError as exc:
        raise ClispError(f"cannot read raw file '{p}': {one_line(exc)}") from exc
    if p.is_dir():
        raise ClispError(f"cannot read raw file '{p}': it is a folder")
    if st.st_size == 0:
        raise ClispError(f"cannot read raw file '{p}': the file is empty")
    if not os.access(p, os.R_OK):
        raise ClispError(f"cannot read raw file '{p}': permission denied")


def _try_read_clisp(p: Path, lazy: bool = False) -> tuple[RawImage | None, str | None]:
    """(RawImage, None) for one of our files; (None, tifffile's complaint or None) otherwise."""
    try:
        with library_output(), tifffile.TiffFile(p) as tif:
            if not tif.pages:
                return None, "no images"
            page = tif.pages[0]
            meta = _private_metadata(page, p)
            if meta is None:
                return None, None
            data = _read_pixels(page, p, meta, lazy)
            shape = tuple(int(v) for v in page.shape)
            ops = page_opcodes(page, str(p), (0, 0), shape, shape)
    except ClispError:
        raise
    except Exception as exc:  # noqa: BLE001 - tifffile raises many types on non-TIFF input
        return None, clip(one_line(exc))
    raw = _rebuild(meta, data, p)
    if ops:
        raw.metadata["opcodes"] = ops
    return raw, None


def _private_metadata(page: Any, p: Path) -> dict[str, Any] | None:
    """Our JSON from DNGPrivateData, or None when the TIFF is not one of ours."""
    tag = page.tags.get(TAG_DNG_PRIVATE_DATA)
    if tag is None:
        return None
    value = tag.value
    blob = bytes(value) if not isinstance(value, bytes) else value
    if not blob.startswith(PRIVATE_PREFIX):
        return None
    try:
        meta = json.loads(blob[len(PRIVATE_PREFIX):].rstrip(b"\0").decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ClispError(f"cannot read raw file '{p}': corrupt clisp metadata ({clip(one_line(exc))})") from exc
    if not isinstance(meta, dict) or meta.get("format") != FORMAT_NAME:
        raise ClispError(f"cannot read raw file '{p}': unrecognised clisp metadata")
    version = meta.get("version", 0)
    if not isinstance(version, int) or version < 1:
        raise ClispError(f"cannot read raw file '{p}': corrupt clisp metadata (version {clip(version, 20)})")
    if version > FORMAT_VERSION:
        raise ClispError(f"cannot read raw file '{p}': written by a newer clisp (format version {version})")
    return meta


def _read_pixels(page: Any, p: Path, meta: dict[str, Any], lazy: bool = False) -> np.ndarray:
    """The mosaic of ``page`` after checking that the file holds all of it (``lazy``: mapped,
    not read, when the file allows it)."""
    if int(page.photometric) != PHOTOMETRIC_CFA:
        raise ClispError(f"cannot read raw file '{p}': photometric {int(page.photometric)} is not CFA")
    want_dtype, want_shape = _declared_layout(meta, p)
    if int(page.compression) != 1:
        raise ClispError(f"cannot read raw file '{p}': compressed image data (compression "
                         f"{int(page.compression)}); clisp writes its raws uncompressed")
    if tuple(page.shape) != want_shape or page.dtype is None or \
            np.dtype(page.dtype).newbyteorder("=") != want_dtype:
        raise ClispError(f"cannot read raw file '{p}': image is {clip(page.dtype, 20)} {clip(tuple(page.shape), 40)}, "
                         f"metadata says {want_dtype} {want_shape}")
    size = p.stat().st_size
    ends = [int(o) + int(n) for o, n in zip(page.dataoffsets, page.databytecounts)]
    need = want_shape[0] * want_shape[1] * want_dtype.itemsize
    if not ends or max(ends) > size or sum(int(n) for n in page.databytecounts) < need:
        need = max(max(ends) if ends else 0, need)
        raise ClispError(f"cannot read raw file '{p}': truncated (image data needs {need} bytes, "
                         f"file has {size})")
    try:
        data = _mapped_pixels(page, p) if lazy else None
        if data is None:
            data = page.asarray()
    except Exception as exc:  # noqa: BLE001
        raise ClispError(f"cannot read raw file '{p}': damaged image data ({clip(one_line(exc))})") from exc
    if data.shape != want_shape or data.dtype.newbyteorder("=") != want_dtype.newbyteorder("="):
        raise ClispError(f"cannot read raw file '{p}': image is {data.dtype} {data.shape}, "
                         f"metadata says {want_dtype} {want_shape}")
    if isinstance(data, np.memmap):
        return data
    return np.ascontiguousarray(data, dtype=want_dtype.newbyteorder("="))


def _declared_layout(meta: dict[str, Any], p: Path) -> tuple[np.dtype, tuple[int, int]]:
    """The dtype (uint16 or float32) and shape our metadata declares, checked against
    MAX_PIXELS before anything is read or allocated."""
    dtype, shape = meta.get("dtype"), meta.get("shape")
    if dtype not in ("uint16", "float32"):
        raise ClispError(f"cannot read raw file '{p}': corrupt clisp metadata (dtype {clip(dtype, 20)})")
    if not (isinstance(shape, list) and len(shape) == 2 and all(type(v) is int and v > 0 for v in shape)):
        raise ClispError(f"cannot read raw file '{p}': corrupt clisp metadata (shape {clip(shape, 30)})")
    if shape[0] * shape[1] > MAX_PIXELS:
        raise ClispError(f"cannot read raw file '{p}': declares {shape[1]}x{shape[0]} pixels, "
                         f"more than clisp's limit of {MAX_PIXELS // 2**20} MP")
    return np.dtype(dtype), (shape[0], shape[1])


def _mapped_pixels(page: Any, p: Path) -> np.memmap | None:
    """A read-only memory map of an uncompressed single-sample page stored in contiguous
    strips (as we write them), or None when the layout does not allow one."""
    offsets, counts = page.dataoffsets, page.databytecounts
    contiguous = all(int(o) + int(n) == int(o2) for o, n, o2 in zip(offsets, counts, offsets[1:]))
    if int(page.compression) != 1 or page.samplesperpixel != 1 or len(page.shape) != 2 or not contiguous:
        return None
    dtype = np.dtype(page.parent.byteorder + page.dtype.char)
    return np.memmap(p, dtype=dtype, mode="r", offset=int(offsets[0]), shape=tuple(page.shape))


def _rebuild(meta: dict[str, Any], data: np.ndarray, p: Path) -> RawImage:
    """RawImage from our JSON metadata and the pixels."""
    try:
        cfa = _rebuild_cfa(meta["cfa"], p)
        raw = RawImage(
            data=data,
            cfa=cfa,
            black_level=np.asarray(meta["black_level"], dtype=np.float64),
            white_level=float(meta["white_level"]),
            wb=np.asarray(meta["wb"], dtype=np.float64),
            colour_matrix=np.asarray(meta["colour_matrix"], dtype=np.float64),
            exposure=float(meta["exposure"]),
            wb2=np.asarray(meta["wb2"], dtype=np.float64),
            metadata=dict(meta.get("metadata") or {}),
            source=str(p),
        )
    except ClispError:
        raise
    except (KeyError, TypeError, ValueError, OverflowError, AttributeError) as exc:
        raise ClispError(f"cannot read raw file '{p}': corrupt clisp metadata ({clip(one_line(exc))})") from exc
    problem = check_levels(raw)
    if problem:
        raise ClispError(f"cannot read raw file '{p}': corrupt clisp metadata ({problem})")
    return raw


def _rebuild_cfa(desc: dict[str, Any], p: Path) -> CFA:
    """The CFA named in the metadata, checked against the stored kind (or the kind clisp gave it
    before issue 45, cfa.kind_before_issue45), channels and pattern."""
    if not isinstance(desc, dict):
        raise ClispError(f"cannot read raw file '{p}': corrupt clisp metadata (cfa {clip(desc, 30)})")
    full = desc.get("name")
    name = clip(full, 30)
    try:
        cfa = cfa_from_name(full if isinstance(full, str) and len(full) <= 200 else name)
    except ClispError as exc:
        raise ClispError(f"cannot read raw file '{p}': unsupported CFA {name!r}") from exc
    stored = np.asarray(desc.get("pattern", cfa.pattern.tolist()))
    if (desc.get("kind", cfa.kind) not in (cfa.kind, kind_before_issue45(cfa))
            or list(cfa.channels) != list(desc.get("channels", cfa.channels))
            or stored.shape != cfa.pattern.shape or not np.array_equal(stored, cfa.pattern)):
        raise ClispError(f"cannot read raw file '{p}': unsupported CFA {name!r} "
                         f"(stored pattern does not match clisp's)")
    return cfa


_MAGIC = (
    (b"\x89PNG\r\n\x1a\n", "PNG image"),
    (b"\xff\xd8\xff", "JPEG image"),
    (b"GIF8", "GIF image"),
    (b"BM", "BMP image"),
    (b"II*\0", "TIFF"),
    (b"MM\0*", "TIFF"),
)


def _sniff_kind(p: Path) -> str | None:
    """Name of a common non-raw format from the file's first bytes ('TIFF' included), or None."""
    try:
        with open(p, "rb") as fh:
            head = fh.read(4096)
    except OSError:
        return None
    for magic, kind in _MAGIC:
        if head.startswith(magic):
            return kind
    return "text file" if _looks_like_text(head) else None


def _looks_like_text(head: bytes) -> bool:
    """True for UTF-8 text without control characters other than tab, CR, LF, FF."""
    if not head or b"\0" in head:
        return False
    try:
        text = head.decode("utf-8")
    except UnicodeDecodeError:
        text = head[:-3].decode("utf-8", "replace")  # the cut may split a multi-byte character
        if "\ufffd" in text:
            return False
    return all(ch.isprintable() or ch in "\t\r\n\f" for ch in text)


