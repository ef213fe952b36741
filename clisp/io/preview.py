"""The preview a camera embeds in its raw file (``clisp thumb``): LibRaw's thumbnail, through rawpy.

Cameras store a JPEG (sometimes a small bitmap) beside the mosaic, the picture their screen shows.
Reading it costs no demosaic: the quickest look at a raw. Our own raws hold none.
"""
from __future__ import annotations

import io
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ClispError, clip, library_output, one_line


@dataclass(frozen=True)
class Preview:
    """An embedded preview: ``jpeg`` (the file's bytes, as stored) or ``pixels`` (H x W x 3 uint8,
    sRGB-encoded), and its size."""

    width: int
    height: int
    jpeg: bytes | None = None
    pixels: np.ndarray | None = None

    def decoded(self) -> np.ndarray:
        """H x W x 3 sRGB-encoded floats in [0, 1]."""
        if self.pixels is not None:
            return self.pixels.astype(np.float32) / 255.0
        from PIL import Image      # deferred: Pillow only to decode a JPEG preview into another format
        with Image.open(io.BytesIO(self.jpeg)) as im:
            return np.asarray(im.convert("RGB"), dtype=np.float32) / 255.0


def read_preview(path: str | os.PathLike[str]) -> Preview:
    """The preview embedded in the raw at ``path``; ClispError naming the file when there is none
    or the file cannot be read."""
    import rawpy                   # deferred: rawpy only for camera raws (not at `import clisp`)
    p = Path(path)
    if not p.is_file():
        raise ClispError(f"cannot read raw file '{p}': {'it is a folder' if p.is_dir() else 'no such file'}")
    try:
        with library_output(), rawpy.imread(str(p)) as raw:
            thumb = raw.extract_thumb()
    except (rawpy.LibRawNoThumbnailError, rawpy.LibRawUnsupportedThumbnailError):
        raise ClispError(f"{p}: has no embedded preview (clisp process --preset fast makes one)") from None
    except (rawpy.LibRawError, OSError, ValueError, RuntimeError) as exc:
        raise ClispError(f"cannot read raw file '{p}': {clip(one_line(exc))}") from exc
    if thumb.format == rawpy.ThumbFormat.JPEG:
        data = bytes(thumb.data)
        from PIL import Image      # deferred: as in Preview.decoded
        try:
            with Image.open(io.BytesIO(data)) as im:
                width, height = im.size
        except OSError as exc:
            raise ClispError(f"{p}: its embedded preview is a damaged JPEG ({clip(one_line(exc))})") from exc
        return Preview(width, height, jpeg=data)
    pixels = np.asarray(thumb.data)
    if pixels.ndim != 3 or pixels.shape[2] != 3:
        raise ClispError(f"{p}: its embedded preview is not an RGB image (shape {pixels.shape})")
    if pixels.dtype != np.uint8:
        pixels = np.clip(np.round(pixels / (np.iinfo(pixels.dtype).max / 255.0)), 0, 255).astype(np.uint8)
    return Preview(pixels.shape[1], pixels.shape[0], pixels=np.ascontiguousarray(pixels))
