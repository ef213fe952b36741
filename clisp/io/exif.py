"""Capture metadata: what a raw file says about its shot, and what our outputs say about themselves.

:func:`read_exif` reads the make, model, lens, exposure time, f-number, ISO and capture date of a
camera raw with exiv2 (its Python bindings; exiv2 knows the TIFF-based raws, DNG, and Canon's CRW
and maker notes), keyed by the OpenImageIO attribute names the output writers take, so the values
go into TIFF, PNG and EXR unchanged (:func:`output_attributes`). Our simulated raws have no EXIF:
their outputs name clisp as the camera and carry the simulation's settings as the description.
"""
from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from ..version import __version__
from ..cfa import CFA
from .rawimage import RawImage

MAKE, MODEL, LENS = "Make", "Model", "Exif:LensModel"
EXPOSURE_TIME, F_NUMBER, ISO = "ExposureTime", "FNumber", "Exif:PhotographicSensitivity"
DATE_ORIGINAL, DATE_TIME = "Exif:DateTimeOriginal", "DateTime"
"""OpenImageIO attribute names (TIFF tags and the EXIF directory; EXR maps them to its header)."""

ISO_SPEED = "Exif:ISOSpeed"
"""EXIF 2.3 ISOSpeed (LONG): also written, because OpenImageIO's TIFF writer drops
PhotographicSensitivity (a SHORT of variable count in libtiff's table), so a TIFF keeps its ISO."""

_DATE = re.compile(r"\d{4}:\d\d:\d\d \d\d:\d\d:\d\d")


def read_exif(path: str | Path) -> dict[str, Any]:
    """The shot's facts from a raw file as {OpenImageIO attribute name: value}; only what the file
    states with a usable value (zero exposure times, empty dates are left out); {} when exiv2 cannot
    read the file. Strings for make, model, lens and dates ('YYYY:MM:DD HH:MM:SS'), floats for the
    exposure time (s) and f-number, an int for the ISO."""
    import exiv2                 # deferred: exiv2 is only for camera raws (not at `import clisp`)
    exiv2.LogMsg.setLevel(exiv2.LogMsg.Level.mute)
    try:
        image = exiv2.ImageFactory.open(str(path))
        image.readMetadata()
    except exiv2.Exiv2Error:
        return {}
    exif = image.exifData()
    out: dict[str, Any] = {}
    # exiv2's "easy access" functions pick the best tag among the standard, TIFF/EP and maker-note
    # ones (e.g. a CRW's ISO and lens are in Canon's maker notes); each returns a datum or None.
    for name, find in ((MAKE, exiv2.make), (MODEL, exiv2.model), (LENS, exiv2.lensName)):
        datum = find(exif)
        text = _text(datum.print(exif)) if datum is not None else ""
        if text and not text.startswith("("):        # exiv2 prints '(n)' for an unknown lens code
            out[name] = text
    if MODEL not in out:                              # DNGs from video cameras name only this
        text = _text(_value(exif, "Exif.Image.UniqueCameraModel"))
        if text:
            out[MODEL] = text
    for name, find in ((EXPOSURE_TIME, exiv2.exposureTime), (F_NUMBER, exiv2.fNumber)):
        datum = find(exif)
        value = datum.toFloat(0) if datum is not None and datum.count() else 0.0
        if value > 0 and value == value:
            out[name] = float(value)
    datum = exiv2.isoSpeed(exif)
    iso = _int(datum.print(exif)) if datum is not None else None
    if iso:
        out[ISO] = iso
    datum = exiv2.dateTimeOriginal(exif)
    original = _date(datum.toString()) if datum is not None else None
    changed = _date(_value(exif, "Exif.Image.DateTime"))
    if original or changed:
        out[DATE_ORIGINAL] = original or changed
        out[DATE_TIME] = original or changed
    return out


def _value(exif: Any, key: str) -> str:
    """The text of ``key`` in exiv2's ExifData, '' when absent (findKey: indexing would add it)."""
    import exiv2                 # deferred, as in read_exif
    found = exif.findKey(exiv2.ExifKey(key))
    return found.toString() if found != exif.end() else ""


def _text(value: str) -> str:
    return value.strip("\0 ").strip()


def _int(text: str) -> int | None:
    try:
        value = int(float(text.split()[0]))
    except (ValueError, IndexError):
        return None
    return value if value > 0 else None


def _date(text: str) -> str | None:
    text = _text(text)
    return text if _DATE.fullmatch(text) and not text.startswith("0000") else None


def output_attributes(raw: RawImage) -> dict[str, Any]:
    """OpenImageIO attributes of an image processed from ``raw``: the camera's EXIF (from
    ``raw.metadata['exif']``, see :func:`read_exif`), or for our simulated raws clisp as make, the
    simulated sensor as model and the simulation's settings (JSON) as the description; Orientation 1
    (the output is already upright) and clisp as the software."""
    md = raw.metadata
    attrs: dict[str, Any] = {}
    exif = md.get("exif")
    if isinstance(exif, dict):
        attrs.update({k: v for k, v in exif.items() if isinstance(v, (str, int, float))})
    else:                                                # one of our simulated raws
        attrs[MAKE], attrs[MODEL] = camera_make_model(raw)
    if "simulator" in md:
        attrs["ImageDescription"] = "clisp simulated raw: " + json.dumps(
            {k: v for k, v in md.items() if k != "opcodes"}, sort_keys=True, default=str)
    if ISO in attrs:
        attrs[ISO_SPEED] = attrs[ISO]
    attrs["Orientation"] = 1
    attrs["Software"] = f"clisp {__version__}"
    return attrs


def simulated_model_name(cfa: CFA) -> str:
    """UniqueCameraModel (and EXIF Model) of our simulated sensors.

    >>> from clisp.cfa import cfa_from_name
    >>> simulated_model_name(cfa_from_name("lms"))
    'clisp LMS simulated'
    """
    names = {"lms": "LMS", "bayer": "Bayer", "lms-bayer": "LMS-Bayer"}
    return f"clisp {names.get(cfa.kind, cfa.kind)} simulated"


def camera_make_model(raw: RawImage) -> tuple[str, str]:
    """(Make, Model) of ``raw``: a camera raw's from its EXIF (``metadata['exif']``; '' where the
    file names none), else clisp and our simulated sensor."""
    exif = raw.metadata.get("exif")
    if not isinstance(exif, dict):
        return "clisp", simulated_model_name(raw.cfa)
    return str(exif.get("Make") or ""), str(exif.get("Model") or "")
