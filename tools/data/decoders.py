"""What the image decoders say, kept off the terminal and put into the command's one line.

libpng prints its complaints ("libpng error: IDAT: CRC error", "iCCP: known incorrect sRGB
profile") itself, on file descriptor 2, as libjpeg does ("Premature end of JPEG file"), and
OpenCV logs its own warnings there too: none can be asked to stay quiet per call.
`native_stderr()` catches fd 2 for the length of one read or write; `png_problem()` names what
is wrong with a PNG file that failed to read (truncated, a chunk failing its CRC), and
`damage_said()` tells an image a decoder returned though part of the file was missing (a
truncated JPEG comes back grey below the cut).
"""
from __future__ import annotations

import os
import struct
import sys
import tempfile
import threading
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import cv2

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
SAID_KEPT = 4096  # bytes of a native complaint kept

_redirect = threading.Lock()  # fd 2 is the process's: one redirection at a time

cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)  # our one line says what failed


@contextmanager
def native_stderr() -> Iterator[list[str]]:
    """fd 2 into a temporary file for the block; the list it yields holds, afterwards, the text
    the native code wrote there (empty when nothing was, or fd 2 could not be redirected)."""
    said: list[str] = []
    with _redirect:
        try:
            sys.stderr.flush()
            saved = os.dup(2)
        except (OSError, ValueError, AttributeError):  # no fd 2 to redirect: nothing to hide
            yield said
            return
        with tempfile.TemporaryFile() as sink:
            try:
                os.dup2(sink.fileno(), 2)
                yield said
            finally:
                os.dup2(saved, 2)
                os.close(saved)
                sink.seek(0)
                said.append(sink.read(SAID_KEPT).decode(errors="replace"))


def complaint(said: list[str]) -> str:
    """The native code's last complaint, on one line, without OpenCV's log prefix."""
    lines = [ln.strip() for text in said for ln in text.splitlines() if ln.strip()]
    if not lines:
        return ""
    last = lines[-1]
    if last.startswith("[") and "] " in last:  # "[ WARN:0@0.031] global grfmt_png.cpp:834 read_chunk ..."
        last = last.split("] ", 1)[1].split(" ", 2)[-1]
    return last


# What a decoder says, still returning pixels, when part of the file is missing or garbled
# (libjpeg's "Premature end of JPEG file", "Corrupt JPEG data"; libtiff's "Read error on strip").
DAMAGE_WORDS = ("premature end", "corrupt", "crc error", "read error", "truncat")


def damage_said(said: list[str]) -> str:
    """The decoder's complaint when it says the image it returned is damaged ('' otherwise:
    harmless warnings such as libpng's 'iCCP: known incorrect sRGB profile')."""
    text = complaint(said)
    return text if any(w in text.lower() for w in DAMAGE_WORDS) else ""


def png_problem(path: Path) -> str:
    """Why a PNG file cannot be read, by its chunks ('' when they look whole, or it is no PNG)."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        return exc.strerror or str(exc)
    if not data.startswith(PNG_SIGNATURE):
        return ""
    at, first = len(PNG_SIGNATURE), True
    while at + 8 <= len(data):
        length, kind = struct.unpack(">I4s", data[at:at + 8])
        name = kind.decode("latin-1")
        if first and kind != b"IHDR":
            return f"damaged PNG: its first chunk is {name!r}, not the IHDR header"
        first = False
        end = at + 12 + length
        if end > len(data):
            return f"truncated PNG: it ends inside its {name} chunk, at byte {len(data)}"
        if zlib.crc32(data[at + 4:end - 4]) != struct.unpack(">I", data[end - 4:end])[0]:
            return f"damaged PNG: its {name} chunk at byte {at} fails its CRC"
        if kind == b"IEND":
            return ""
        at = end
    return f"truncated PNG: it ends at byte {len(data)} without its IEND chunk"
