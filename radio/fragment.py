"""Cutting messages to frame payloads and putting them back together, in bounded memory.

Reliable data travels in sequence, so its segments need only FIRST/LAST flags and
the message id on the first one; small messages share a frame. Datagrams may arrive in any order (or not at all):
they carry index and count, and their reassembly has a timeout and hard limits on
concurrent messages and on buffered bytes.
"""
from __future__ import annotations

from collections import Counter, OrderedDict, deque
from dataclasses import dataclass, field

from radio.frame import Reason, reject
from radio.varint import get_varint, varint

FIRST = 0x01
LAST = 0x02
AUTO = 0x04  # message id from the sender's automatic namespace
AUTO_BASE = 1 << 56  # public ids at or above this are automatic ones
MAX_FRAGMENTS = 4096
# The link's largest message, and so the largest packet body (radio.packets.MAX_BODY is this):
# a sender refuses a longer one (`MessageTooLarge`), a receiver drops it and reads on.
MAX_MESSAGE = 64 * 1024


class MessageTooLarge(ValueError):
    """A message longer than the link carries; the sender refuses it (nothing is queued)."""


def id_fields(msg_id: int) -> tuple[int, int]:
    """(flag, wire number) for a public message id."""
    return (AUTO, msg_id - AUTO_BASE) if msg_id >= AUTO_BASE else (0, msg_id)


def public_id(flags: int, number: int) -> int:
    return AUTO_BASE + number if flags & AUTO else number


MORE = 0x08  # a length follows and another segment after this one


class StreamPacker:
    """Fills reliable frame payloads from a queue of messages, several per frame if they fit.

    A segment is: flags, message id (first segment of a message only), a length (only
    when another segment follows in the same frame), bytes.
    """

    def __init__(self) -> None:
        self._cur: tuple[int, bytes] | None = None
        self._off = 0

    def reset(self) -> None:
        self._cur, self._off = None, 0

    def next_payload(self, queue: "deque[tuple[int, bytes]]", room: int) -> tuple[bytes, list[int]] | None:
        """(payload of at most `room` bytes, ids of messages it completes), or None when idle.

        Pops whole messages from the left of `queue` as it starts them."""
        out = bytearray()
        ends: list[int] = []
        while True:
            if self._cur is None:
                if not queue:
                    break
                self._cur, self._off = queue.popleft(), 0
            mid, payload = self._cur
            flag, number = id_fields(mid)
            head = bytes([flag | (FIRST if self._off == 0 else 0)])
            if self._off == 0:
                head += varint(number)
            rest = len(payload) - self._off
            if len(out) + len(head) + rest <= room:
                seg = bytes([head[0] | LAST | MORE]) + head[1:] + varint(rest) + payload[self._off:]
                # MORE promises a segment after it: room for the next one's head and a byte
                if queue and len(out) + len(seg) + 2 + len(varint(id_fields(queue[0][0])[1])) <= room:
                    out += seg
                    ends.append(mid)
                    self._cur = None
                    continue
                out += bytes([head[0] | LAST]) + head[1:] + payload[self._off:]
                ends.append(mid)
                self._cur = None
                break
            take = room - len(out) - len(head)
            if take < 1:
                break
            out += head + payload[self._off:self._off + take]
            self._off += take
            break
        return (bytes(out), ends) if out else None


def parse_segments(data: bytes) -> list[tuple[int, int | None, bytes]]:
    """[(flags, public id or None, chunk)] of a reliable frame payload."""
    if not data:
        raise reject(Reason.PAYLOAD, "empty data payload")
    segs = []
    pos = 0
    while pos < len(data):
        flags = data[pos]
        pos += 1
        if flags & ~(FIRST | LAST | AUTO | MORE):
            raise reject(Reason.PAYLOAD, f"unknown segment flags {flags:#x}")
        msg_id = None
        if flags & FIRST:
            number, pos = get_varint(data, pos, "message id", 9)
            msg_id = public_id(flags, number)
        if flags & MORE:
            n, pos = get_varint(data, pos, "segment length", 3)
            if pos + n >= len(data):
                raise reject(Reason.PAYLOAD, "segment length runs past the frame")
            chunk, pos = data[pos:pos + n], pos + n
        else:
            chunk, pos = data[pos:], len(data)
        segs.append((flags, msg_id, chunk))
    return segs


class StreamAssembler:
    """Joins in-order reliable segments; one partial message of at most `max_message` bytes.

    A message that grows past the bound is dropped and the rest of its segments skipped, while
    the other messages sharing its frames are still delivered; what was dropped is counted in
    `refused` (by reason) for the link to take with `take_refused`."""

    def __init__(self, max_message: int = MAX_MESSAGE) -> None:
        self.max_message = max_message
        self._id: int | None = None
        self._parts: list[bytes] = []
        self._size = 0
        self._skipping = False  # the rest of a dropped message's segments
        self.refused: Counter[str] = Counter()

    def reset(self) -> None:
        self._id, self._parts, self._size, self._skipping = None, [], 0, False

    @property
    def buffered(self) -> int:
        return self._size

    def take_refused(self) -> Counter[str]:
        out, self.refused = self.refused, Counter()
        return out

    def add(self, data: bytes) -> list[tuple[int, bytes]]:
        """Messages completed by this frame payload. FrameError for a payload that does not
        parse (then nothing of it is used); a segment that cannot belong to a message (too long,
        or a continuation without its start) is counted in `refused` and the others go on."""
        done: list[tuple[int, bytes]] = []
        for flags, msg_id, chunk in parse_segments(data):
            if flags & FIRST:
                self.reset()
                self._id = msg_id
            elif self._skipping:
                self._skipping = not flags & LAST
                continue
            elif self._id is None:
                self.refused[Reason.PAYLOAD.value] += 1  # its start was lost with a malformed frame
                continue
            self._size += len(chunk)
            if self._size > self.max_message:
                self.reset()
                self._skipping = not flags & LAST
                self.refused[Reason.OVERSIZE.value] += 1
                continue
            self._parts.append(chunk)
            if flags & LAST:
                done.append((self._id, b"".join(self._parts)))  # type: ignore[arg-type]
                self.reset()
        return done


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

    def __init__(self, timeout: float = 5.0, max_messages: int = 8, max_bytes: int = MAX_MESSAGE,
                 max_message: int = MAX_MESSAGE) -> None:
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
        number, pos = get_varint(data, 1, "datagram id", 9)
        index, pos = get_varint(data, pos, "fragment index", 3)
        count, pos = get_varint(data, pos, "fragment count", 3)
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
