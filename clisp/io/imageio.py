"""Scene and output images through OpenImageIO: EXR (linear float), TIFF/PNG (16-bit sRGB).

Outputs are written band by band (:class:`ImageWriter`, scanlines top to bottom), so tile
streaming never holds a whole output image. Every output says what it holds: TIFF and PNG embed
an sRGB ICC profile, EXR declares the chromaticities of linear sRGB (Rec. 709 primaries, D65), and
the caller's attributes (camera EXIF, see clisp.io.exif) go into the header before the first row.
Every write goes to a temporary file in the destination folder and is renamed into place only
after it completed, so a failure never leaves a partial or corrupt output.
"""
from __future__ import annotations

import errno
import os
import tempfile
from contextlib import ExitStack, contextmanager
from functools import lru_cache
from pathlib import Path
from typing import Iterator

import numpy as np

from ..sim.colorimetry import srgb_decode, srgb_encode
from ..errors import ClispError, clip, library_output
from ..engine.profile import host_timer

LINEAR_EXTENSIONS = (".exr",)
ENCODED_EXTENSIONS = (".tif", ".tiff", ".png", ".jpg", ".jpeg")
OIIO_FORMATS = {".exr": "openexr", ".tif": "tiff", ".tiff": "tiff", ".png": "png", ".jpg": "jpeg", ".jpeg": "jpeg"}
JPEG_EXTENSIONS = (".jpg", ".jpeg")
JPEG_QUALITY = 92
"""JPEG quality when ``--compression`` does not give one ('jpeg:N', N 1..100): libjpeg's scale,
where 90-95 is what cameras and raw converters save by default."""
JPEG_SUBSAMPLING = "4:4:4"
"""Chroma kept at full resolution. libjpeg's default 4:2:0 halves it both ways: on a 320 x 256 raw
at gain 4 (fast preset) the JPEG differed from the 16-bit TIFF by 0.053 on average (99th
percentile 0.31, colour edges) at quality 92 and 0.050 at 100; 4:4:4 at 92: 0.017 (0.063), for
twice the file size."""


def _oiio():  # imported lazily: OpenImageIO takes a moment to load
    import OpenImageIO as oiio
    return oiio


def output_kind(path: str | Path) -> str:
    """'linear' for EXR, 'srgb' for 16-bit TIFF/PNG; ClispError for anything else."""
    ext = Path(path).suffix.lower()
    if ext in LINEAR_EXTENSIONS:
        return "linear"
    if ext in ENCODED_EXTENSIONS:
        return "srgb"
    if not ext:
        raise ClispError(f"{path}: the output name has no extension; use .exr, .tif, .tiff, .png or .jpg "
                         f"(several raws go to an output folder)")
    raise ClispError(f"{path}: unsupported output extension {ext!r}; use .exr, .tif, .tiff, .png or .jpg")


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` with the same extension; rename it to ``path`` on
    success, delete it on any failure."""
    path = Path(path)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():
        raise ClispError(f"{path}: output folder {folder} does not exist")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.partial-", suffix=path.suffix, dir=folder)
    except OSError as exc:
        if exc.errno == errno.ENOENT:             # the folder is there (checked above) but takes no files
            raise ClispError(f"{path}: cannot write in {folder}: it takes no new files (a system folder "
                             f"such as /proc or /sys?)") from exc
        raise ClispError(f"{path}: cannot write in {folder} ({clip(exc.strerror or exc)})") from exc
    os.close(fd)
    tmp_path = Path(tmp)
    umask = os.umask(0)
    os.umask(umask)
    try:
        yield tmp_path
        os.chmod(tmp_path, 0o666 & ~umask)  # mkstemp creates 0600; give the usual permissions
        os.replace(tmp_path, path)
    except BaseException as exc:
        tmp_path.unlink(missing_ok=True)
        if isinstance(exc, OSError):             # full disk, vanished folder, target is a folder
            raise ClispError(f"{path}: write failed ({clip(exc.strerror or exc)})") from exc
        raise


MAX_SCENE_PIXELS = 2**28
"""Largest scene image (pixels) read_image accepts: 256 MP, checked before the pixels are read."""

MAX_EXPANSION = 1100
"""Most bytes a byte of an image file may decode to: deflate's ceiling is about 1032:1 (PNG,
TIFF and EXR zip), the others' are lower; a header declaring more pixels than that is corrupt,
refused before anything is allocated."""


def read_image(path: str | Path) -> tuple[np.ndarray, bool]:
    """Read an image as H x W x 3 float32; returns (pixels, is_float_file).

    Integer files are scaled to [0, 1]; grey images are replicated to 3 channels, alpha dropped.
    ClispError naming the file for anything unreadable, with OpenImageIO's complaint (what it
    prints on stderr is folded into the message), for sizes a file of its size cannot hold.
    """
    oiio = _oiio()
    path = Path(path)
    if not path.is_file():
        raise ClispError(f"{path}: no such file")
    with library_output() as said:
        inp = oiio.ImageInput.open(str(path))
        if inp is None:
            problem = _error_text(oiio) or "unknown format"
        else:
            try:
                spec = inp.spec()
                problem = _implausible(spec, path.stat().st_size)
                pixels = None if problem else inp.read_image(0, 0, 0, spec.nchannels, "float")
                if not problem and (pixels is None or not isinstance(pixels, np.ndarray)
                                    or pixels.size != spec.width * spec.height * spec.nchannels):
                    problem = f"cannot read pixels ({_error_text(inp) or 'truncated file?'})"
                is_float = spec.format.basetype in (oiio.FLOAT, oiio.HALF, oiio.DOUBLE)
            finally:
                _error_text(inp)
                inp.close()
            _error_text(oiio)                    # nothing left pending for OpenImageIO to print at exit
    if inp is None:
        raise ClispError(f"{path}: cannot read image ({clip(problem)}{said.note(40)})")
    if problem:
        raise ClispError(f"{path}: {clip(problem, 100)}{said.note(40)}")
    pixels = pixels.reshape(spec.height, spec.width, spec.nchannels)
    if spec.nchannels in (1, 2):
        pixels = np.repeat(pixels[..., :1], 3, axis=2)
    return np.ascontiguousarray(pixels[..., :3], dtype=np.float32), is_float


def _error_text(source: object) -> str:
    """OpenImageIO's pending error of ``source`` (the module or an ImageInput/ImageOutput), cleared,
    on one line and cut; its text may quote the file's bytes, which the bindings fail to decode
    as UTF-8 (found by fuzzing): then a placeholder."""
    try:
        return clip(source.geterror(), 100)
    except UnicodeDecodeError:
        return "(undecodable error text)"


def _implausible(spec: object, file_size: int) -> str | None:
    """Why an image header cannot be right (sizes out of range, more pixels than a file of
    ``file_size`` bytes can hold), or None."""
    w, h, c = int(spec.width), int(spec.height), int(spec.nchannels)
    if w <= 0 or h <= 0 or not 1 <= c <= 64:
        return f"image of {w}x{h} pixels and {c} channels"
    if w * h > MAX_SCENE_PIXELS:
        return f"image of {w}x{h} pixels, more than clisp's limit of {MAX_SCENE_PIXELS // 2**20} MP"
    stored = w * h * c * max(1, int(spec.format.size()))
    if stored > MAX_EXPANSION * file_size + 2**16:
        return f"header declares {w}x{h}x{c}, more than a file of {file_size} bytes can hold (corrupt)"
    return None


def read_scene(path: str | Path) -> np.ndarray:
    """A scene as H x W x 3 float64 LINEAR sRGB (white 1.0).

    Float files (EXR) are taken as linear sRGB; integer files (PNG/TIFF, 8 or 16 bit) as
    sRGB-encoded and decoded with the IEC 61966-2-1 curve.
    """
    pixels, is_float = read_image(path)
    pixels = pixels.astype(np.float64)
    if not np.all(np.isfinite(pixels)):
        raise ClispError(f"{path}: scene contains NaN or infinite values")
    return pixels if is_float else srgb_decode(np.clip(pixels, 0.0, 1.0))


def write_image(path: str | Path, image: np.ndarray, encoded: bool | None = None,
                compression: str = "none", attributes: dict | None = None) -> None:
    """Write H x W x 3 float: EXR as float32 linear; TIFF/PNG as 16-bit.

    For TIFF/PNG, ``image`` must already be sRGB-encoded in [0, 1] unless ``encoded`` is False,
    in which case it is tone-mapped here. ``compression``: see DEFAULT_COMPRESSION.
    ``attributes``: metadata, see ImageWriter. Atomic.
    """
    pixels = np.asarray(image)
    if output_kind(path) == "srgb" and encoded is False:
        pixels = srgb_encode(np.asarray(pixels, dtype=np.float32))
    with ImageWriter(path, pixels.shape[1], pixels.shape[0], pixels.shape[2], compression, attributes) as out:
        out.write_rows(0, pixels)


WRITE_ROWS = 128
"""Rows per write_scanlines call: bounds the converted (float32, clipped) copy and OIIO's own
conversion buffers, whatever the band height; enough for OpenEXR to compress 8 line blocks of 16
rows in parallel."""


DEFAULT_COMPRESSION = "none"
"""EXR/TIFF/PNG compression unless asked otherwise. Measured on 25 MP of noisy float32 (2-core machine):
none 37 MP/s; zip 3.4 MP/s for a 4% smaller file; piz 3.3 MP/s, 12% smaller. A raw converter's
output is noisy, so compression costs ten times the processing time for little; ``--compression
zip`` (or piz, dwaa, ...; any OpenImageIO compression name) when size matters."""


COMPRESSIONS = {
    ".exr": ("none", "rle", "zips", "zip", "piz", "pxr24", "b44", "b44a", "dwaa", "dwab"),
    ".tif": ("none", "lzw", "zip", "packbits"),
    ".tiff": ("none", "lzw", "zip", "packbits"),
    ".png": ("none", "zip"),
    ".jpg": ("jpeg",),
    ".jpeg": ("jpeg",),
}
"""Compression names accepted per output extension (OpenImageIO's; 'zip:N' / 'dwaa:N' set a level)."""


SRGB_CHROMATICITIES = (0.64, 0.33, 0.30, 0.60, 0.15, 0.06, 0.3127, 0.3290)
"""CIE xy of the sRGB / Rec. 709 red, green and blue primaries and of the D65 white point: the
EXR ``chromaticities`` attribute of our linear outputs."""

ATTRIBUTE_TYPES = {"Orientation": "int", "Exif:PhotographicSensitivity": "int", "Exif:ISOSpeed": "uint",
                   "ExposureTime": "float", "FNumber": "float"}
"""OpenImageIO types of the numeric attributes we write (OpenImageIO converts them to the EXIF types)."""


@lru_cache(maxsize=1)
def srgb_icc_profile() -> bytes:
    """An sRGB ICC profile (LittleCMS's built-in sRGB, through Pillow's ImageCms), for TIFF, PNG and JPEG; kept
    in clisp's cache folder, since importing Pillow for these 588 bytes took 17 ms of every TIFF or
    PNG output's start (clisp.engine.disk_cache: a folder that cannot be read or written only costs
    that time)."""
    from ..engine.disk_cache import cache_dir, entry_name, keep_bytes    # deferred: only TIFF/PNG outputs need it
    try:
        path: Path | None = cache_dir() / "icc" / f"{entry_name('sRGB ICC profile')}.icc"
    except RuntimeError:                                        # Path.home() without a home
        path = None
    try:
        kept = path.read_bytes() if path is not None else b""
        if kept.startswith(b"\0\0") and kept[36:40] == b"acsp":     # an ICC header: size < 16 MB, signature
            return kept
    except OSError:
        pass
    from PIL import ImageCms     # deferred: Pillow only when the profile is not kept
    profile = ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).tobytes()
    if path is not None:
        keep_bytes(path, profile)
    return profile


def _describe(spec: object, kind: str, attributes: dict | None) -> None:
    """Colour space and ``attributes`` into an OpenImageIO ImageSpec (before the file opens)."""
    oiio = _oiio()
    if kind == "srgb":
        spec.attribute("oiio:ColorSpace", "sRGB")
        icc = np.frombuffer(srgb_icc_profile(), dtype=np.uint8)
        spec.attribute("ICCProfile", oiio.TypeDesc(f"uint8[{icc.size}]"), icc)
    else:
        spec.attribute("chromaticities", oiio.TypeDesc("float[8]"), SRGB_CHROMATICITIES)
    for name, value in (attributes or {}).items():
        if name in ATTRIBUTE_TYPES:
            spec.attribute(name, oiio.TypeDesc(ATTRIBUTE_TYPES[name]), value)
        elif isinstance(value, str):
            spec.attribute(name, value)


def check_compression(path: str | Path, compression: str) -> None:
    """ClispError naming ``path`` when ``compression`` is not one of its format's COMPRESSIONS."""
    ext = Path(path).suffix.lower()
    if ext in JPEG_EXTENSIONS and compression == DEFAULT_COMPRESSION:
        return                                                   # the default: JPEG_QUALITY
    allowed = COMPRESSIONS.get(ext, ())
    name, _, level = compression.partition(":")
    if name not in allowed:
        raise ClispError(f"{path}: compression {compression!r} is not available for {ext} "
                         f"(choose from {', '.join(allowed)})")
    if ext in JPEG_EXTENSIONS and level and not (level.isdigit() and 1 <= int(level) <= 100):
        raise ClispError(f"{path}: JPEG quality {level!r} is not a whole number from 1 to 100 (jpeg:N)")


PNG_ZIP_LEVEL = 6
"""zlib level of ``--compression zip`` for PNG without a level ('zip:N' sets N)."""


def _png_compression(spec: object, compression: str) -> None:
    """PNG compression attributes: 'none' stores the rows in uncompressed deflate blocks, without
    row filters (a valid PNG as large as the pixels; libpng's default filters and level 6 took
    10 s for 24 MP of 16-bit RGB, this 0.5 s, like the uncompressed TIFF and EXR defaults);
    'zip[:N]' deflates at level N (default PNG_ZIP_LEVEL) with libpng's adaptive filters."""
    name, _, level = compression.partition(":")
    if name == "none":
        spec.attribute("png:compressionLevel", 0)
        spec.attribute("png:filter", 8)                      # PNG_FILTER_NONE
    else:
        spec.attribute("png:compressionLevel", int(level) if level.isdigit() else PNG_ZIP_LEVEL)


class ImageWriter:
    """An H x W x C output image written band by band, top to bottom, never held whole.

    EXR: float32 linear scanlines. TIFF/PNG: 16-bit; the rows must be
    sRGB-encoded and are clipped to [0, 1] here. Use as a context manager: the file is written
    under a temporary name beside ``path`` and renamed when every row arrived without error;
    otherwise it is removed (ClispError names ``path``).

    TIFF/PNG embed an sRGB ICC profile, EXR declares linear sRGB's chromaticities.
    ``attributes``: OpenImageIO attribute names and values (strings, and the numbers of
    ATTRIBUTE_TYPES), e.g. clisp.io.exif.output_attributes: each format stores what it can (TIFF:
    its tags and EXIF directory; PNG: text and eXIf chunks; EXR: header attributes).
    """

    def __init__(self, path: str | Path, width: int, height: int, channels: int = 3,
                 compression: str = DEFAULT_COMPRESSION, attributes: dict | None = None) -> None:
        self.path = Path(path)
        check_compression(self.path, compression)
        self.compression = compression
        self.kind = output_kind(self.path)
        self.width, self.height, self.channels = width, height, channels
        self.attributes = dict(attributes or {})
        self.next_row = 0
        self._stack = ExitStack()
        self._out = None
        self._tmp: Path | None = None

    def __enter__(self) -> "ImageWriter":
        oiio = _oiio()
        suffix = self.path.suffix.lower()
        fmt = "float" if self.kind == "linear" else "uint8" if suffix in JPEG_EXTENSIONS else "uint16"
        spec = oiio.ImageSpec(self.width, self.height, self.channels, fmt)     # rows are converted to fmt
        if suffix == ".png":
            _png_compression(spec, self.compression)
        elif suffix in JPEG_EXTENSIONS:
            spec.attribute("compression", self.compression if self.compression.startswith("jpeg:")
                           else f"jpeg:{JPEG_QUALITY}")
            spec.attribute("jpeg:subsampling", JPEG_SUBSAMPLING)
        else:
            spec.attribute("compression", self.compression)
        _describe(spec, self.kind, self.attributes)
        tmp = self._tmp = self._stack.enter_context(atomic_path(self.path))
        out = oiio.ImageOutput.create(OIIO_FORMATS[self.path.suffix.lower()])
        if out is None or not out.open(str(tmp), spec):
            self._stack.close()
            raise ClispError(f"{self.path}: cannot open for writing ({_error_text(oiio)})")
        self._out = out
        return self

    def write_rows(self, y0: int, rows: np.ndarray) -> None:
        """Write rows y0..y0+h (h x W x C float, or uint16 codes for TIFF/PNG); bands must follow
        each other without gaps."""
        if y0 != self.next_row or rows.shape[1:] != (self.width, self.channels):
            raise ClispError(f"{self.path}: band {rows.shape} at row {y0} does not follow row "
                             f"{self.next_row} of a {self.width}x{self.height}x{self.channels} image")
        with host_timer("write output", rows.nbytes):
            self._write_rows(rows)

    def _write_rows(self, rows: np.ndarray) -> None:
        for pixels in self._chunks(rows):
            if not self._out.write_scanlines(self.next_row, self.next_row + pixels.shape[0], 0, pixels):
                raise ClispError(f"{self.path}: write failed ({_error_text(self._out)})")
            self.next_row += pixels.shape[0]

    def _chunks(self, rows: np.ndarray) -> Iterator[np.ndarray]:
        """``rows`` as the contiguous arrays write_scanlines takes. Codes from the device (16-bit for
        TIFF/PNG, 8-bit for JPEG) go as they are, a contiguous band in one call (TIFF: 0.13 s for 24 MP in
        504-row bands, 0.28 s in 128-row chunks); float rows are converted (and for TIFF/PNG
        clipped) WRITE_ROWS at a time, which bounds the converted copy."""
        codes = rows.dtype in (np.uint16, np.uint8) and self.kind == "srgb"
        if codes and rows.flags.c_contiguous:
            yield rows
            return
        for start in range(0, rows.shape[0], WRITE_ROWS):      # (a rotated view: copied in chunks)
            if codes:
                yield np.ascontiguousarray(rows[start:start + WRITE_ROWS])
                continue
            pixels = np.ascontiguousarray(rows[start:start + WRITE_ROWS], dtype=np.float32)
            if not np.isfinite(pixels).all():            # the last guard: no NaN/Inf in a file
                bad = int(pixels.size - np.count_nonzero(np.isfinite(pixels)))
                raise ClispError(f"{self.path}: {bad} non-finite values in output rows "
                                 f"{self.next_row}..{self.next_row + pixels.shape[0] - 1}; nothing written")
            yield np.clip(pixels, 0.0, 1.0) if self.kind == "srgb" else pixels

    def _photographers_rationals(self) -> None:
        """The exposure time and f-number of a TIFF or JPEG as cameras write them (1/203, 56/10), not
        as OpenImageIO's floats are converted (10578737/2147483648, 4926/1000000): clisp.io.exif_rationals."""
        from .exif_rationals import (TAG_EXPOSURE_TIME, TAG_F_NUMBER, exposure_fraction,   # deferred: TIFF and JPEG
                                     f_number_fraction, set_exif_rationals)
        values = {}
        if isinstance(self.attributes.get("ExposureTime"), (int, float)):
            values[TAG_EXPOSURE_TIME] = exposure_fraction(float(self.attributes["ExposureTime"]))
        if isinstance(self.attributes.get("FNumber"), (int, float)):
            values[TAG_F_NUMBER] = f_number_fraction(float(self.attributes["FNumber"]))
        if values:
            try:
                set_exif_rationals(self._tmp, values)
            except OSError as exc:
                raise ClispError(f"{self.path}: write failed ({exc.strerror or exc})") from None

    def __exit__(self, exc_type: type | None, exc: BaseException | None, tb: object) -> None:
        out, self._out = self._out, None
        closed = out is not None and out.close()
        error = exc
        if error is None and self.next_row != self.height:
            error = ClispError(f"{self.path}: only {self.next_row} of {self.height} rows were written")
        elif error is None and not closed:
            error = ClispError(f"{self.path}: write failed ({_error_text(out)})")
        if error is None and self.path.suffix.lower() in (".tif", ".tiff", *JPEG_EXTENSIONS):
            try:
                self._photographers_rationals()
            except ClispError as failed:
                error = failed
        if error is None:
            self._stack.close()                                   # rename into place
            return
        self._stack.__exit__(type(error), error, error.__traceback__)   # remove the temporary file
        if exc is None:
            raise error
