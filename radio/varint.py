"""Unsigned LEB128 varints, the one encoding for variable-length integers on the wire (frame
segments and datagram fragments, MODELS label counts). Decoding is strict: bounded length,
canonical form (no redundant high zero bytes), FrameError naming the field otherwise."""
from __future__ import annotations

from radio import FrameError


def put_varint(out: bytearray, value: int) -> None:
    """Append `value` (>= 0) in 7-bit groups, low first, high bit set on all but the last."""
    if value < 0:
        raise ValueError(f"varint must be non-negative, got {value}")
    while value >= 0x80:
        out.append(value & 0x7F | 0x80)
        value >>= 7
    out.append(value)


def varint(value: int) -> bytes:
    """`value` as a varint on its own."""
    out = bytearray()
    put_varint(out, value)
    return bytes(out)


def get_varint(blob: bytes, pos: int, name: str, max_bytes: int = 5) -> tuple[int, int]:
    """(value, next position) of the varint at `pos`; at most `max_bytes` long, canonical."""
    value = 0
    for i in range(max_bytes):
        if pos + i >= len(blob):
            raise FrameError(f"{name} ends inside a varint")
        b = blob[pos + i]
        value |= (b & 0x7F) << (7 * i)
        if not b & 0x80:
            if b == 0 and i:
                raise FrameError(f"{name} varint has a redundant zero byte")
            return value, pos + i + 1
    raise FrameError(f"{name} varint is longer than {max_bytes} bytes")
