"""The one place a `radio.link.Link` meets a port: `LinkPump.read` feeds the link what arrived
and returns its events, `LinkPump.write` writes what the link has due, paced.

Pacing: a step writes at most `max_write` bytes, less what the port reports still waiting to
go out (`out_waiting`: a UART's driver queue, the simulated radio's backlog). What does not
fit stays in the link, where an acknowledgement can still cancel it, rather than in a buffer
that would block the write while the other end is not reading. The robot (`btf-robot run`),
the host (`listen`, `cmd`, `linktest`) and the demo all run their link through this class.
"""
from __future__ import annotations

import time
from typing import Callable

from radio.link import Event, Link, LinkStats
from radio.ports import Port

MAX_WRITE = 1024  # bytes a step may leave in the port's output queue


class LinkPump:
    """A Link bound to a port. A turn is `read`, acting on its events (storing what was
    delivered, queueing replies), then `write`; `step` is both when there is nothing to do."""

    def __init__(self, link: Link, port: Port, clock: Callable[[], float] = time.monotonic,
                 max_write: int = MAX_WRITE, chunk: int = 4096) -> None:
        self.link, self.port, self.clock = link, port, clock
        self.max_write, self.chunk = max_write, chunk

    def send(self, payload: bytes, reliable: bool = True, msg_id: int | None = None,
             now: float | None = None) -> int:
        """Queue a message on the link (see `Link.send`); returns its id."""
        return self.link.send(payload, self.clock() if now is None else now, reliable, msg_id)

    def read(self, now: float | None = None) -> list[Event]:
        """Feed what arrived (waiting at most the port's timeout for it) to the link; the
        events it raised. Act on them before `write`: that is what acknowledges a delivery."""
        return self.feed(self._read_port(), now)

    def write(self, now: float | None = None) -> None:
        """Write what the link has due: acknowledgements, retransmissions, new data, paced."""
        out = self.due(self.room(), now)
        if out:
            self.port.write(out)

    # A caller that keeps the port on a thread of its own (the station's event loop must not
    # wait on it) splits a turn in two: `transfer` there, `feed` and `due` where the link lives.
    def transfer(self, out: bytes) -> tuple[bytes, int]:
        """The port's half of a turn: write `out` (what `due` returned), then read what arrived,
        waiting at most the port's timeout; (bytes read, room for the next `due`)."""
        if out:
            self.port.write(out)
        return self._read_port(), self.room()

    def feed(self, data: bytes, now: float | None = None) -> list[Event]:
        """The link's half of `read`: bytes from the port in, the link's events out."""
        if data:
            self.link.receive(data, self.clock() if now is None else now)
        return self.link.pop_events()

    def due(self, room: int, now: float | None = None) -> bytes:
        """The link's half of `write`: at most `room` bytes it has to send now."""
        return self.link.poll(self.clock() if now is None else now, room)

    def _read_port(self) -> bytes:
        return self.port.read(min(max(self.port.in_waiting, 1), self.chunk))

    def step(self, now: float | None = None) -> list[Event]:
        """`read`, then `write`, for a caller with nothing to do in between."""
        events = self.read(now)
        self.write(now)
        return events

    def room(self) -> int:
        """Bytes this step may write."""
        queued = getattr(self.port, "out_waiting", 0)  # pyserial's socket:// does not report it
        return max(0, self.max_write - queued)

    @property
    def up(self) -> bool:
        return self.link.up

    def stats(self) -> LinkStats:
        return self.link.stats()

    def close(self) -> None:
        self.port.close()
