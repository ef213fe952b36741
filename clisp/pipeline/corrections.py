"""The sensor corrections a pipeline applies to one raw (issue 44): what ``--bad-pixels``, ``--dark``,
``--flat`` and the DNG's opcodes ask for, built into the stages of clisp.modules.sensor.

:func:`sensor_corrections` gathers, in the DNG's order:

* **bad pixels** (``bad_pixels``): 'auto' (the default) searches them against the raw's noise model
  on the device, fused into the first pass over the mosaic (SensorCorrect), and also uses every
  list the raw and the frames give (the DNG's FixBadPixelsList / FixBadPixelsConstant; pixels the
  dark frame shows saturating, DARK_BAD of the range; pixels the flat shows dead or wild); a path
  is a map file used as given, with those lists and without the search (dcraw's format: ``column
  row`` per line, ``#`` comments, further columns ignored; coordinates of the mosaic ``clisp info``
  describes); 'off' corrects none, not even the DNG's lists.
* **dark frame** (``dark``: paths, one or several, averaged; each read once a process: the next
  input of the same size, CFA and levels reuses the average while the files are unchanged): the
  per-pixel dark level replaces the black level; scaled by the exposure times when both raws state
  them; refused (one line naming both files) unless size, CFA, black and white levels match the
  raw's.
* **flat field** (``flat``: paths, averaged): each less its black level, normalised per channel to
  its brightest region (FLAT_BLOCK px blocks: the optical centre gets gain 1, as a GainMap's), the
  raw multiplied by its inverse, unsmoothed (so it also removes PRNU); size and CFA must match.
* **DNG opcodes** (``opcodes``): GainMap and FixVignetteRadial of OpcodeLists 1 and 2 on the
  mosaic, of OpcodeList3 with the smooth gain after the chroma stage; any other opcode is listed
  in :attr:`Corrections.unapplied` (the CLI names it once on stderr).

A raw that needs none of it gets the auto search only (nothing else is built), and with
``bad_pixels='off'`` nothing at all.
"""
from __future__ import annotations

import math
import os
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Sequence

import numpy as np

from ..errors import ClispError, clip
from ..io.rawimage import RawImage
from ..sim.noise import ChannelNoise, NoiseModel
# clisp.io.opcodes and clisp.modules.sensor.stage are imported where they are used: a raw that needs
# no correction (the fast preset's, --bad-pixels off, no opcode, no frame) loads neither (start-up)
if TYPE_CHECKING:
    from ..modules.sensor.stage import DefectTest, GainTerms, SensorCorrect, SensorShade, SmoothGain
from ..io.rawfile import read_raw
from ..modules.highlights.stage import clip_thresholds_dn

BAD_PIXEL_MODES = ("auto", "off")
"""``--bad-pixels`` keywords; anything else is a map file."""

DARK_BAD = 0.5
"""A pixel whose dark level takes more than this share of the range is listed bad (it saturates early)."""

FLAT_BLOCK = 32
"""Side (px) of the blocks whose per-channel means normalise a flat frame (the brightest is the centre)."""

FLAT_DARK = 0.05
"""A flat pixel reading less than this share of its channel's brightest region is dead (no lens
shades a corner that far)."""

FLAT_WILD = 4.0
"""A pixel whose flat-field gain differs from its region's by more than this factor either way is
listed bad (a dead pixel reads no light in the flat) and gets its region's gain."""

FALLBACK_ELECTRONS = 2000.0
"""Electrons at white of the noise model the auto search assumes for a raw that has none and whose
noise is not estimated (the fast preset on a camera raw): a noisy small-pixel sensor, so the
search errs towards finding fewer pixels, never false ones (tools/bench_sensor.py)."""

FALLBACK_FLOOR = 1e-6
"""Variance floor (normalised units, about 16 DN of a 14-bit raw) of that assumed model."""

ROWS = 512
"""Rows of a frame read at a time while averaging (a memory-mapped frame stays on disk)."""


@dataclass
class Corrections:
    """What :func:`sensor_corrections` built for one raw."""

    pre: SensorCorrect | None = None
    smooth: SmoothGain | None = None
    notes: list[str] = field(default_factory=list)
    unapplied: list[str] = field(default_factory=list)
    added_floor: np.ndarray | None = None
    """Variance (white-balanced units, per channel) the corrections add to the raw's noise floor:
    the averaged dark frame's own noise."""

    def shade(self, colour_matrix: np.ndarray, scale: int = 1) -> SensorShade | None:
        """The stage after the chroma stage that applies the smooth gain (None: there is none)."""
        if self.smooth is None:
            return None
        from ..modules.sensor.stage import SensorShade   # deferred: only raws that get a sensor correction load the stage (start-up)
        return SensorShade(self.smooth, colour_matrix, scale)

    def noise(self, noise: Any) -> Any:
        """``noise`` (ChannelNoise) as the corrected raw has it: the dark frame's noise added."""
        if noise is None or self.added_floor is None or getattr(noise, "is_zero", False):
            return noise
        floor = tuple(float(f + a) for f, a in zip(noise.floor, self.added_floor))
        return ChannelNoise(tuple(noise.shot), floor, noise.source)

    def explain(self, stats: Any = None) -> str:
        """``--explain``'s lines: what each correction did (after the run, ``stats`` its RunStats:
        how many pixels the auto test found in it; none on the reference backend)."""
        lines = [f"sensor: {note}" for note in self.notes] or ["sensor: no corrections (--bad-pixels off, no frames)"]
        if self.pre is not None and self.pre.test is not None and stats is not None:
            from ..modules.sensor.stage import FOUND   # deferred: only raws that get a sensor correction load the stage (start-up)
            found = getattr(stats, "counts", {}).get(FOUND)
            if found is not None:
                lines.append(f"sensor: the auto test found and replaced {found} pixels")
        if self.unapplied:
            lines.append(f"sensor: DNG opcodes not applied: {', '.join(self.unapplied)}")
        return "\n".join(lines)


def sensor_corrections(raw: RawImage, bad_pixels: Any = "auto", dark: Sequence[Any] = (),
                       flat: Sequence[Any] = (), opcodes: bool = True, noise: Any = None) -> Corrections:
    """The corrections for ``raw`` (module doc). ``bad_pixels``: also an H x W bool array, a map.
    ``dark``, ``flat``: paths of raw files, or RawImages. ``noise``: the raw's ChannelNoise where the caller has it (build_pipeline's, for the
    denoiser), else the sensor model of the metadata, else the assumed model FALLBACK_ELECTRONS.
    ClispError (one line naming the files) for frames that do not match the raw, an unreadable map,
    or frames without light."""
    out = Corrections()
    out.added_floor = dark_shot_floor(raw)
    has_ops = opcodes and bool(raw.metadata.get("opcodes") or raw.metadata.get("opcodes_unreadable"))
    if isinstance(bad_pixels, str) and bad_pixels == "off" and not dark and not flat and not has_ops:
        return out                                          # nothing to build
    from ..modules.sensor.stage import GainTerms, SensorCorrect, SmoothGain
    shape, cfa = raw.shape, raw.cfa
    ops: list[Any] = []
    if has_ops:                                             # clisp.io.opcodes only for a raw that has some
        from ..io.opcodes import opcodes_of, unapplied
        ops = opcodes_of(raw.metadata)
        out.unapplied = unapplied(ops)
    if raw.metadata.get("opcodes_unreadable") and opcodes:
        out.unapplied.append(f"all ({raw.metadata['opcodes_unreadable']})")
    mask: np.ndarray | None = None                          # the known bad pixels (none: no H x W pass)
    known: list[str] = []
    if isinstance(bad_pixels, np.ndarray):                  # a map given as an H x W bool array
        mask = _union(mask, bad_pixels, shape)
        known.append(f"{int(mask.sum())} from the map")
        bad_pixels = "map"
    elif bad_pixels not in BAD_PIXEL_MODES:
        listed = read_bad_pixel_map(bad_pixels, shape)
        mask = _union(mask, listed, shape)
        known.append(f"{int(listed.sum())} from {Path(bad_pixels).name}")
    if bad_pixels != "off" and ops:
        from ..io.opcodes import bad_pixel_mask   # deferred: only raws with DNG opcodes load clisp.io.opcodes (start-up)
        dng = bad_pixel_mask(ops, raw.data, shape)
        if dng is not None:
            mask = _union(mask, dng, shape)
            known.append(f"{int(dng.sum())} from the DNG's FixBadPixels opcodes")
    dark_level = None
    if dark:
        dark_level, frames_note, dark_n = _once(dark_master, raw, list(dark), "dark")
        out.notes.append(frames_note)
        if bad_pixels != "off":
            hot = dark_level - raw.black_level[cfa.channel_map(*shape)] > DARK_BAD * (raw.white_level - raw.black_level.max())
            if hot.any():
                mask = _union(mask, hot, shape)
                known.append(f"{int(hot.sum())} saturating in the dark frame")
        base = _noise_of(raw, noise)
        if base is not None:
            added = np.asarray(base.floor) / dark_n
            out.added_floor = added if out.added_floor is None else out.added_floor + added
    flat_gain, flat_smooth = None, None
    if flat:
        flat_gain, wild, flat_smooth, note = _once(flat_master, raw, list(flat), "flat")
        out.notes.append(note)
        if bad_pixels != "off" and wild.any():
            mask = _union(mask, wild, shape)
            known.append(f"{int(wild.sum())} dead or wild in the flat")
    gains: list[Any] = []
    if ops:
        from ..io.opcodes import FixVignetteRadial, GainMap   # deferred: only raws with DNG opcodes load clisp.io.opcodes (start-up)
        gains = [op for op in ops if isinstance(op, (GainMap, FixVignetteRadial))]
    if flat and gains:                       # the flat measured the same lens: it replaces them
        out.notes.append(f"the flat replaces the DNG's {len(gains)} gain opcodes (the same lens shading)")
        gains = []
    pre_terms = [op for op in gains if op.list_no in (1, 2) and _applies_to_mosaic(op)]
    post_terms = [op for op in gains if op.list_no == 3]
    skipped = [op for op in gains if op not in pre_terms and op not in post_terms]
    out.unapplied += [f"{op.name} (OpcodeList{op.list_no}, plane {getattr(op, 'plane', 0)})" for op in skipped]
    if gains and len(skipped) < len(gains):
        counts: dict[str, int] = {}
        for op in pre_terms + post_terms:
            key = f"{op.name} (OpcodeList{op.list_no})"
            counts[key] = counts.get(key, 0) + 1
        out.notes.append("DNG opcodes applied: " + ", ".join(f"{k} x{v}" if v > 1 else k for k, v in counts.items()))
    terms = GainTerms(pre_terms) if pre_terms else None
    if terms is not None or post_terms or flat_smooth is not None:
        pre_grid = smooth_grid(raw, terms, flat_smooth)
        post_grid = pre_grid * _list3_grid(raw, post_terms) if post_terms else pre_grid
        out.smooth = SmoothGain(post_grid.astype(np.float32))
        pre_smooth = SmoothGain(pre_grid.astype(np.float32))
    else:
        pre_smooth = None
    test = None
    known_text = f" ({', '.join(known)})" if known else ""
    if bad_pixels == "auto":
        test, how = defect_test(raw, out.noise(_noise_of(raw, noise)))
        out.notes.insert(0, f"bad pixels auto, searched against the noise model ({how}); listed{known_text or ': none'}")
    elif bad_pixels != "off":
        out.notes.insert(0, f"bad pixels from the map, no search{known_text}")
    if mask is not None and not mask.any():
        mask = None
    if test is None and mask is None and dark_level is None and flat_gain is None and terms is None \
            and pre_smooth is None:
        return out
    out.pre = SensorCorrect(cfa, raw.black_level, raw.white_level, test,
                            None if mask is None else mask.astype(np.uint16),
                            None if dark_level is None else dark_level.astype(np.float32),
                            None if flat_gain is None else flat_gain.astype(np.float32),
                            terms, pre_smooth, wb=tuple(float(v) for v in raw.pass1_gains()))
    return out


def _union(mask: np.ndarray | None, more: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """``mask | more`` as a new H x W (``shape``) bool array, ``more`` alone where there is no mask
    yet (a raw without maps, frames or opcodes makes no H x W array: 2 + 2 ms of host time at 24
    MP). ClispError for a map of another shape."""
    more = np.asarray(more, dtype=bool)
    if more.shape != tuple(shape):
        size = f"{more.shape[1]}x{more.shape[0]}" if more.ndim == 2 else f"shape {more.shape}"
        raise ClispError(f"a bad pixel map of {size} for a raw of {shape[1]}x{shape[0]}")
    return more if mask is None else mask | more          # never changed in place: no copy


def _applies_to_mosaic(op: Any) -> bool:
    """A gain opcode of OpcodeList1 or 2 acts on the CFA mosaic's one plane."""
    from ..io.opcodes import GainMap   # deferred: only raws with DNG opcodes load clisp.io.opcodes (start-up)
    return not isinstance(op, GainMap) or op.plane == 0


def dark_shot_floor(raw: RawImage) -> np.ndarray | None:
    """The variance (white-balanced units, per channel) a simulated sensor's mean dark current adds
    to the raw's noise (its shot noise), which the sensor model in the metadata leaves out; None for
    other raws (a camera raw's noise is estimated from its data, dark current included)."""
    md = raw.metadata or {}
    sensor, gain = md.get("sensor"), md.get("gain")
    if not isinstance(sensor, dict) or gain is None or not sensor.get("dark_current"):
        return None
    n_fs = NoiseModel.from_dict(md.get("noise") or {}).full_scale_electrons(float(gain))
    electrons = float(sensor["dark_current"]) * float(sensor.get("exposure_time", 0.0))
    w = raw.pass1_gains()
    return w * w * electrons / (n_fs * n_fs)


def _noise_of(raw: RawImage, noise: Any) -> Any:
    """The raw's ChannelNoise: ``noise`` as given, else its sensor model (None without one)."""
    if noise is not None:
        return noise
    md = raw.metadata or {}
    if "noise" in md and "gain" in md:
        from ..scene.noise import raw_noise          # deferred: only for raws that carry a model
        return raw_noise(raw, estimate=False)
    return None


def defect_test(raw: RawImage, noise: Any = None) -> tuple[DefectTest, str]:
    """The auto search's model for ``raw`` and where it came from."""
    from ..modules.sensor.stage import DefectTest   # deferred: only raws that get a sensor correction load the stage (start-up)
    model = _noise_of(raw, noise)
    gains = raw.pass1_gains()
    if model is not None:
        source = getattr(model, "source", "model")
        if not getattr(model, "is_zero", False):
            return DefectTest.from_noise(model, gains), {"model": "the sensor model", "estimate": "estimated from the raw"}.get(source, source)
    n = raw.cfa.n_channels
    what = "noiseless" if model is not None else "none in the raw"
    return (DefectTest((1.0 / FALLBACK_ELECTRONS,) * n, (FALLBACK_FLOOR,) * n, tuple(float(v) for v in gains)),
            f"{what}, a {FALLBACK_ELECTRONS:g} e- sensor assumed")


# --------------------------------------------------------------------------------------------
# Frames
# --------------------------------------------------------------------------------------------

def exposure_time(raw: RawImage) -> float | None:
    """The raw's exposure time in seconds (a camera's EXIF, a simulation's sensor), or None."""
    md = raw.metadata or {}
    for value in ((md.get("exif") or {}).get("ExposureTime"), (md.get("sensor") or {}).get("exposure_time")):
        try:
            t = float(value)
        except (TypeError, ValueError):
            continue
        if math.isfinite(t) and t > 0:
            return t
    return None


def _mismatch(frame: RawImage, raw: RawImage, levels: bool) -> str | None:
    """What differs between ``frame`` and ``raw`` (size, CFA, and with ``levels`` black and white)."""
    if frame.shape != raw.shape:
        return f"size {frame.shape[1]}x{frame.shape[0]}, the raw's {raw.shape[1]}x{raw.shape[0]}"
    if frame.cfa.name != raw.cfa.name or not np.array_equal(frame.cfa.pattern, raw.cfa.pattern):
        return f"CFA {frame.cfa.name}, the raw's {raw.cfa.name}"
    if levels and (not np.allclose(frame.black_level, raw.black_level, rtol=0, atol=0.5)
                   or abs(frame.white_level - raw.white_level) > 0.5):
        return (f"black {_levels(frame.black_level)} and white {frame.white_level:g}, the raw's "
                f"{_levels(raw.black_level)} and {raw.white_level:g}")
    return None


def _levels(black: np.ndarray) -> str:
    values = sorted(set(float(v) for v in black))
    return "/".join(f"{v:g}" for v in values)


def _frames(raw: RawImage, paths: list[Any], what: str, levels: bool) -> list[RawImage]:
    """The frames at ``paths`` (read lazily; RawImages as they are), each checked against the raw
    (refused in one line naming both files)."""
    frames = []
    for path in paths:
        frame = path if isinstance(path, RawImage) else read_raw(path, lazy=True)
        problem = _mismatch(frame, raw, levels)
        if problem:
            raise ClispError(f"{path}: {what} frame does not match {raw.source}: {problem}")
        frames.append(frame)
    return frames


_MASTERS: dict[str, tuple[Any, Any]] = {}
"""The last dark and flat master made in this process ('dark', 'flat': (key, master)): the inputs of
one ``clisp process`` share their frames, which are read and averaged once (24 MP: about 1 s and
200 MB a kind, so one of each is kept)."""

_MASTERS_LOCK = threading.Lock()


def _frames_key(raw: RawImage, paths: list[Any], what: str) -> tuple[Any, ...] | None:
    """What a master of the frame files ``paths`` for ``raw`` depends on: each file (its resolved
    path, modification time and size) and what of the raw enters (size, CFA, levels and, for a
    dark frame, its exposure time); None for frames given as RawImages (not cached)."""
    try:
        files = tuple((str(Path(p).resolve()), st.st_mtime_ns, st.st_size)
                      for p in paths for st in (os.stat(p),))
    except (TypeError, OSError):
        return None
    return (what, files, raw.shape, raw.cfa.name, raw.cfa.pattern.tobytes(),
            np.asarray(raw.black_level, dtype=np.float64).tobytes(), float(raw.white_level),
            exposure_time(raw) if what == "dark" else None)


def _once(make: Any, raw: RawImage, paths: list[Any], what: str) -> Any:
    """``make(raw, paths)`` (dark_master, flat_master), or the master it made before in this process
    for the same files, unchanged on disk, and a raw of the same size, CFA, levels (and exposure
    time). The master's arrays are shared: not to be written."""
    key = _frames_key(raw, paths, what)
    with _MASTERS_LOCK:
        kept = _MASTERS.get(what)
    if key is not None and kept is not None and kept[0] == key:
        return kept[1]
    master = make(raw, paths)
    if key is not None:
        for value in master:
            if isinstance(value, np.ndarray):
                value.setflags(write=False)
        with _MASTERS_LOCK:
            _MASTERS[what] = (key, master)
    return master


def dark_master(raw: RawImage, paths: list[str]) -> tuple[np.ndarray, str, int]:
    """(H x W dark level in DN for ``raw``: the frames averaged, each scaled to the raw's exposure
    time when both state theirs; a note for --explain; the number of frames)."""
    frames = _frames(raw, paths, "dark", levels=True)
    t_raw = exposure_time(raw)
    ch = raw.cfa.channel_map(*raw.shape)
    black = raw.black_level[ch]
    total = np.zeros(raw.shape)
    scaled = 0
    for frame in frames:
        t = exposure_time(frame)
        factor = t_raw / t if (t_raw and t) else 1.0
        scaled += bool(t_raw and t)
        for y in range(0, raw.shape[0], ROWS):
            rows = np.asarray(frame.data[y:y + ROWS], dtype=np.float64)
            total[y:y + ROWS] += (rows - black[y:y + ROWS]) * factor
    level = black + total / len(frames)
    how = ("scaled by the exposure times" if scaled == len(frames) else
           "not scaled (exposure time unknown)" if not scaled else "partly scaled by exposure time")
    return level, f"dark: {len(frames)} frame{'s' if len(frames) > 1 else ''} averaged, {how}", len(frames)


def flat_master(raw: RawImage, paths: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray, str]:
    """(H x W flat-field gain, H x W bool of wild pixels, the gain's per-channel smooth part at the
    grid's nodes (C x GH x GW), a note) from the flat frames at ``paths``."""
    from ..modules.sensor.stage import GRID_CELL, SmoothGain   # deferred: only raws that get a sensor correction load the stage (start-up)
    frames = _frames(raw, paths, "flat", levels=False)
    shape, cfa = raw.shape, raw.cfa
    ch = cfa.channel_map(*shape)
    total = np.zeros(shape)
    for frame in frames:
        black = frame.black_level[ch]
        for y in range(0, shape[0], ROWS):
            total[y:y + ROWS] += np.asarray(frame.data[y:y + ROWS], dtype=np.float64) - black[y:y + ROWS]
    mean = total / len(frames)
    gain = np.ones(shape)
    level = np.zeros(cfa.n_channels)
    for c in range(cfa.n_channels):
        sel = ch == c
        level[c] = _brightest_block(mean, sel)
        if not level[c] > 0.01 * (raw.white_level - raw.black_level[c]):
            raise ClispError(f"{paths[0]}: flat frame has no light in channel {cfa.channels[c]} "
                             f"(its brightest region reads {level[c]:.3g} DN above black)")
    lit = mean > FLAT_DARK * level[ch]                      # a dead pixel reads (almost) no light
    with np.errstate(divide="ignore", invalid="ignore"):
        gain = np.where(lit, level[ch] / np.where(lit, mean, 1.0), np.inf)
    region = local_channel_mean(np.where(lit, gain, 0.0), lit, ch, cfa.n_channels, FLAT_BLOCK)
    wild = ~lit | (gain > FLAT_WILD * region) | (gain * FLAT_WILD < region)
    gain = np.where(wild, region, gain)
    nodes = SmoothGain.nodes(shape)
    smooth = np.stack([_node_means(gain, ch == c, nodes, GRID_CELL) for c in range(cfa.n_channels)])
    note = (f"flat: {len(frames)} frame{'s' if len(frames) > 1 else ''} averaged, gains "
            f"{float(np.min(gain)):.2f}..{float(np.max(gain)):.2f}")
    return gain, wild, smooth, note


def _brightest_block(values: np.ndarray, sel: np.ndarray) -> float:
    """The largest mean of ``values`` over ``sel`` in FLAT_BLOCK x FLAT_BLOCK blocks."""
    h, w = values.shape
    b = FLAT_BLOCK
    hb, wb = max(1, h // b), max(1, w // b)
    v = np.where(sel, values, 0.0)[:hb * b, :wb * b].reshape(hb, b, wb, b).sum(axis=(1, 3))
    n = sel[:hb * b, :wb * b].reshape(hb, b, wb, b).sum(axis=(1, 3))
    with np.errstate(invalid="ignore", divide="ignore"):
        means = np.where(n > 0, v / np.maximum(n, 1), -np.inf)
    return float(means.max())


def _box_sum(a: np.ndarray, r: int) -> np.ndarray:
    """Sums of ``a`` over the (2r+1)^2 box around each pixel (clipped at the edges)."""
    s = np.pad(np.cumsum(np.cumsum(a, axis=0), axis=1), ((1, 0), (1, 0)))
    h, w = a.shape
    y0, y1 = np.clip(np.arange(h) - r, 0, h), np.clip(np.arange(h) + r + 1, 0, h)
    x0, x1 = np.clip(np.arange(w) - r, 0, w), np.clip(np.arange(w) + r + 1, 0, w)
    return s[y1][:, x1] - s[y0][:, x1] - s[y1][:, x0] + s[y0][:, x0]


def local_channel_mean(values: np.ndarray, valid: np.ndarray, ch: np.ndarray, n: int, size: int) -> np.ndarray:
    """Per pixel, the mean of ``values`` over the valid pixels of its own channel in a ``size`` box."""
    out = np.ones(values.shape)
    r = size // 2
    for c in range(n):
        sel = (ch == c) & valid
        num, den = _box_sum(np.where(sel, values, 0.0), r), _box_sum(sel.astype(np.float64), r)
        with np.errstate(invalid="ignore", divide="ignore"):
            out = np.where(ch == c, np.where(den > 0, num / np.maximum(den, 1), 1.0), out)
    return out


def _node_means(values: np.ndarray, sel: np.ndarray, nodes: tuple[np.ndarray, np.ndarray], cell: int) -> np.ndarray:
    """Mean of ``values`` over ``sel`` in the 2 cell x 2 cell box around each grid node."""
    num, den = _box_sum(np.where(sel, values, 0.0), cell), _box_sum(sel.astype(np.float64), cell)
    ys = np.minimum(nodes[0], values.shape[0] - 1)
    xs = np.minimum(nodes[1], values.shape[1] - 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(den[np.ix_(ys, xs)] > 0, num[np.ix_(ys, xs)] / np.maximum(den[np.ix_(ys, xs)], 1), 1.0)


# --------------------------------------------------------------------------------------------
# The smooth gain
# --------------------------------------------------------------------------------------------

def smooth_grid(raw: RawImage, terms: GainTerms | None, flat_smooth: np.ndarray | None) -> np.ndarray:
    """G at the grid's nodes, C x GH x GW float64: per channel, the mean over the CFA phases of that
    channel of the OpcodeList1 / 2 gains at the node's nearest site of the phase, times the flat's
    smooth part. SensorCorrect divides it out of the mosaic; SensorShade applies it after the chroma
    stage."""
    from ..modules.sensor.stage import SmoothGain   # deferred: only raws that get a sensor correction load the stage (start-up)
    shape, cfa = raw.shape, raw.cfa
    ny, nx = SmoothGain.nodes(shape)
    p = cfa.period
    out = np.zeros((cfa.n_channels, len(ny), len(nx)))
    count = np.zeros(cfa.n_channels)
    for ky in range(p):
        for kx in range(p):
            c = int(cfa.pattern[ky, kx])
            ys, xs = ny + (ky - ny) % p, nx + (kx - nx) % p          # the node's site of this phase
            ys, xs = np.where(ys >= shape[0], ys - p, ys), np.where(xs >= shape[1], xs - p, xs)
            g = np.ones((len(ny), len(nx)))
            if terms is not None:
                g = terms.gain(1, ys[:, None], xs[None, :]) * terms.gain(2, ys[:, None], xs[None, :])
            out[c] += g
            count[c] += 1
    out /= np.maximum(count, 1)[:, None, None]
    if flat_smooth is not None:
        out *= flat_smooth
    return out


def _list3_grid(raw: RawImage, ops: list[Any]) -> np.ndarray:
    """OpcodeList3's gains (GainMap per plane, FixVignetteRadial) at the grid's nodes, C x GH x GW."""
    from ..io.opcodes import FixVignetteRadial, gain_map_at, selects, vignette_at   # deferred: only raws with DNG opcodes load clisp.io.opcodes (start-up)
    from ..modules.sensor.stage import SmoothGain   # deferred: only raws that get a sensor correction load the stage (start-up)
    ny, nx = SmoothGain.nodes(raw.shape)
    ys, xs = ny[:, None], nx[None, :]
    out = np.ones((raw.cfa.n_channels, len(ny), len(nx)))
    for op in ops:
        if isinstance(op, FixVignetteRadial):
            out *= vignette_at(op, ys, xs)[None]
            continue
        for c in range(raw.cfa.n_channels):
            if op.plane <= c < op.plane + op.planes:
                out[c] *= np.where(selects(op, ys, xs), gain_map_at(op, ys, xs, c - op.plane), 1.0)
    return out


# --------------------------------------------------------------------------------------------
# Bad pixel maps
# --------------------------------------------------------------------------------------------

def read_bad_pixel_map(path: str, shape: tuple[int, int]) -> np.ndarray:
    """H x W bool from a bad pixel map: ``column row`` per line (dcraw's -P format; ``#`` starts a
    comment, further columns such as dcraw's time are ignored), 0-based coordinates of the mosaic.
    ClispError naming the file for a missing file or a line that is not two whole numbers inside it."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8", errors="replace")
    except FileNotFoundError as exc:
        raise ClispError(f"{path}: cannot read bad pixel map (no such file; --bad-pixels is auto, off or a map file)") from exc
    except OSError as exc:
        raise ClispError(f"{path}: cannot read bad pixel map ({exc.strerror or exc})") from exc
    mask = np.zeros(shape, dtype=bool)
    for number, line in enumerate(text.splitlines(), 1):
        fields = line.split("#", 1)[0].split()
        if not fields:
            continue
        try:
            col, row = int(fields[0]), int(fields[1])
        except (ValueError, IndexError):
            raise ClispError(f"{path}: bad pixel map line {number}: {clip(line, 40)!r} is not 'column row'") from None
        if not (0 <= row < shape[0] and 0 <= col < shape[1]):
            raise ClispError(f"{path}: bad pixel map line {number}: pixel ({col}, {row}) lies outside the "
                             f"{shape[1]}x{shape[0]} mosaic")
        mask[row, col] = True
    return mask


def write_bad_pixel_map(path: str | os.PathLike[str], mask: np.ndarray, note: str = "") -> int:
    """Write ``mask``'s pixels as a bad pixel map (:func:`read_bad_pixel_map`); the count."""
    rows, cols = np.nonzero(mask)
    lines = [f"# clisp bad pixel map: column row{(' - ' + note) if note else ''}"]
    lines += [f"{c} {r}" for r, c in zip(rows.tolist(), cols.tolist())]
    Path(path).write_text("\n".join(lines) + "\n")
    return len(rows)


# --------------------------------------------------------------------------------------------
# Clipped light against hot pixels
# --------------------------------------------------------------------------------------------

MAX_ISOLATED = 200_000
"""More clipped samples than this are taken for a clipped light without looking further."""

BAND = 2048
"""Rows of the mosaic read at a time (a memory-mapped raw stays on disk)."""

CHUNK = 4096
"""Clipped samples tested at a time: a clipped light fails in its first chunk, so its raw costs a
scan, not a test of every clipped sample (0.45 s on the 24 MP D30 before)."""


def only_isolated_clips(raw: RawImage, pre: SensorCorrect | None) -> bool:
    """Whether every clipped sample of ``raw`` is a bad pixel the corrections replace before the
    highlight stage: a known one (``pre``'s mask), or one the auto test takes for hot (beyond every
    same-channel neighbour within 2 pixels by K noise sigmas: a hot pixel that saturates, not a
    clipped light, whose neighbours are bright too, nor a noise peak on a bright surface). The
    pipeline then leaves the highlight stage out: "a hot pixel is not a clipped light". False where
    nothing is clipped (the stage is left out anyway), without corrections, or for float raws.
    Cost: a maximum per band of rows; in the bands that reach the lowest threshold, a comparison per
    CFA phase and the test of the clipped samples, a chunk at a time, up to the first that fails."""
    data = raw.data
    if pre is None or data.dtype != np.uint16 or (pre.test is None and pre.mask is None):
        return False
    thresholds = clip_thresholds_dn(raw)
    p, (height, width) = raw.cfa.period, raw.shape
    clipped = 0
    for y in range(0, height, BAND):
        band = np.asarray(data[y:y + BAND])
        if band.max() < thresholds.min():
            continue
        for py in range(p):
            for px in range(p):
                k = ((y + py) % p) * p + px
                ys, xs = np.nonzero(band[py::p, px::p] >= thresholds[raw.cfa.pattern[k // p, k % p]])
                if not len(ys):
                    continue
                clipped += len(ys)
                if clipped > MAX_ISOLATED:
                    return False
                ys, xs = ys * p + (y + py), xs * p + px
                if pre.mask is not None:
                    unknown = pre.mask[ys, xs] == 0
                    ys, xs = ys[unknown], xs[unknown]
                for j in range(0, len(ys), CHUNK):
                    if not _all_hot(raw, pre, k, ys[j:j + CHUNK], xs[j:j + CHUNK]):
                        return False
    return clipped > 0


def _all_hot(raw: RawImage, pre: SensorCorrect, k: int, ys: np.ndarray, xs: np.ndarray) -> bool:
    """Whether the auto test of ``pre`` takes every sample (ys, xs) (of CFA phase k) for hot: beyond
    every same-channel neighbour inside the image by its margin (the larger of K noise sigmas at that
    neighbour's level and the level-following HOT_SLOPE share of it, at most HOT_CAP) plus FLOOR."""
    if pre.test is None:
        return False
    from ..modules.sensor.stage import FLOOR, neighbour_tables   # deferred: only raws that get a sensor correction load the stage (start-up)
    data, p, (height, width) = raw.data, raw.cfa.period, raw.shape
    nb, nb_n, _, _ = neighbour_tables(raw.cfa)
    t = pre.test
    c = int(raw.cfa.pattern[k // p, k % p])
    black, span = float(raw.black_level[c]), float(raw.white_level - raw.black_level[c])
    u = (data[ys, xs].astype(np.float64) - black) / span
    hi = np.full(u.shape, -np.inf)
    for dy, dx in nb[k, :nb_n[k]]:
        qy, qx = ys + int(dy), xs + int(dx)
        inside = (qy >= 0) & (qy < height) & (qx >= 0) & (qx < width)
        v = np.full(u.shape, -np.inf)
        v[inside] = (data[qy[inside], qx[inside]].astype(np.float64) - black) / span
        hi = np.maximum(hi, v)
    sigma = np.sqrt(t.noise_a[c] * np.maximum(hi, 0) + t.noise_b[c])
    margin = np.maximum(t.k * sigma, np.minimum(t.hot_cap, t.hot_slope * np.maximum(hi, 0)))
    return bool(np.all(u - hi > margin + FLOOR))
