"""The one exception type that the CLI turns into a one-line message and a non-zero exit, and the
helpers that keep every user-facing message to that one line.

A refusal is ``clisp: error: FILE: problem`` on stderr, at most :data:`MAX_MESSAGE` characters, exit
status 2. Text that comes from a file (JSON metadata, a tag's value, a library's complaint about
the file) is squeezed onto one line and cut (:func:`clip`); C libraries that print to the process's
stderr (LibRaw's "file: Unexpected end of file", OpenImageIO) are silenced around their calls
(:func:`library_output`) and what they said is folded into our message instead.
"""
from __future__ import annotations

import logging
import os
import sys
import tempfile
import threading
from contextlib import contextmanager
from typing import Iterator

MAX_MESSAGE = 200
"""Longest line the CLI prints for a refusal, ``clisp: error:`` included."""

FILE_TEXT = 60
"""Longest piece of text quoted from a file or a library into a message."""


class ClispError(Exception):
    """A user-facing error: bad input, unsupported format, missing OpenCL, failed kernel build."""


def clip(text: object, limit: int = FILE_TEXT) -> str:
    """``text`` on one line (runs of whitespace and control characters become one space), cut to
    ``limit`` characters with '...' where it was longer."""
    s = "".join(ch if ch.isprintable() else " " for ch in str(text))
    s = " ".join(s.split())
    return s if len(s) <= limit else s[:max(0, limit - 3)].rstrip() + "..."


def one_line(exc: BaseException) -> str:
    """An exception's message squeezed onto one line (bytes arguments decoded, as rawpy uses them).

    >>> one_line(ValueError(b"bad\\n  header"))
    'bad header'
    """
    args = [a.decode("utf-8", "replace") if isinstance(a, bytes) else str(a) for a in exc.args]
    text = " ".join(" ".join(args).split()) if args else " ".join(str(exc).split())
    return text or type(exc).__name__


def error_line(message: object, prefix: str = "clisp: error: ") -> str:
    """The one line the CLI prints for ``message``: ``prefix`` + the message, at most MAX_MESSAGE
    characters (the middle is cut, so that the file named at the start and the problem's end stay)."""
    text = clip(message, 10**6)
    room = MAX_MESSAGE - len(prefix)
    while len(text) > room:                  # first shorten paths to their file names
        longest = max(text.split(" "), key=lambda w: len(w) if "/" in w[:-1] else 0)
        folder = longest.rstrip("'\":,").rpartition("/")[0]
        if "/" not in longest[:-1] or not folder.strip("'\"."):
            break
        text = text.replace(folder.lstrip("'\""), "...", 1) if folder.lstrip("'\"") else text
        if folder.lstrip("'\"") in ("", "..."):
            break
    if len(text) > room:
        head = room * 2 // 3
        text = text[:head].rstrip() + " ... " + text[-(room - head - 5):].lstrip()
    return prefix + text


class LibraryOutput:
    """What a C library printed on stderr inside :func:`library_output` (``text``, one line)."""

    text: str = ""

    def note(self, limit: int = FILE_TEXT, drop: str = "") -> str:
        """``'; text'`` for a message ('' when the library said nothing), without ``drop``
        (the file name that LibRaw puts before its complaint)."""
        text = self.text.replace(f"{drop}: ", "").strip() if drop else self.text
        return f"; {clip(text, limit)}" if text else ""


_FD_LOCK = threading.RLock()


@contextmanager
def library_output() -> Iterator[LibraryOutput]:
    """Collect what is written to file descriptor 2 (C libraries' stderr, e.g. LibRaw's
    ``file: Unexpected end of file``) while the block runs, instead of letting it reach the
    terminal before our one-line message; tifffile's log records are held back the same way.
    The captured text is in the yielded object's ``text`` after the block (also on an error).
    Threads that write to stderr meanwhile are captured too, so keep the block to the library call."""
    out = LibraryOutput()
    tiff_log = logging.getLogger("tifffile")
    with _FD_LOCK:
        tiff_log_level = tiff_log.level
        tiff_log.setLevel(logging.CRITICAL + 1)
        try:
            sys.stderr.flush()
        except (AttributeError, ValueError, OSError):
            pass
        try:
            saved = os.dup(2)
        except OSError:                       # no fd 2 (embedded interpreter): nothing to capture
            saved = None
        sink = tempfile.TemporaryFile() if saved is not None else None
        try:
            if sink is not None:
                os.dup2(sink.fileno(), 2)
            yield out
        finally:
            if sink is not None:
                os.dup2(saved, 2)
                os.close(saved)
                sink.seek(0)
                out.text = clip(sink.read(4096).decode("utf-8", "replace"), 1000)
                sink.close()
            tiff_log.setLevel(tiff_log_level)
