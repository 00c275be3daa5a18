"""The station's event bus: every event reaches every subscriber, in order, through a bounded
queue of the subscriber's own.

A subscriber that falls behind (a slow control-socket client, a browser tab in the background)
never slows the station or the other subscribers: when its queue is full the oldest event is
dropped, and the next thing it reads is a `LostEvent` (`tools.station.events`) of n, the events
dropped since it last read, followed by the events that were kept. Everything here runs on the
station's event loop (no locks).
"""
from __future__ import annotations

import asyncio
import time
from collections import deque

from tools.station.events import Event, LostEvent  # shared by every subscriber: frozen
DEFAULT_QUEUE = 256


class Subscription:
    """One subscriber's queue; `await get()` for the next event (or the lost notice)."""

    def __init__(self, bus: EventBus, maxsize: int) -> None:
        if maxsize < 1:
            raise ValueError(f"a subscriber's queue holds at least one event, got {maxsize}")
        self._bus, self.maxsize = bus, maxsize
        self._queue: deque[Event] = deque()
        self._ready = asyncio.Event()
        self._lost = 0  # dropped since the last read
        self.lost_total = 0
        self.closed = False

    def put(self, event: Event) -> None:
        """The bus's side: queue `event`, dropping the oldest one when full."""
        if len(self._queue) >= self.maxsize:
            self._queue.popleft()
            self._lost += 1
            self.lost_total += 1
        self._queue.append(event)
        self._ready.set()

    def get_nowait(self) -> Event | None:
        """The next event, the lost notice first if events were dropped; None when empty."""
        if self._lost:
            n, self._lost = self._lost, 0
            return LostEvent(time.time(), f"{n} events dropped: this subscriber fell behind", count=n)
        if self._queue:
            return self._queue.popleft()
        return None

    async def get(self) -> Event:
        """Wait for the next event; EOFError once the subscription is closed and drained."""
        while True:
            event = self.get_nowait()
            if event is not None:
                return event
            if self.closed:
                raise EOFError("subscription closed")
            self._ready.clear()
            await self._ready.wait()

    def __len__(self) -> int:
        return len(self._queue)

    def close(self) -> None:
        """Unsubscribe; a waiting `get` ends with EOFError."""
        self.closed = True
        self._bus.unsubscribe(self)
        self._ready.set()


class EventBus:
    def __init__(self, maxsize: int = DEFAULT_QUEUE) -> None:
        self.maxsize = maxsize
        self._subscribers: list[Subscription] = []

    def subscribe(self, maxsize: int | None = None) -> Subscription:
        sub = Subscription(self, self.maxsize if maxsize is None else maxsize)
        self._subscribers.append(sub)
        return sub

    def unsubscribe(self, sub: Subscription) -> None:
        if sub in self._subscribers:
            self._subscribers.remove(sub)

    def publish(self, event: Event) -> None:
        for sub in self._subscribers:
            sub.put(event)

    @property
    def subscribers(self) -> int:
        return len(self._subscribers)
