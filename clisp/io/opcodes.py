"""DNG opcode lists (OpcodeList1, 2, 3): read, written and evaluated (issue 44).

A DNG may carry corrections as opcodes (DNG specification 1.4, chapter 6): OpcodeList1 acts on the
raw as stored, OpcodeList2 after linearisation and black subtraction (values 0..1), OpcodeList3
after the demosaic. LibRaw, and so rawpy, applies none of them; clisp reads the tags itself
(:func:`read_opcode_tags`, tifffile) and applies GainMap, FixVignetteRadial, FixBadPixelsConstant and
FixBadPixelsList (clisp.modules.sensor); any other opcode is kept as :class:`OtherOpcode` and named
once on stderr by the CLI.

Layout (big-endian throughout, whatever the TIFF's byte order)::

    list    = uint32 count, then count opcodes
    opcode  = uint32 id, uint32 DNG version (4 bytes), uint32 flags (bit 0 optional,
              bit 1 preview may skip), uint32 n, n bytes of parameters
    GainMap (id 9, 76 + 4 k bytes) = uint32 Top, Left, Bottom, Right, Plane, Planes, RowPitch,
              ColPitch, MapPointsV, MapPointsH; double MapSpacingV, MapSpacingH, MapOriginV,
              MapOriginH; uint32 MapPlanes; float MapGain[MapPointsV][MapPointsH][MapPlanes]
    FixVignetteRadial (id 3, 56 bytes) = double k0 .. k4, double OpticalCenterX, OpticalCenterY
    FixBadPixelsConstant (id 4, 8 bytes) = uint32 Constant, BayerPhase
    FixBadPixelsList (id 5) = uint32 BayerPhase, BadPointCount, BadRectCount, then per point int32
              row, column; per rectangle int32 top, left, bottom, right

GainMap semantics (as the DNG SDK's dng_gain_map interpolates): a pixel (row, col) of the opcode's
image, whose bounds are (t, l, H, W), has the relative position v = (row + 0.5 - t) / H,
h = (col + 0.5 - l) / W; its map index is ((v - MapOriginV) / MapSpacingV, (h - MapOriginH) /
MapSpacingH), clamped to the map, and its gain the bilinear interpolation of the map there. Only
the pixels in the area [Top, Bottom) x [Left, Right) on its row and column pitch are multiplied
(an empty area: the whole image). FixVignetteRadial multiplies every pixel by
``1 + k0 r^2 + k1 r^4 + ... + k4 r^10``, r the distance from the optical centre (relative
coordinates of the image) over the distance from it to the farthest corner.

Coordinates. Each opcode keeps the coordinates of its list's image; ``origin`` says where that
image's (0, 0) lies in clisp's mosaic and ``image`` its (H, W). For our DNGs both are the mosaic's;
for a camera DNG OpcodeList1 acts on the stored raw, whose (0, 0) is (-top margin, -left margin)
of the mosaic LibRaw returns (its ActiveArea), and OpcodeLists 2 and 3 on the ActiveArea itself.
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from typing import Any, Union

import numpy as np

from ..errors import ClispError, clip

TAG_OPCODE_LIST = {1: 51008, 2: 51009, 3: 51022}
"""The TIFF tags of OpcodeList1, 2 and 3 (type UNDEFINED)."""

OPCODE_NAMES = {1: "WarpRectilinear", 2: "WarpFisheye", 3: "FixVignetteRadial", 4: "FixBadPixelsConstant",
                5: "FixBadPixelsList", 6: "TrimBounds", 7: "MapTable", 8: "MapPolynomial", 9: "GainMap",
                10: "DeltaPerRow", 11: "DeltaPerColumn", 12: "ScalePerRow", 13: "ScalePerColumn",
                14: "WarpRectilinear2"}
"""Opcode ids of the DNG specification (1.4; 14 from 1.6)."""

DNG_VERSION_1_3 = bytes((1, 3, 0, 0))
"""The DNG version our writer stamps on GainMap and FixBadPixelsList (they are DNG 1.3 opcodes)."""

FLAG_OPTIONAL = 1

GAINMAP_FIXED = 76
"""Bytes of a GainMap's parameters before its gains."""


@dataclass
class GainMap:
    """A GainMap opcode (id 9). ``area`` (top, left, bottom, right) and ``row_pitch``, ``col_pitch``
    select the pixels; ``plane``, ``planes`` the planes (a CFA raw has one); ``gains`` is
    MapPointsV x MapPointsH x MapPlanes float32; ``spacing`` and ``origin`` (v, h) in relative
    coordinates of the image."""

    area: tuple[int, int, int, int]
    plane: int
    planes: int
    row_pitch: int
    col_pitch: int
    spacing: tuple[float, float]
    origin_rel: tuple[float, float]
    gains: np.ndarray
    list_no: int = 2
    flags: int = 0
    origin: tuple[int, int] = (0, 0)
    image: tuple[int, int] | None = None
    opcode_id = 9

    @property
    def name(self) -> str:
        return "GainMap"


@dataclass
class FixVignetteRadial:
    """FixVignetteRadial (id 3): gain ``1 + sum_i k[i] r^(2 i + 2)``; ``center`` (x, y) relative."""

    k: tuple[float, float, float, float, float]
    center: tuple[float, float]
    list_no: int = 3
    flags: int = 0
    origin: tuple[int, int] = (0, 0)
    image: tuple[int, int] | None = None
    opcode_id = 3

    @property
    def name(self) -> str:
        return "FixVignetteRadial"


@dataclass
class FixBadPixelsConstant:
    """FixBadPixelsConstant (id 4): every pixel whose stored value equals ``constant`` is bad."""

    constant: int
    bayer_phase: int = 0
    list_no: int = 1
    flags: int = 0
    origin: tuple[int, int] = (0, 0)
    image: tuple[int, int] | None = None
    opcode_id = 4

    @property
    def name(self) -> str:
        return "FixBadPixelsConstant"


@dataclass
class FixBadPixelsList:
    """FixBadPixelsList (id 5): ``points`` (row, col) and ``rects`` (top, left, bottom, right) are bad."""

    points: list[tuple[int, int]] = field(default_factory=list)
    rects: list[tuple[int, int, int, int]] = field(default_factory=list)
    bayer_phase: int = 0
    list_no: int = 1
    flags: int = 0
    origin: tuple[int, int] = (0, 0)
    image: tuple[int, int] | None = None
    opcode_id = 5

    @property
    def name(self) -> str:
        return "FixBadPixelsList"


@dataclass
class OtherOpcode:
    """An opcode clisp does not apply: kept (its bytes) so that it is named, and written back."""

    opcode_id: int
    params: bytes
    version: bytes = DNG_VERSION_1_3
    list_no: int = 1
    flags: int = 0
    origin: tuple[int, int] = (0, 0)
    image: tuple[int, int] | None = None

    @property
    def name(self) -> str:
        return OPCODE_NAMES.get(self.opcode_id, f"opcode {self.opcode_id}")


Opcode = Union[GainMap, FixVignetteRadial, FixBadPixelsConstant, FixBadPixelsList, OtherOpcode]


# --------------------------------------------------------------------------------------------
# Parsing and encoding
# --------------------------------------------------------------------------------------------

def parse_opcode_list(data: bytes, list_no: int, where: str = "") -> list[Opcode]:
    """The opcodes of one OpcodeList tag's bytes (big-endian). ClispError naming ``where`` for a
    list that is cut short or whose known opcodes have impossible sizes."""
    data = bytes(data)

    def bad(why: str) -> ClispError:
        return ClispError(f"{where}: corrupt DNG OpcodeList{list_no} ({why})")

    if len(data) < 4:
        raise bad("shorter than its count")
    (count,), pos, out = struct.unpack_from(">I", data, 0), 4, []
    if count > len(data) // 16:
        raise bad(f"{count} opcodes in {len(data)} bytes")
    for _ in range(count):
        if pos + 16 > len(data):
            raise bad("cut short")
        opcode_id, = struct.unpack_from(">I", data, pos)
        version = data[pos + 4:pos + 8]
        flags, size = struct.unpack_from(">II", data, pos + 8)
        pos += 16
        if pos + size > len(data):
            raise bad(f"{OPCODE_NAMES.get(opcode_id, opcode_id)} needs {size} bytes")
        params = data[pos:pos + size]
        pos += size
        try:
            op = _parse_params(opcode_id, params, version)
        except (struct.error, ValueError) as exc:
            raise bad(f"{OPCODE_NAMES.get(opcode_id, opcode_id)}: {clip(exc, 40)}") from exc
        op.list_no, op.flags = list_no, flags
        out.append(op)
    return out


def _parse_params(opcode_id: int, p: bytes, version: bytes) -> Opcode:
    if opcode_id == 9:
        if len(p) < GAINMAP_FIXED:
            raise ValueError(f"{len(p)} bytes")
        top, left, bottom, right, plane, planes, rp, cp, pv, ph = struct.unpack_from(">10I", p, 0)
        sv, sh, ov, oh = struct.unpack_from(">4d", p, 40)
        mp, = struct.unpack_from(">I", p, 72)
        n = pv * ph * mp
        if min(pv, ph, mp) < 1 or len(p) != GAINMAP_FIXED + 4 * n:
            raise ValueError(f"{pv}x{ph}x{mp} points in {len(p)} bytes")
        if pv == 1:                               # as the DNG SDK: a single row or column spans all
            sv, ov = 1.0, 0.0
        if ph == 1:
            sh, oh = 1.0, 0.0
        if not (sv > 0 and sh > 0) or not all(math.isfinite(v) for v in (sv, sh, ov, oh)):
            raise ValueError("map spacing must be positive")
        gains = np.frombuffer(p, dtype=">f4", count=n, offset=GAINMAP_FIXED).astype(np.float32).reshape(pv, ph, mp)
        return GainMap((top, left, bottom, right), plane, planes, max(1, rp), max(1, cp), (sv, sh), (ov, oh), gains)
    if opcode_id == 3:
        if len(p) != 56:
            raise ValueError(f"{len(p)} bytes")
        values = struct.unpack(">7d", p)
        if not all(math.isfinite(v) for v in values) or not (0 <= values[5] <= 1 and 0 <= values[6] <= 1):
            raise ValueError("coefficients or centre out of range")
        return FixVignetteRadial(tuple(values[:5]), (values[5], values[6]))      # type: ignore[arg-type]
    if opcode_id == 4:
        if len(p) != 8:
            raise ValueError(f"{len(p)} bytes")
        constant, phase = struct.unpack(">II", p)
        return FixBadPixelsConstant(constant, phase)
    if opcode_id == 5:
        phase, npts, nrects = struct.unpack_from(">III", p, 0)
        if len(p) != 12 + 8 * npts + 16 * nrects:
            raise ValueError(f"{npts} points and {nrects} rectangles in {len(p)} bytes")
        pts = np.frombuffer(p, dtype=">i4", count=2 * npts, offset=12).reshape(-1, 2)
        rects = np.frombuffer(p, dtype=">i4", count=4 * nrects, offset=12 + 8 * npts).reshape(-1, 4)
        return FixBadPixelsList([tuple(int(v) for v in r) for r in pts],          # type: ignore[misc]
                                [tuple(int(v) for v in r) for r in rects], phase)  # type: ignore[misc]
    return OtherOpcode(opcode_id, bytes(p), bytes(version))


def encode_opcode_list(ops: list[Opcode]) -> bytes:
    """One OpcodeList tag's bytes (big-endian) for ``ops`` (the inverse of :func:`parse_opcode_list`)."""
    out = [struct.pack(">I", len(ops))]
    for op in ops:
        params, version = _encode_params(op)
        out.append(struct.pack(">I", op.opcode_id) + version + struct.pack(">II", op.flags, len(params)) + params)
    return b"".join(out)


def _encode_params(op: Opcode) -> tuple[bytes, bytes]:
    if isinstance(op, GainMap):
        pv, ph, mp = op.gains.shape
        head = struct.pack(">10I", *op.area, op.plane, op.planes, op.row_pitch, op.col_pitch, pv, ph)
        head += struct.pack(">4d", *op.spacing, *op.origin_rel) + struct.pack(">I", mp)
        return head + np.ascontiguousarray(op.gains, dtype=">f4").tobytes(), DNG_VERSION_1_3
    if isinstance(op, FixVignetteRadial):
        return struct.pack(">7d", *op.k, *op.center), DNG_VERSION_1_3
    if isinstance(op, FixBadPixelsConstant):
        return struct.pack(">II", op.constant, op.bayer_phase), DNG_VERSION_1_3
    if isinstance(op, FixBadPixelsList):
        body = struct.pack(">III", op.bayer_phase, len(op.points), len(op.rects))
        body += np.asarray(op.points, dtype=">i4").reshape(-1).tobytes()
        body += np.asarray(op.rects, dtype=">i4").reshape(-1).tobytes()
        return body, DNG_VERSION_1_3
    return op.params, op.version


def read_opcode_tags(page: Any, where: str, origin1: tuple[int, int] = (0, 0),
                     image1: tuple[int, int] | None = None,
                     image23: tuple[int, int] | None = None) -> list[Opcode]:
    """The opcodes of a tifffile page's OpcodeList1-3 tags, placed on clisp's mosaic: list 1's image
    starts at ``origin1`` of the mosaic and is ``image1`` (H, W) large (the stored raw), lists 2 and 3
    act on the mosaic itself (``image23``)."""
    ops: list[Opcode] = []
    for list_no, code in TAG_OPCODE_LIST.items():
        tag = page.tags.get(code)
        if tag is None:
            continue
        value = tag.value
        blob = bytes(value) if not isinstance(value, bytes) else value
        for op in parse_opcode_list(blob, list_no, where):
            op.origin = origin1 if list_no == 1 else (0, 0)
            op.image = image1 if list_no == 1 else image23
            ops.append(op)
    return ops


def opcode_tags(ops: list[Opcode]) -> list[tuple[int, int, int, bytes, bool]]:
    """tifffile ``extratags`` for ``ops`` (type UNDEFINED, 7), one tag per list that has opcodes."""
    tags = []
    for list_no, code in TAG_OPCODE_LIST.items():
        mine = [op for op in ops if op.list_no == list_no]
        if mine:
            blob = encode_opcode_list(mine)
            tags.append((code, 7, len(blob), blob, True))
    return tags


def unapplied(ops: list[Opcode]) -> list[str]:
    """'Name (OpcodeListN)' of each opcode clisp does not apply, once each, in order."""
    seen: list[str] = []
    for op in ops:
        if isinstance(op, OtherOpcode):
            text = f"{op.name} (OpcodeList{op.list_no}{', optional' if op.flags & FLAG_OPTIONAL else ''})"
            if text not in seen:
                seen.append(text)
    return seen


# --------------------------------------------------------------------------------------------
# Metadata round trip (RawImage.metadata['opcodes'], JSON)
# --------------------------------------------------------------------------------------------

def to_json(op: Opcode) -> dict[str, Any]:
    """A JSON-ready description of ``op`` (its parameters and placement)."""
    base = {"id": op.opcode_id, "list": op.list_no, "flags": op.flags, "origin": list(op.origin),
            "image": None if op.image is None else list(op.image)}
    params, version = _encode_params(op)
    return {**base, "params": params.hex(), "version": version.hex()}


def from_json(d: dict[str, Any]) -> Opcode:
    """The opcode :func:`to_json` described (ClispError on a malformed description)."""
    try:
        op = _parse_params(int(d["id"]), bytes.fromhex(d["params"]), bytes.fromhex(d.get("version", "01030000")))
        op.list_no, op.flags = int(d["list"]), int(d.get("flags", 0))
        op.origin = tuple(int(v) for v in d.get("origin", (0, 0)))               # type: ignore[assignment]
        image = d.get("image")
        op.image = None if image is None else tuple(int(v) for v in image)        # type: ignore[assignment]
    except (KeyError, TypeError, ValueError, struct.error) as exc:
        raise ClispError(f"corrupt opcode description ({clip(exc, 40)})") from exc
    return op


def opcodes_of(metadata: dict[str, Any]) -> list[Opcode]:
    """The opcodes a RawImage's metadata carries (``metadata['opcodes']``: objects or JSON dicts)."""
    return [op if not isinstance(op, dict) else from_json(op) for op in metadata.get("opcodes") or []]


# --------------------------------------------------------------------------------------------
# Evaluation (the reference: float64)
# --------------------------------------------------------------------------------------------

def selects(op: GainMap, ys: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """Which mosaic pixels (ys, xs broadcast) ``op`` multiplies: inside its area, on its pitch."""
    oy, ox = op.origin
    r, c = np.asarray(ys) - oy, np.asarray(xs) - ox
    t, l, b, rt = op.area
    if b <= t or rt <= l:                        # an empty area covers the whole image
        return np.ones(np.broadcast(r, c).shape, dtype=bool)
    return (r >= t) & (r < b) & (c >= l) & (c < rt) & ((r - t) % op.row_pitch == 0) & ((c - l) % op.col_pitch == 0)


def gain_map_at(op: GainMap, ys: np.ndarray, xs: np.ndarray, plane: int = 0) -> np.ndarray:
    """The gain of ``op``'s map at mosaic pixels (ys, xs), whether or not it selects them (the
    DNG SDK's interpolation: relative pixel centres, clamped index, bilinear)."""
    oy, ox = op.origin
    height, width = op.image
    pv, ph, mp = op.gains.shape
    g = op.gains[:, :, min(plane, mp - 1)].astype(np.float64)
    v = ((np.asarray(ys, dtype=np.float64) - oy + 0.5) / height - op.origin_rel[0]) / op.spacing[0]
    h = ((np.asarray(xs, dtype=np.float64) - ox + 0.5) / width - op.origin_rel[1]) / op.spacing[1]
    v, h = np.clip(v, 0.0, pv - 1), np.clip(h, 0.0, ph - 1)
    i0, j0 = np.minimum(np.floor(v).astype(np.int64), max(pv - 2, 0)), np.minimum(np.floor(h).astype(np.int64), max(ph - 2, 0))
    i1, j1 = np.minimum(i0 + 1, pv - 1), np.minimum(j0 + 1, ph - 1)
    fv, fh = v - i0, h - j0
    top = g[i0, j0] * (1 - fh) + g[i0, j1] * fh
    bottom = g[i1, j0] * (1 - fh) + g[i1, j1] * fh
    return top * (1 - fv) + bottom * fv


def vignette_at(op: FixVignetteRadial, ys: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """FixVignetteRadial's gain at mosaic pixels (ys, xs)."""
    oy, ox = op.origin
    height, width = op.image
    cy, cx = op.center[1] * height, op.center[0] * width
    rmax2 = max(cy, height - cy) ** 2 + max(cx, width - cx) ** 2
    r2 = ((np.asarray(ys, dtype=np.float64) - oy + 0.5 - cy) ** 2
          + (np.asarray(xs, dtype=np.float64) - ox + 0.5 - cx) ** 2) / max(rmax2, 1e-12)
    out = np.zeros_like(r2)
    for k in reversed(op.k):                     # Horner in r^2
        out = r2 * (k + out)
    return 1.0 + out


def bad_pixel_mask(ops: list[Opcode], raw_data: np.ndarray, shape: tuple[int, int]) -> np.ndarray | None:
    """H x W bool of the pixels the FixBadPixels opcodes name (None when there are none):
    FixBadPixelsList's points and rectangles, and FixBadPixelsConstant's pixels whose stored value
    equals its constant (``raw_data``, the mosaic as stored)."""
    lists = [op for op in ops if isinstance(op, (FixBadPixelsList, FixBadPixelsConstant))]
    if not lists:
        return None
    mask = np.zeros(shape, dtype=bool)
    height, width = shape
    for op in lists:
        oy, ox = op.origin
        if isinstance(op, FixBadPixelsConstant):
            for y in range(0, height, 1024):                    # row bands: a memory-mapped raw stays on disk
                mask[y:y + 1024] |= np.asarray(raw_data[y:y + 1024]) == op.constant
            continue
        if op.points:
            pts = np.asarray(op.points, dtype=np.int64) + (oy, ox)
            keep = (pts[:, 0] >= 0) & (pts[:, 0] < height) & (pts[:, 1] >= 0) & (pts[:, 1] < width)
            mask[pts[keep, 0], pts[keep, 1]] = True
        for t, l, b, r in op.rects:
            mask[max(t + oy, 0):max(b + oy, 0), max(l + ox, 0):max(r + ox, 0)] = True
    return mask
