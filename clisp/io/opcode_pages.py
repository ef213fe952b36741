"""Which pages of a TIFF/DNG carry DNG opcode lists, and reading them only for those pages: a raw
without them never imports clisp.io.opcodes (start-up). Used by our DNG reader (clisp.io.rawfile) and
the camera DNG reader (clisp.io.camera)."""
from __future__ import annotations

from typing import Any

TAG_OPCODE_LISTS = (51008, 51009, 51022)
"""OpcodeList1, 2 and 3 (clisp.io.opcodes.TAG_OPCODE_LIST): a raw without them does not import that
module (start-up)."""


def page_opcodes(page: Any, where: str, origin1: tuple[int, int] = (0, 0), image1: tuple[int, int] | None = None,
                 image23: tuple[int, int] | None = None) -> list[Any]:
    """clisp.io.opcodes.read_opcode_tags of a tifffile page, [] without an OpcodeList tag (that module
    imported only for a page that has one)."""
    if not any(code in page.tags for code in TAG_OPCODE_LISTS):
        return []
    from .opcodes import read_opcode_tags   # deferred: only raws with DNG opcodes load clisp.io.opcodes (start-up)
    return read_opcode_tags(page, where, origin1, image1, image23)
