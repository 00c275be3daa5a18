"""Authentication counters: monotonic across restarts on the sending side, a replay window
on the receiving side.

A sender reserves counters in blocks: the high-water mark of the block is written
(atomically, fsync'd) before any counter of it is used, and a restarted process
starts above the last mark, so a process killed at any instant never reuses a
counter. The receiver keeps, per (sender, link), the highest counter accepted and
a bitmap of the `window` counters below it, so reordered frames are accepted once
and replays are not.
"""
from __future__ import annotations

import json
import os
import tempfile
import threading
from pathlib import Path
from typing import Protocol

from radio.frame import MAX_COUNTER, Reason

BLOCK = 1 << 16


class CounterExhausted(RuntimeError):
    """The 48-bit counter space of a (sender, link) is used up: rotate the key."""


class CounterStore(Protocol):
    def next_tx(self, sender: int, link: int) -> int: ...
    def rx_floor(self, sender: int, link: int) -> int: ...
    def set_rx_floor(self, sender: int, link: int, counter: int) -> None: ...


class MemoryCounterStore:
    """Counters that live as long as the process: for simulations and tests."""

    def __init__(self, start: int = 1) -> None:
        self._next: dict[tuple[int, int], int] = {}
        self._floor: dict[tuple[int, int], int] = {}
        self._start = start

    def next_tx(self, sender: int, link: int) -> int:
        c = self._next.get((sender, link), self._start)
        if c > MAX_COUNTER:
            raise CounterExhausted(f"counter of sender {sender} link {link} exhausted; rotate the key")
        self._next[(sender, link)] = c + 1
        return c

    def rx_floor(self, sender: int, link: int) -> int:
        return self._floor.get((sender, link), 0)

    def set_rx_floor(self, sender: int, link: int, counter: int) -> None:
        self._floor[(sender, link)] = max(counter, self.rx_floor(sender, link))


class FileCounterStore:
    """Counters persisted in a small JSON file, rewritten atomically with fsync."""

    def __init__(self, path: str | os.PathLike[str], block: int = BLOCK) -> None:
        self.path = Path(path)
        self.block = block
        self._lock = threading.Lock()
        self._reserved: dict[str, int] = {}
        self._floor: dict[str, int] = {}
        if self.path.exists():
            try:
                data = json.loads(self.path.read_text())
                self._reserved = {str(k): int(v) for k, v in data.get("tx", {}).items()}
                self._floor = {str(k): int(v) for k, v in data.get("rx", {}).items()}
            except (ValueError, TypeError, AttributeError) as exc:
                # Starting from zero could reuse counters: refuse instead.
                raise ValueError(f"counter file {self.path} is unreadable ({exc}); "
                                 "restore it or rotate the key") from None
        # Everything below the last reservation may have been used before a restart.
        self._next = dict(self._reserved)

    def next_tx(self, sender: int, link: int) -> int:
        k = f"{sender}:{link}"
        with self._lock:
            c = max(self._next.get(k, 1), 1)
            if c > MAX_COUNTER:
                raise CounterExhausted(f"counter of sender {sender} link {link} exhausted; "
                                       "rotate the key")
            if c >= self._reserved.get(k, 0):
                self._reserved[k] = min(c + self.block, MAX_COUNTER + 1)
                self._save()
            self._next[k] = c + 1
            return c

    def rx_floor(self, sender: int, link: int) -> int:
        return self._floor.get(f"{sender}:{link}", 0)

    def set_rx_floor(self, sender: int, link: int, counter: int) -> None:
        k = f"{sender}:{link}"
        with self._lock:
            if counter > self._floor.get(k, 0):
                self._floor[k] = counter
                self._save()

    def _save(self) -> None:
        text = json.dumps({"tx": self._reserved, "rx": self._floor}, sort_keys=True)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=self.path.parent, prefix=self.path.name, suffix=".tmp")
        try:
            with os.fdopen(fd, "w") as f:
                f.write(text)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, self.path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        dfd = os.open(self.path.parent, os.O_RDONLY)
        try:
            os.fsync(dfd)
        finally:
            os.close(dfd)


class ReplayWindow:
    """Highest accepted counter plus a bitmap of the `size` counters below it."""

    def __init__(self, size: int = 64, floor: int = 0) -> None:
        self.size = size
        self.top = floor  # counters <= floor are stale until something newer arrives
        self._bits = (1 << size) - 1  # bit i set: counter top - i already seen

    def check(self, counter: int) -> Reason | None:
        """None if `counter` is fresh; otherwise why not. Does not record it."""
        if counter > self.top:
            return None
        back = self.top - counter
        if back >= self.size:
            return Reason.STALE
        return Reason.REPLAY if (self._bits >> back) & 1 else None

    def accept(self, counter: int) -> None:
        if counter > self.top:
            shift = counter - self.top
            self._bits = ((self._bits << shift) | 1) & ((1 << self.size) - 1) if shift < self.size else 1
            self.top = counter
        else:
            self._bits |= 1 << (self.top - counter)
