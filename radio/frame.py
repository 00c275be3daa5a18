"""Frames on the wire: 0x00 · COBS(header · payload · tag · CRC-16) · 0x00.

The header (10 bytes) carries version and kind, sender id, link id, an 8-bit
sequence number and the sender's 48-bit authentication counter. The tag is
HMAC-SHA256 over header and payload, truncated to 8 bytes; the CRC-16 (CCITT)
covers everything before it and is checked before any header field is trusted. A
single bit error (most of what a 1e-4 BER radio does to a 100-byte frame) is
corrected from the CRC syndrome; the tag check that follows is the real gate.
Header + tag + CRC = 20 bytes.
"""
from __future__ import annotations

import binascii
import enum
import hashlib
import hmac
import struct
from dataclasses import dataclass

from cobs import cobs

from radio import FrameError

VERSION = 1
HEADER = struct.Struct(">BBBB6s")  # version<<4|kind, sender, link, seq, counter
TAG_LEN = 8
CRC_LEN = 2
OVERHEAD = HEADER.size + TAG_LEN + CRC_LEN
MAX_COUNTER = (1 << 48) - 1
DEFAULT_MTU = 100


class FrameKind(enum.IntEnum):
    """What a frame does on the link. Not a packet kind (`radio.packets.Kind`): a frame ACK
    acknowledges frames by sequence number, a packet ACK answers a command."""

    DATA = 1  # reliable, sequenced
    DATAGRAM = 2  # unreliable, fragmented with explicit indices
    ACK = 3
    HEARTBEAT = 4
    SYN = 5  # opens a sending session
    SYNACK = 6
    NEED_SYN = 7  # "I hold no session for your data: open one"


class Reason(enum.Enum):
    """Why untrusted bytes were rejected; the keys of the rejection counters."""

    COBS = "cobs"
    LENGTH = "length"
    CRC = "crc"
    VERSION = "version"
    KIND = "kind"
    TAG = "tag"
    SENDER = "sender"
    LINK = "link"
    REPLAY = "replay"
    STALE = "stale"
    STALE_SESSION = "stale_session"
    PAYLOAD = "payload"
    OVERSIZE = "oversize"
    REASSEMBLY = "reassembly"


def reject(reason: Reason, detail: str) -> FrameError:
    """A FrameError carrying its reason as an attribute, for counting."""
    err = FrameError(f"{reason.value}: {detail}")
    err.reason = reason  # type: ignore[attr-defined]
    return err


def reason_of(err: FrameError) -> Reason:
    return getattr(err, "reason", Reason.PAYLOAD)


@dataclass(frozen=True, slots=True)
class Frame:
    kind: FrameKind
    sender: int
    link: int
    seq: int
    counter: int
    payload: bytes


def max_payload(mtu: int) -> int:
    """Payload bytes that fit in one frame of `mtu` bytes on the wire (worst-case COBS)."""
    body = mtu - 2  # two delimiters
    # COBS adds one byte per 254 bytes (or part); solve for the largest raw body.
    raw = body - -(-body // 255)
    return raw - OVERHEAD


def _tag(key: bytes, data: bytes) -> bytes:
    return hmac.new(key, data, hashlib.sha256).digest()[:TAG_LEN]


def encode(frame: Frame, key: bytes) -> bytes:
    """The wire bytes of `frame`, delimiters included."""
    if not (0 <= frame.counter <= MAX_COUNTER):
        raise ValueError(f"counter {frame.counter} outside 48 bits")
    for name in ("sender", "link", "seq"):
        if not 0 <= getattr(frame, name) <= 255:
            raise ValueError(f"{name} {getattr(frame, name)} outside 0..255")
    head = HEADER.pack((VERSION << 4) | int(frame.kind), frame.sender, frame.link,
                       frame.seq, frame.counter.to_bytes(6, "big"))
    body = head + frame.payload
    body += _tag(key, body)
    body += binascii.crc_hqx(body, 0xFFFF).to_bytes(CRC_LEN, "big")
    return b"\x00" + cobs.encode(body) + b"\x00"


# CRC-16/CCITT (x^16+x^12+x^5+1) is linear: a single flipped bit D bits from the end of
# body+CRC leaves the syndrome x^D mod g, distinct for D < 32767, so the bit can be found.
_POLY = 0x11021
_REPAIR_BITS = 32760
_syndromes: dict[int, int] = {}  # syndrome -> bit distance from the end, grown on demand
_next_syn = [1, 0]  # (x^n mod g, n) for the next entry


def _bit_at(syndrome: int, nbits: int) -> int | None:
    s, n = _next_syn
    while n < nbits:
        _syndromes[s] = n
        s, n = (s << 1) ^ (_POLY if s & 0x8000 else 0), n + 1
    _next_syn[:] = [s, n]
    d = _syndromes.get(syndrome)
    return d if d is not None and d < nbits else None


def repair(body: bytes) -> tuple[bytes, int]:
    """(body, bits corrected): the body unchanged if its CRC holds, with one bit flipped back
    if a single flipped bit explains the mismatch; FrameError otherwise. The caller's tag
    check still decides: a multi-bit error mistaken for one bit fails it."""
    syndrome = binascii.crc_hqx(body[:-CRC_LEN], 0xFFFF) ^ int.from_bytes(body[-CRC_LEN:], "big")
    if syndrome == 0:
        return body, 0
    nbits = 8 * len(body)
    d = _bit_at(syndrome, nbits) if nbits <= _REPAIR_BITS else None
    if d is None:
        raise reject(Reason.CRC, "CRC mismatch")
    fixed = bytearray(body)
    fixed[len(body) - 1 - d // 8] ^= 1 << (d % 8)
    return bytes(fixed), 1


def decode(stuffed: bytes, key: bytes) -> Frame:
    """Decode one COBS body (without delimiters); raises FrameError with a reason."""
    return decode_repaired(stuffed, key)[0]


def decode_repaired(stuffed: bytes, key: bytes) -> tuple[Frame, int]:
    """Like `decode`, with the number of bit errors the CRC corrected (0 or 1)."""
    try:
        body = cobs.decode(stuffed)
    except cobs.DecodeError as exc:
        raise reject(Reason.COBS, str(exc)) from None
    if len(body) < OVERHEAD:
        raise reject(Reason.LENGTH, f"{len(body)} bytes, shorter than the {OVERHEAD}-byte overhead")
    body, fixed = repair(body)
    first, sender, link, seq, counter = HEADER.unpack_from(body)
    if first >> 4 != VERSION:
        raise reject(Reason.VERSION, f"version {first >> 4}, expected {VERSION}")
    try:
        kind = FrameKind(first & 0x0F)
    except ValueError:
        raise reject(Reason.KIND, f"unknown frame kind {first & 0x0F}") from None
    signed, tag = body[:-CRC_LEN - TAG_LEN], body[-CRC_LEN - TAG_LEN:-CRC_LEN]
    if not hmac.compare_digest(_tag(key, signed), tag):
        raise reject(Reason.TAG, "authentication tag mismatch")
    return Frame(kind, sender, link, seq, int.from_bytes(counter, "big"), bytes(signed[HEADER.size:])), fixed


class Deframer:
    """Splits a byte stream at 0x00 delimiters; resyncs at the next delimiter after garbage.

    Memory is bounded: a run longer than `max_body` bytes is discarded up to its
    next delimiter and reported as one oversize rejection.
    """

    def __init__(self, max_body: int) -> None:
        self.max_body = max_body
        self._buf = bytearray()
        self._overflow = False
        self.oversize = 0

    def feed(self, data: bytes) -> list[bytes]:
        out: list[bytes] = []
        parts = bytes(data).split(b"\x00")
        for i, part in enumerate(parts):
            last = i == len(parts) - 1
            if not self._overflow:
                self._buf += part
                if len(self._buf) > self.max_body:
                    self._overflow = True
                    self._buf.clear()
            if last:
                break
            # a delimiter ends the current run
            if self._overflow:
                self.oversize += 1
            elif self._buf:
                out.append(bytes(self._buf))
            self._buf.clear()
            self._overflow = False
        return out

    @property
    def buffered(self) -> int:
        return len(self._buf)
