"""The runtime's link seam: reliable send under a persistent id, and the events it needs.

`LinkTransport` binds the sans-I/O `radio.link.Link` to a byte port; `MemoryTransport` is
the in-memory body for tests.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any, Protocol

from radio.link import Acked  # the link's own event: the peer holds message msg_id


@dataclass(frozen=True, slots=True)
class Received:
    body: bytes


@dataclass(frozen=True, slots=True)
class LinkState:
    up: bool


class Transport(Protocol):
    """What the runtime needs from a link: reliable send under a persistent id, and events."""

    def send(self, body: bytes, msg_id: int, now: float) -> None: ...
    def poll(self, now: float) -> list[Received | Acked | LinkState]: ...


class MemoryTransport:
    """An in-memory link for tests: `sent` holds (msg_id, body); push events with `deliver`."""

    def __init__(self, auto_ack: bool = True) -> None:
        self.sent: list[tuple[int, bytes]] = []
        self.auto_ack = auto_ack
        self._events: deque = deque()

    def send(self, body: bytes, msg_id: int, now: float) -> None:
        self.sent.append((msg_id, body))
        if self.auto_ack:
            self._events.append(Acked(msg_id))

    def deliver(self, event: Received | Acked | LinkState) -> None:
        self._events.append(event)

    def poll(self, now: float) -> list[Received | Acked | LinkState]:
        out = list(self._events)
        self._events.clear()
        return out



class LinkTransport:
    """The sans-I/O `radio.link.Link` bound to a pyserial-like port (read/write/in_waiting)."""

    def __init__(self, link: Any, port: Any) -> None:
        self.link = link
        self.port = port

    def send(self, body: bytes, msg_id: int, now: float) -> None:
        self.link.send(body, now, reliable=True, msg_id=msg_id)

    def poll(self, now: float) -> list[Received | Acked | LinkState]:
        from radio import link as lk

        data = self.port.read(max(1, getattr(self.port, "in_waiting", 0) or 0))
        events = self.link.receive(data, now) if data else []
        out = self.link.poll(now)
        if out:
            self.port.write(out)
        events = [*events, *self.link.pop_events()]
        mine: list[Received | Acked | LinkState] = []
        for ev in events:
            if isinstance(ev, lk.Delivered):
                mine.append(Received(ev.payload))
            elif isinstance(ev, Acked):
                mine.append(ev)
            elif isinstance(ev, lk.LinkUp):
                mine.append(LinkState(True))
            elif isinstance(ev, lk.LinkDown):
                mine.append(LinkState(False))
        return mine
