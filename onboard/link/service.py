"""The robot's side of the link: every packet is stored in the outbox before it is offered to
the link, at most `link.window` at a time, and leaves the outbox when the base acknowledges
it. Link events other than acknowledgements go back to the runtime, except the base's refusal
of a message (a NACK UNUSABLE naming it): that message is set aside in the outbox's dead
letters, never offered again (`Outbox.set_aside`), and the refusal is one of the robot's errors.
A message the link refuses as longer than its largest (an outbox row written before that bound)
is set aside the same way and the next one offered: one message never stalls those after it.
A refusal that arrives in the same read as the message's acknowledgement is applied first, so
the dead letter keeps the body; one that arrives later finds only the id to keep.

On a full disk an acknowledged row whose delete fails stays marked and is deleted at a later
turn (it is never offered again), and a STATUS or a query's answer that not even the outbox's
last room takes goes straight to the link (`send_direct`): not kept across a restart, but
heard."""
from __future__ import annotations

from typing import Callable

from onboard.link.outbox import Outbox, OutboxError, OutboxFull
from onboard.link.transport import Transport
from onboard.state import RuntimeState
from radio import FrameError
from radio import packets as pk
from radio.link import Acked, Delivered, Event, LinkStats, MessageTooLarge, QueueFull


class LinkService:
    def __init__(self, transport: Transport, outbox: Outbox, state: RuntimeState,
                 on_ack: Callable[[], None] = lambda: None) -> None:
        self.transport, self.outbox, self.state = transport, outbox, state
        self.on_ack = on_ack  # an acknowledgement freed room in the outbox
        self._in_flight: set[int] = set()
        self._last_sent = 0
        self._unacked: set[int] = set()  # acknowledged rows whose delete failed (a full disk)
        self._delete_failing = False

    def queue(self, kind: int, body: bytes) -> int | None:
        """Store a packet in the outbox (before any send); None when the outbox is full."""
        try:
            msg_id = self.outbox.put(kind, body)
            self.state.paused_reason = ""
            return msg_id
        except OutboxFull as exc:
            self.state.paused_reason = str(exc)
            return None

    def send_direct(self, kind: int, body: bytes, now: float | None = None) -> bool:
        """Send a body on the link without the outbox (it is full): whether the link took it."""
        try:
            self.transport.send(body, now=now)
            return True
        except QueueFull:
            return False
        except MessageTooLarge as exc:
            self.state.errors.append(f"a message of kind {kind} not sent: {exc}")
            return False

    def read(self, now: float) -> list[Event]:
        """The link's events; acknowledged packets leave the outbox here."""
        events = []
        for event in self.transport.read(now):
            if isinstance(event, Acked):
                self._in_flight.discard(event.msg_id)
                self._unacked.add(event.msg_id)
            elif not (isinstance(event, Delivered) and self._refused(event.payload)):
                events.append(event)
        for msg_id in sorted(self._unacked):
            try:
                gone = self.outbox.ack(msg_id)
            except OutboxError as exc:  # a full disk: deleted at a later turn
                if not self._delete_failing:
                    self.state.errors.append(f"acknowledged packets not yet deleted: {exc}")
                self._delete_failing = True
                break
            self._unacked.discard(msg_id)
            self._delete_failing = False
            if gone:
                self.on_ack()
        return events

    def _refused(self, payload: bytes) -> bool:
        """Whether `payload` is the base's refusal of one of the robot's messages (then set aside)."""
        try:
            p = pk.decode(payload)
        except FrameError:
            return False  # the dispatcher says what was wrong with it
        if not isinstance(p, pk.NackPacket) or p.msg_id is None:
            return False
        self._in_flight.discard(p.msg_id)
        try:
            held = self.outbox.set_aside(p.msg_id, p.text)
        except OutboxError as exc:
            self.state.errors.append(f"the base refused message {p.msg_id} ({p.text}); not set aside: {exc}")
            return True
        self.state.errors.append(f"the base refused message {p.msg_id} ({p.text}): set aside, not sent again"
                                 + ("" if held else " (already acknowledged)"))
        if held:
            self.on_ack()
        return True

    def _too_large(self, msg_id: int, why: str) -> None:
        """The link refused message `msg_id` as too long: into the dead letters, never offered again."""
        try:
            self.outbox.set_aside(msg_id, why)
        except OutboxError as exc:
            self.state.errors.append(f"message {msg_id} not sent ({why}); not set aside: {exc}")
            return
        self.state.errors.append(f"message {msg_id} not sent: {why}; set aside")
        self.on_ack()

    def stats(self) -> LinkStats | None:
        """The link's counters (None for a link that keeps none)."""
        stats = getattr(self.transport, "stats", None)
        return stats() if stats is not None else None

    def write(self, now: float) -> None:
        """Offer the outbox's next packets to the link, then let it write (replies queued while
        the events were handled leave with the acknowledgements)."""
        room = self.state.cfg.link.window - len(self._in_flight)
        if room > 0:
            for msg_id, body in self.outbox.pending(limit=room, after=self._last_sent):
                try:
                    self.transport.send(body, msg_id=msg_id, now=now)
                except QueueFull:  # the link holds enough already: offer the rest later
                    break
                except MessageTooLarge as exc:
                    self._last_sent = msg_id
                    self._too_large(msg_id, str(exc))
                    continue
                self._in_flight.add(msg_id)
                self._last_sent = msg_id
        self.transport.write(now)
