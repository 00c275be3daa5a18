"""The link protocol, sans-I/O: fed received bytes and the time (`receive`), it queues events
(`pop_events`), and `poll` returns the bytes to write. No sockets, clocks or threads:
deterministic. `radio.pump.LinkPump` binds it to a port.

Each direction is a session opened by SYN (its counter names the session) and
answered by SYNACK. Reliable messages are cut into sequenced DATA frames, sent with
selective-repeat ARQ and delivered in order; the ACK carries the next expected
sequence and a bitmap of what arrived beyond it. `Acked(msg_id)` means the peer
has delivered (or already had) the message. A receiver holding no session for a
sender (it restarted) answers NEED_SYN and the sender re-sends, in a new session,
everything not yet acknowledged; the (sender, msg_id) dedup window turns those
repeats into re-acks rather than re-deliveries.
A SYN names the sender's incarnation (a robot's outbox: when it is new, message ids and
capture numbers start again): deliveries carry it, and a new one empties the dedup window.
"""
from __future__ import annotations

from collections import Counter, OrderedDict, deque

from radio import FrameError
from radio.auth import CounterStore, ReplayWindow, StaleRun
from radio.events import Acked, Delivered, Event, LinkDown, LinkStats, LinkUp, PeerStale, QueueFull
from radio.fragment import (
    AUTO_BASE,
    MAX_MESSAGE,
    MessageTooLarge,
    Reassembler,
    StreamAssembler,
    StreamPacker,
    split_datagram,
)
from radio.frame import (
    DEFAULT_MTU,
    Deframer,
    Frame,
    FrameKind,
    Reason,
    decode_repaired,
    encode,
    max_payload,
    reason_of,
    reject,
)
from radio.retransmit import DUPTHRESH, GRACE_TIMEOUTS, TAIL_COPIES, TAIL_FRAMES, InFlight, RetransmitTimer

__all__ = ["Link", "Acked", "Delivered", "Event", "LinkDown", "LinkStats", "LinkUp", "MessageTooLarge",
           "PeerStale", "QueueFull", "MAX_MESSAGE"]


ACK_REPEATS = 2  # copies of the ACK that ends a burst of data
MAX_INCARNATION = 16  # bytes of a SYN's incarnation id


def _c6(counter: int) -> bytes:
    return counter.to_bytes(6, "big")


def _check_args(node_id: int, peer_id: int, link_id: int, key: bytes, window: int, mtu: int,
                incarnation: bytes) -> None:
    for name, v in (("node_id", node_id), ("peer_id", peer_id), ("link_id", link_id)):
        if not 0 <= v <= 255:
            raise ValueError(f"{name} {v} outside 0..255")
    if node_id == peer_id:
        raise ValueError("node_id and peer_id must differ")
    if len(key) != 32:
        raise ValueError(f"key of {len(key)} bytes, expected 32")
    if not 1 <= window <= 64:
        raise ValueError(f"window {window} outside 1..64")
    if not 40 <= mtu <= 4096:
        raise ValueError(f"mtu {mtu} outside 40..4096")
    if len(incarnation) > MAX_INCARNATION:
        raise ValueError(f"incarnation of {len(incarnation)} bytes, at most {MAX_INCARNATION}")


class Link:
    def __init__(self, node_id: int, peer_id: int, link_id: int, key: bytes,
                 counter_store: CounterStore, *, mtu: int = DEFAULT_MTU, window: int = 64,
                 rto: float = 0.3, min_rto: float = 0.05, max_rto: float = 1.0,
                 heartbeat: float = 1.0, link_timeout: float = 3.0, dedup: int = 4096,
                 max_message: int = MAX_MESSAGE, max_queue_bytes: int = 1 << 20,
                 reassembly_timeout: float = 5.0, incarnation: bytes = b"") -> None:
        _check_args(node_id, peer_id, link_id, key, window, mtu, incarnation)
        self.incarnation = bytes(incarnation)
        self.node_id, self.peer_id, self.link_id = node_id, peer_id, link_id
        self._key, self._store = bytes(key), counter_store
        self.mtu, self.window, self.heartbeat, self.link_timeout = mtu, window, heartbeat, link_timeout
        self._room = max_payload(mtu)
        self._timer = RetransmitTimer(rto, min_rto, max_rto)
        self._bitmap_len = (window + 7) // 8
        self.max_message, self.max_queue_bytes = max_message, max_queue_bytes
        self._deframer = Deframer(max_body=mtu)
        self._events: list[Event] = []
        self._rejected: Counter[str] = Counter()
        self._n = Counter()  # frames_sent, bytes_sent, ... for LinkStats
        # sending side
        self._tx_open = False
        self._syn_first: int | None = None
        self._syn_sent_at: float | None = None
        self._last_ack_counter = 0
        self._msgs: OrderedDict[int, bytes] = OrderedDict()  # reliable, not yet acked
        self._unsent: deque[tuple[int, bytes]] = deque()
        self._packer = StreamPacker()
        self._inflight: dict[int, InFlight] = {}
        self._tx_base = self._tx_next = 0
        self._xmit = 0
        self._news = 0.0  # last ACK that acknowledged something new
        self._timeouts = 0  # RTO expiries since then
        self._dgrams: deque[bytes] = deque()
        self._dgram_bytes = 0  # datagram fragments not yet written count against max_queue_bytes
        self._queued_bytes = 0
        self._last_tx: float | None = None
        # receiving side
        floor = counter_store.rx_floor(peer_id, link_id)
        self._replay = ReplayWindow(64, floor)
        self._rx_session: int | None = None
        self.peer_incarnation: bytes | None = None  # named by the peer's last SYN
        self._stale = StaleRun(peer_id)
        self._rx_max_data = 0
        self._rx_next = 0
        self._rx_buf: dict[int, bytes] = {}
        self._asm = StreamAssembler(max_message)
        self._reasm = Reassembler(reassembly_timeout, max_messages=8, max_bytes=4 * max_message,
                                  max_message=max_message)
        self._dedup: OrderedDict[int, None] = OrderedDict()
        self._dedup_size = dedup
        self._ack_pending = False
        self._ack_repeats, self._ack_again = 0, 0.0
        self._synacks: list[int] = []
        self._synack_again: tuple[int, int, float] | None = None  # (counter, repeats left, due)
        self._need_syn: int | None = None
        self._heard: float | None = None
        self.up = False

    # ------------------------------------------------------------------ public
    def send(self, payload: bytes, now: float, reliable: bool = True,
             msg_id: int | None = None) -> int:
        """Queue a message; returns its id (the caller's, or a fresh automatic one). A message
        longer than `max_message` is refused (MessageTooLarge): the peer would drop it."""
        payload = bytes(payload)
        if len(payload) > self.max_message:
            raise MessageTooLarge(f"message of {len(payload)} bytes exceeds the link's largest, {self.max_message}")
        if msg_id is None:
            msg_id = AUTO_BASE + self._store.next_tx(self.node_id, self.link_id)
        elif not 0 <= msg_id < AUTO_BASE:
            raise ValueError(f"msg_id {msg_id} outside 0..2**56-1")
        held = self._queued_bytes + self._dgram_bytes
        if held + len(payload) > self.max_queue_bytes:
            raise QueueFull(f"{held} bytes already queued")
        if reliable:
            if msg_id in self._msgs:
                raise ValueError(f"msg_id {msg_id} is already in flight")
            self._msgs[msg_id] = payload
            self._unsent.append((msg_id, payload))
            self._queued_bytes += len(payload)
        else:
            frags = split_datagram(msg_id, payload, self._room)
            self._dgrams.extend(frags)
            self._dgram_bytes += sum(map(len, frags))
        return msg_id

    @property
    def queued_bytes(self) -> int:
        """Bytes of reliable messages not yet acknowledged."""
        return self._queued_bytes

    @property
    def idle(self) -> bool:
        return not self._msgs and not self._dgrams

    def pop_events(self) -> list[Event]:
        """Everything that happened since the last call, in order: what `receive` delivered
        and acknowledged, and what `poll` found (LinkDown). The link's one event queue."""
        ev, self._events = self._events, []
        return ev

    def stats(self) -> LinkStats:
        n = self._n
        return LinkStats(n["frames_sent"], n["bytes_sent"], n["accepted"], n["retransmissions"],
                         n["delivered"], n["duplicates"], n["acked"], n["sessions"],
                         dict(self._rejected), n["repaired"])

    def buffered_bytes(self) -> int:
        """Bytes held for reassembly and reordering (bounded by the configuration)."""
        return (self._reasm.bytes_held + self._asm.buffered + self._deframer.buffered
                + sum(len(b) for b in self._rx_buf.values()))

    def receive(self, data: bytes, now: float) -> None:
        """Feed bytes read from the port; what happened waits in `pop_events`. Never raises on
        bad bytes."""
        before = self._deframer.oversize
        for body in self._deframer.feed(data):
            try:
                frame, fixed = decode_repaired(body, self._key)
                self._handle(frame, now)
                self._n["repaired"] += fixed
            except FrameError as exc:
                self._rejected[reason_of(exc).value] += 1
                if said := self._stale.refused(reason_of(exc)):  # the peer's counters are behind
                    self._events.append(said)
        if self._deframer.oversize > before:
            self._rejected[Reason.OVERSIZE.value] += self._deframer.oversize - before

    def poll(self, now: float, max_bytes: int | None = None) -> bytes:
        """Bytes to write now: control frames, retransmissions, new data, heartbeats; at most
        `max_bytes` (what a paced transport can carry), the rest waits."""
        if self.up and self._heard is not None and now - self._heard > self.link_timeout:
            self.up = False
            self._events.append(LinkDown())
        self._reasm.expire(now)
        out = bytearray()
        budget = [max_bytes if max_bytes is not None else 1 << 62]

        def emit(kind: FrameKind, payload: bytes = b"", seq: int = 0) -> bool:
            if budget[0] < self.mtu:
                return False
            c = self._store.next_tx(self.node_id, self.link_id)
            if kind is FrameKind.SYN:
                payload = self.incarnation
            wire = encode(Frame(kind, self.node_id, self.link_id, seq, c, payload), self._key)
            out.extend(wire)
            budget[0] -= len(wire)
            self._n["frames_sent"] += 1
            self._n["bytes_sent"] += len(wire)
            self._last_tx = now
            if kind is FrameKind.SYN and self._syn_first is None:
                self._syn_first = c
            return True

        while self._synacks and emit(FrameKind.SYNACK, _c6(self._synacks[0])):
            self._synack_again = (self._synacks.pop(0), ACK_REPEATS, now + self._timer.min_rto / 2)
        if self._synack_again and self._synack_again[1] and now >= self._synack_again[2]:
            c, left, _ = self._synack_again  # a lost SYNACK would cost the peer a whole RTO
            if emit(FrameKind.SYNACK, _c6(c)):
                self._synack_again = (c, left - 1, now + self._timer.min_rto / 2)
        if self._need_syn is not None and emit(FrameKind.NEED_SYN, _c6(self._need_syn)):
            self._need_syn = None
        if self._ack_pending and emit(FrameKind.ACK, self._ack_payload()):
            self._ack_pending = False
            self._ack_repeats, self._ack_again = ACK_REPEATS, now + self._timer.min_rto / 2
        elif self._ack_repeats and now >= self._ack_again and emit(FrameKind.ACK, self._ack_payload()):
            # The last ACK of a burst has no successor to cover its loss: say it again.
            self._ack_repeats -= 1
            self._ack_again = now + self._timer.min_rto / 2
        if not self._tx_open:
            if (self._syn_sent_at is None or now - self._syn_sent_at >= self._timer.rto) and emit(FrameKind.SYN):
                self._syn_sent_at = now
        while self._dgrams and emit(FrameKind.DATAGRAM, self._dgrams[0]):
            self._dgram_bytes -= len(self._dgrams.popleft())
        if self._tx_open:
            self._send_data(now, emit, lambda: budget[0])
        if (self._last_tx is None or now - self._last_tx >= self.heartbeat) and not out:
            emit(FrameKind.HEARTBEAT)
        return bytes(out)

    # ------------------------------------------------------------- sending side
    def _send_data(self, now: float, emit, budget) -> None:
        if self._inflight and now - max(self._news, self._oldest_unsacked()) >= self._timer.rto:
            # No news for a whole RTO: everything unacknowledged is presumed lost; back off.
            missing = [o for o in self._inflight.values() if not o.sacked]
            for o in missing:
                o.lost = True
                # A few frames stuck at the tail: extra copies cost idle air, and save RTOs.
                o.copies = TAIL_COPIES if len(missing) <= TAIL_FRAMES else 1
            self._news = now
            self._timeouts += 1
            if self._timeouts > GRACE_TIMEOUTS:  # a dead link is not flooded, a burst not waited out
                self._timer.back_off()
        for s in range(self._tx_base, self._tx_next):
            o = self._inflight[s]
            if o.lost and not o.sacked:
                for _ in range(o.copies):
                    if not emit(FrameKind.DATA, o.data, s & 0xFF):
                        return
                o.copies = 1
                o.sent_at, o.tries, o.lost, o.xmit = now, o.tries + 1, False, self._xmit
                self._xmit += 1
                self._n["retransmissions"] += 1
        while self._tx_next - self._tx_base < self.window and self.mtu <= budget():
            nxt = self._packer.next_payload(self._unsent, self._room)
            if nxt is None:
                return
            emit(FrameKind.DATA, nxt[0], self._tx_next & 0xFF)
            if not self._inflight:
                self._news = now  # the timer runs from the first frame of a flight
            self._inflight[self._tx_next] = InFlight(nxt[0], nxt[1], now, 1, self._xmit)
            self._xmit += 1
            self._tx_next += 1

    def _oldest_unsacked(self) -> float:
        return min((o.sent_at for o in self._inflight.values() if not o.sacked), default=float("inf"))

    def _restart_session(self) -> None:
        self._tx_open = False
        self._syn_first = self._syn_sent_at = None
        self._inflight.clear()
        self._packer.reset()
        self._unsent = deque(self._msgs.items())
        self._tx_base = self._tx_next = 0

    def _on_ack(self, f: Frame, now: float) -> None:
        if len(f.payload) != 1 + self._bitmap_len:
            raise reject(Reason.PAYLOAD, f"ACK of {len(f.payload)} bytes")
        if not self._tx_open or f.counter <= self._last_ack_counter:
            return  # an older ACK than one already applied says nothing new
        self._last_ack_counter = f.counter
        d = (f.payload[0] - self._tx_base) & 0xFF
        if d > self._tx_next - self._tx_base:
            return
        newest: float | None = None  # send time of the latest first-try frame this ACK covers
        arrived: list[int] = []  # transmission indices known to have arrived
        for s in range(self._tx_base, self._tx_base + d):
            o = self._inflight.pop(s)
            if not o.sacked:
                arrived.append(o.xmit)
                if o.tries == 1:
                    newest = o.sent_at if newest is None else max(newest, o.sent_at)
            for mid in o.ends:
                self._queued_bytes -= len(self._msgs.pop(mid, b""))
                self._n["acked"] += 1
                self._events.append(Acked(mid))
        self._tx_base += d
        bits = int.from_bytes(f.payload[1:], "little")
        fresh = bool(d)
        for i in range(self.window):
            o = self._inflight.get(self._tx_base + 1 + i)
            if o is not None and (bits >> i) & 1 and not o.sacked:
                o.sacked = fresh = True
                if o.tries == 1:
                    newest = o.sent_at if newest is None else max(newest, o.sent_at)
        if not fresh:
            return
        self._news, self._timeouts = now, 0
        # Karn: only frames sent once, timed when first acknowledged (a SACKed frame
        # cumulatively acked later would count the hole's repair time as RTT).
        if newest is not None:
            self._timer.sample(now - newest)
        # A frame is lost once DUPTHRESH frames transmitted after it have arrived.
        arrived += [o.xmit for o in self._inflight.values() if o.sacked]
        if len(arrived) >= DUPTHRESH:
            limit = sorted(arrived)[-DUPTHRESH]
            for o in self._inflight.values():
                if not o.sacked and o.xmit < limit:
                    o.lost = True

    # ----------------------------------------------------------- receiving side
    def _ack_payload(self) -> bytes:
        bits = 0
        for i in range(self.window):
            if ((self._rx_next + 1 + i) & 0xFF) in self._rx_buf:
                bits |= 1 << i
        return bytes([self._rx_next & 0xFF]) + bits.to_bytes(self._bitmap_len, "little")

    def _handle(self, f: Frame, now: float) -> None:
        if f.sender != self.peer_id:
            raise reject(Reason.SENDER, f"sender {f.sender}, expected {self.peer_id}")
        if f.link != self.link_id:
            raise reject(Reason.LINK, f"link {f.link}, expected {self.link_id}")
        why = self._replay.check(f.counter)
        if why is not None:
            raise reject(why, f"counter {f.counter}")
        self._replay.accept(f.counter)
        self._n["accepted"] += 1
        self._stale.accepted()
        if f.kind is FrameKind.SYN:
            self._on_syn(f)
        elif f.kind is FrameKind.SYNACK:
            if len(f.payload) != 6:
                raise reject(Reason.PAYLOAD, "SYNACK without a 6-byte counter")
            c = int.from_bytes(f.payload, "big")
            if not self._tx_open and self._syn_first is not None and c >= self._syn_first:
                self._tx_open = True
                self._last_ack_counter = f.counter
        elif f.kind is FrameKind.NEED_SYN:
            if len(f.payload) != 6:
                raise reject(Reason.PAYLOAD, "NEED_SYN without a 6-byte counter")
            c = int.from_bytes(f.payload, "big")
            if self._tx_open and self._syn_first is not None and c > self._syn_first:
                self._restart_session()
        elif f.kind is FrameKind.ACK:
            self._on_ack(f, now)
        if self._rx_session is None or f.counter <= self._rx_session:
            if f.kind in (FrameKind.DATA, FrameKind.DATAGRAM, FrameKind.HEARTBEAT):
                if self._rx_session is None:
                    self._need_syn = f.counter
                raise reject(Reason.STALE_SESSION, f"{f.kind.name} outside a session")
            return
        self._heard = now
        if not self.up:
            self.up = True
            self._events.append(LinkUp())
        if f.kind is FrameKind.DATA:
            self._on_data(f)
        elif f.kind is FrameKind.DATAGRAM:
            done = self._reasm.add(f.payload, now)
            if done is not None:
                self._deliver(*done)

    def _on_syn(self, f: Frame) -> None:
        if len(f.payload) > MAX_INCARNATION:
            raise reject(Reason.PAYLOAD, f"SYN with {len(f.payload)} bytes of incarnation")
        if f.counter <= max(self._rx_session or 0, self._rx_max_data):
            raise reject(Reason.STALE_SESSION, "SYN older than the current session")
        if self.peer_incarnation is not None and f.payload != self.peer_incarnation:
            self._dedup.clear()  # the ids it holds were the old incarnation's
        self.peer_incarnation = bytes(f.payload)
        # Persist first: after a restart no frame of an older session may be accepted.
        self._store.set_rx_floor(self.peer_id, self.link_id, f.counter)
        self._rx_session = f.counter
        self._rx_next, self._rx_max_data = 0, 0
        self._rx_buf.clear()
        self._asm.reset()
        self._ack_pending = False
        self._synacks = (self._synacks + [f.counter])[-4:]
        self._n["sessions"] += 1

    def _on_data(self, f: Frame) -> None:
        self._rx_max_data = max(self._rx_max_data, f.counter)
        d = (f.seq - self._rx_next) & 0xFF
        if d >= self.window:
            self._ack_pending = True
            if d < 256 - self.window:
                raise reject(Reason.PAYLOAD, f"sequence {f.seq} outside the window")
            self._n["duplicates_frames"] += 1  # already delivered: re-ack only
            return
        self._ack_pending = True
        if f.seq in self._rx_buf:
            return
        self._rx_buf[f.seq] = f.payload
        while (self._rx_next & 0xFF) in self._rx_buf:
            data = self._rx_buf.pop(self._rx_next & 0xFF)
            self._rx_next += 1
            try:
                done = self._asm.add(data)
            except FrameError as exc:
                self._rejected[reason_of(exc).value] += 1
                continue
            finally:
                self._rejected.update(self._asm.take_refused())
            for mid, msg in done:
                self._deliver(mid, msg)

    def _deliver(self, msg_id: int, payload: bytes) -> None:
        if msg_id in self._dedup:
            self._n["duplicates"] += 1
            return
        self._dedup[msg_id] = None
        while len(self._dedup) > self._dedup_size:
            self._dedup.popitem(last=False)
        self._n["delivered"] += 1
        self._events.append(Delivered(self.peer_id, msg_id, payload, self.peer_incarnation or b""))
