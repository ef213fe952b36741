"""EXIF rationals of a TIFF or JPEG written by OpenImageIO, set to the fractions a photographer reads.

OpenImageIO takes ExposureTime and FNumber as floats. libtiff stores a float as a RATIONAL with a
denominator of 2^31 (the Canon D30's 1/203 s came out as 10578737/2147483648, as exiftool and
camera software print it), OpenImageIO's JPEG writer over a power of ten (4926/1000000). :func:`set_exif_rationals` rewrites those values in place in the
written file, before it is renamed into place (clisp.io.imageio.ImageWriter): same tags, same
sizes, only the two 32-bit numbers of each RATIONAL change. Classic TIFF only (OpenImageIO writes
no BigTIFF for our sizes), and the TIFF structure inside a JPEG's APP1 segment; a file whose
layout is not as expected is left as it is.
"""
from __future__ import annotations

import struct
from fractions import Fraction
from pathlib import Path

TAG_EXIF_IFD = 34665
TAG_EXPOSURE_TIME = 33434
TAG_F_NUMBER = 33437
RATIONAL = 5


def exposure_fraction(seconds: float) -> tuple[int, int]:
    """An exposure time as a camera shows it: 1/N below one second when 1/seconds is within 1 % of
    an integer N, else the nearest fraction with a denominator of at most 1000.

    >>> exposure_fraction(0.004926108), exposure_fraction(2.5), exposure_fraction(1 / 3)
    ((1, 203), (5, 2), (1, 3))
    """
    if not seconds > 0:
        return 0, 1
    if seconds < 1:
        n = round(1.0 / seconds)
        if n > 0 and abs(1.0 / seconds - n) <= 0.01 * n:
            return 1, n
    f = Fraction(seconds).limit_denominator(1000)
    return f.numerator, f.denominator


def f_number_fraction(value: float) -> tuple[int, int]:
    """An f-number to a tenth, as a camera states it: 5.6 -> (56, 10).

    >>> f_number_fraction(5.599999904632568), f_number_fraction(8.0)
    ((56, 10), (80, 10))
    """
    return (round(value * 10), 10) if value > 0 else (0, 1)


def set_exif_rationals(path: str | Path, values: dict[int, tuple[int, int]]) -> int:
    """Rewrite the RATIONAL tags ``values`` ({tag: (numerator, denominator)}) of the EXIF directory
    of the classic TIFF, or the JPEG's EXIF block (APP1, a TIFF structure inside), at ``path`` in
    place; returns how many were rewritten (0 when there is no EXIF directory or the layout is not
    as expected)."""
    with open(path, "r+b") as f:
        base = _jpeg_exif_base(f) if f.read(2) == b"\xff\xd8" else 0
        if base is None:
            return 0
        f.seek(base)
        head = f.read(8)
        if len(head) < 8 or head[:2] not in (b"II", b"MM"):
            return 0
        order = "<" if head[:2] == b"II" else ">"
        if struct.unpack(order + "H", head[2:4])[0] != 42:
            return 0
        exif = _entry_value(f, order, base, struct.unpack(order + "I", head[4:8])[0], TAG_EXIF_IFD)
        if exif is None:
            return 0
        done = 0
        for tag, kind, count, value in _entries(f, order, base, exif):
            if tag in values and kind == RATIONAL and count == 1:
                f.seek(base + value)
                f.write(struct.pack(order + "II", *values[tag]))
                done += 1
        return done


def _jpeg_exif_base(f) -> int | None:
    """Byte position of the TIFF header in a JPEG's ``Exif`` APP1 segment (f just past SOI); None
    without one before the image data."""
    while True:
        marker = f.read(4)
        if len(marker) < 4 or marker[0] != 0xFF or marker[1] in (0xDA, 0xD9):    # start of scan, end
            return None
        length = struct.unpack(">H", marker[2:])[0]
        start = f.tell()
        if marker[1] == 0xE1 and f.read(6) == b"Exif\0\0":
            return start + 6
        f.seek(start + length - 2)


def _entries(f, order: str, base: int, ifd: int) -> list[tuple[int, int, int, int]]:
    """(tag, type, count, value or offset) of the IFD at ``ifd`` (offsets from the TIFF header at
    byte ``base``)."""
    f.seek(base + ifd)
    raw = f.read(2)
    if len(raw) < 2:
        return []
    n = struct.unpack(order + "H", raw)[0]
    found = []
    for i in range(n):
        entry = f.read(12)
        if len(entry) < 12:
            break
        found.append(struct.unpack(order + "HHII", entry))
    return found


def _entry_value(f, order: str, base: int, ifd: int, tag: int) -> int | None:
    """The LONG (or IFD) value of ``tag`` in the IFD at ``ifd``; None if absent."""
    for t, _, count, value in _entries(f, order, base, ifd):
        if t == tag and count == 1:
            return value
    return None
