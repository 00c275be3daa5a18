"""The robot's side of the link: every packet is stored in the outbox before it is offered to
the link, at most `link.window` at a time, and leaves the outbox when the base acknowledges
it. Link events other than acknowledgements go back to the runtime."""
from __future__ import annotations

from typing import Callable

from onboard.outbox import Outbox, OutboxFull
from onboard.runtime_state import RuntimeState
from onboard.transport import Transport
from radio.link import Acked, Event, QueueFull


class LinkService:
    def __init__(self, transport: Transport, outbox: Outbox, state: RuntimeState,
                 on_ack: Callable[[], None] = lambda: None) -> None:
        self.transport, self.outbox, self.state = transport, outbox, state
        self.on_ack = on_ack  # an acknowledgement freed room in the outbox
        self._in_flight: set[int] = set()
        self._last_sent = 0

    def queue(self, kind: int, body: bytes) -> int | None:
        """Store a packet in the outbox (before any send); None when the outbox is full."""
        try:
            msg_id = self.outbox.put(kind, body)
            self.state.paused_reason = ""
            return msg_id
        except OutboxFull as exc:
            self.state.paused_reason = str(exc)
            return None

    def read(self, now: float) -> list[Event]:
        """The link's events; acknowledged packets leave the outbox here."""
        events = []
        for event in self.transport.read(now):
            if isinstance(event, Acked):
                self._in_flight.discard(event.msg_id)
                if self.outbox.ack(event.msg_id):
                    self.on_ack()
            else:
                events.append(event)
        return events

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
                self._in_flight.add(msg_id)
                self._last_sent = msg_id
        self.transport.write(now)
