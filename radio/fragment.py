"""Cutting messages to frame payloads and putting them back together, in bounded memory.

Reliable data travels in sequence, so its fragments need only FIRST/LAST flags and
the message id on the first one. Datagrams may arrive in any order (or not at all):
they carry index and count, and their reassembly has a timeout and hard limits on
concurrent messages and on buffered bytes.
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field

from radio.frame import Reason, read_varint, reject, varint

FIRST = 0x01
LAST = 0x02
AUTO = 0x04  # message id from the sender's automatic namespace
AUTO_BASE = 1 << 56  # public ids at or above this are automatic ones
MAX_FRAGMENTS = 4096


def id_fields(msg_id: int) -> tuple[int, int]:
    """(flag, wire number) for a public message id."""
    return (AUTO, msg_id - AUTO_BASE) if msg_id >= AUTO_BASE else (0, msg_id)


def public_id(flags: int, number: int) -> int:
    return AUTO_BASE + number if flags & AUTO else number


def split_stream(msg_id: int, payload: bytes, room: int) -> list[bytes]:
    """Reliable fragments of at most `room` bytes each, header included."""
    flag, number = id_fields(msg_id)
    first_head = bytes([FIRST | flag]) + varint(number)
    out: list[bytes] = []
    pos = 0
    head = first_head
    while True:
        take = room - len(head) - 0
        if take <= 0:
            raise ValueError(f"frame room {room} too small for fragment headers")
        chunk = payload[pos:pos + take]
        pos += len(chunk)
        last = pos >= len(payload)
        out.append(bytes([head[0] | (LAST if last else 0)]) + head[1:] + chunk)
        if last:
            return out
        head = bytes([flag])


def parse_stream(data: bytes) -> tuple[int, int | None, bytes]:
    """(flags, public id or None, chunk) of a reliable fragment."""
    if not data:
        raise reject(Reason.PAYLOAD, "empty data fragment")
    flags = data[0]
    if flags & ~(FIRST | LAST | AUTO):
        raise reject(Reason.PAYLOAD, f"unknown fragment flags {flags:#x}")
    if flags & FIRST:
        number, pos = read_varint(data, 1)
        return flags, public_id(flags, number), data[pos:]
    return flags, None, data[1:]


class StreamAssembler:
    """Joins in-order reliable fragments; one partial message of at most `max_message` bytes."""

    def __init__(self, max_message: int) -> None:
        self.max_message = max_message
        self._id: int | None = None
        self._parts: list[bytes] = []
        self._size = 0

    def reset(self) -> None:
        self._id, self._parts, self._size = None, [], 0

    @property
    def buffered(self) -> int:
        return self._size

    def add(self, data: bytes) -> tuple[int, bytes] | None:
        """(msg id, message) when `data` completes one; FrameError if the stream is malformed."""
        flags, msg_id, chunk = parse_stream(data)
        if flags & FIRST:
            self.reset()
            self._id = msg_id
        elif self._id is None:
            raise reject(Reason.PAYLOAD, "continuation fragment without a first fragment")
        self._size += len(chunk)
        if self._size > self.max_message:
            self.reset()
            raise reject(Reason.OVERSIZE, f"message longer than {self.max_message} bytes")
        self._parts.append(chunk)
        if flags & LAST:
            done = (self._id, b"".join(self._parts))
            self.reset()
            return done  # type: ignore[return-value]
        return None


def split_datagram(msg_id: int, payload: bytes, room: int) -> list[bytes]:
    """Datagram fragments carrying id, index and count, each at most `room` bytes."""
    flag, number = id_fields(msg_id)
    fixed = 1 + len(varint(number))
    count = 1
    while True:  # the count's own size depends on the count
        take = room - fixed - 2 * len(varint(count))
        if take <= 0:
            raise ValueError(f"frame room {room} too small for datagram headers")
        need = max(1, -(-len(payload) // take))
        if need <= count:
            break
        count = need
    if count > MAX_FRAGMENTS:
        raise ValueError(f"datagram of {len(payload)} bytes needs more than {MAX_FRAGMENTS} fragments")
    head = bytes([flag]) + varint(number)
    return [head + varint(i) + varint(count) + payload[i * take:(i + 1) * take] for i in range(count)]


@dataclass
class _Partial:
    count: int
    started: float
    parts: dict[int, bytes] = field(default_factory=dict)
    size: int = 0


class Reassembler:
    """Datagram reassembly with a timeout and bounds on messages and bytes held."""

    def __init__(self, timeout: float = 5.0, max_messages: int = 8, max_bytes: int = 64 * 1024,
                 max_message: int = 64 * 1024) -> None:
        self.timeout = timeout
        self.max_messages = max_messages
        self.max_bytes = max_bytes
        self.max_message = max_message
        self._partials: OrderedDict[int, _Partial] = OrderedDict()
        self.bytes_held = 0
        self.dropped = 0  # incomplete messages given up (timeout or limits)

    def __len__(self) -> int:
        return len(self._partials)

    def expire(self, now: float) -> None:
        for key in [k for k, p in self._partials.items() if now - p.started > self.timeout]:
            self._drop(key)

    def _drop(self, key: int) -> None:
        p = self._partials.pop(key)
        self.bytes_held -= p.size
        self.dropped += 1

    def add(self, data: bytes, now: float) -> tuple[int, bytes] | None:
        """(msg id, message) once all fragments are in; FrameError for malformed fragments."""
        if not data:
            raise reject(Reason.PAYLOAD, "empty datagram fragment")
        flags = data[0]
        if flags & ~AUTO:
            raise reject(Reason.PAYLOAD, f"unknown datagram flags {flags:#x}")
        number, pos = read_varint(data, 1)
        index, pos = read_varint(data, pos, 3)
        count, pos = read_varint(data, pos, 3)
        if not 0 < count <= MAX_FRAGMENTS or index >= count:
            raise reject(Reason.PAYLOAD, f"fragment {index} of {count}")
        msg_id, chunk = public_id(flags, number), data[pos:]
        if count == 1:
            return msg_id, chunk
        self.expire(now)
        p = self._partials.get(msg_id)
        if p is None:
            while len(self._partials) >= self.max_messages:
                self._drop(next(iter(self._partials)))
            p = self._partials[msg_id] = _Partial(count, now)
        if p.count != count:
            raise reject(Reason.PAYLOAD, f"fragment count {count} disagrees with {p.count}")
        if index in p.parts:
            return None
        if p.size + len(chunk) > self.max_message:
            self._drop(msg_id)
            raise reject(Reason.OVERSIZE, f"datagram longer than {self.max_message} bytes")
        while self.bytes_held + len(chunk) > self.max_bytes and len(self._partials) > 1:
            oldest = next(k for k in self._partials if k != msg_id)
            self._drop(oldest)
        if self.bytes_held + len(chunk) > self.max_bytes:
            self._drop(msg_id)
            raise reject(Reason.REASSEMBLY, "reassembly buffer full")
        p.parts[index] = chunk
        p.size += len(chunk)
        self.bytes_held += len(chunk)
        if len(p.parts) < count:
            return None
        del self._partials[msg_id]
        self.bytes_held -= p.size
        return msg_id, b"".join(p.parts[i] for i in range(count))
