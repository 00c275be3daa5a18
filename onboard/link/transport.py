"""The runtime's link seam: what the robot needs of its link, and an in-memory body for tests.

On the robot the body is `radio.pump.LinkPump` (the sans-I/O link bound to the serial port);
its events are the link's own (`radio.link`: Delivered, Acked, LinkUp, LinkDown).
"""
from __future__ import annotations

from collections import deque
from typing import Protocol

from radio.fragment import AUTO_BASE
from radio.link import Acked, Delivered, Event, LinkStats


class Transport(Protocol):
    """Reliable send under a persistent id; `read` returns the link's events, `write` sends
    what is due (after the events were acted on)."""

    def send(self, payload: bytes, reliable: bool = True, msg_id: int | None = None,
             now: float | None = None) -> int: ...
    def read(self, now: float | None = None) -> list[Event]: ...
    def write(self, now: float | None = None) -> None: ...


class MemoryTransport:
    """An in-memory link for tests: `sent` holds (msg_id, body); the base's messages arrive
    with `receive`, any other link event with `deliver`."""

    BASE = 2  # the peer's node id on the events it raises

    def __init__(self, auto_ack: bool = True) -> None:
        self.sent: list[tuple[int, bytes]] = []
        self.auto_ack = auto_ack
        self._events: deque[Event] = deque()
        self._received = 0
        self.rejected: dict[str, int] = {}  # what the link would have counted, for STATUS tests
        self.sessions = 0  # sessions the base opened (a station started), as the link counts them

    def send(self, payload: bytes, reliable: bool = True, msg_id: int | None = None,
             now: float | None = None) -> int:
        msg_id = AUTO_BASE + len(self.sent) if msg_id is None else msg_id  # as the link's automatic ids
        self.sent.append((msg_id, bytes(payload)))
        if self.auto_ack:
            self._events.append(Acked(msg_id))
        return msg_id

    def receive(self, body: bytes) -> None:
        """The base's message `body` arrives."""
        self._received += 1
        self._events.append(Delivered(self.BASE, self._received, bytes(body)))

    def deliver(self, event: Event) -> None:
        self._events.append(event)

    def read(self, now: float | None = None) -> list[Event]:
        out = list(self._events)
        self._events.clear()
        return out

    def write(self, now: float | None = None) -> None:
        pass  # `sent` already holds what the robot sent

    def stats(self) -> LinkStats:
        return LinkStats(0, 0, 0, 0, 0, 0, 0, self.sessions, dict(self.rejected))
