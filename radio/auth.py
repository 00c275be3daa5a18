"""Authentication counters: monotonic across restarts, and across a lost counters file, on
the sending side; a replay window on the receiving side.

As MAVLink's signing timestamp, a sender's counter follows the wall clock in 10 µs ticks since
2015 (`clock_counter`) whenever the clock is ahead of it, so a process that lost its counters
file starts above every counter it used before. The file still matters where the clock does
not: a sender reserves counters in blocks, writing the block's high-water mark (atomically,
fsync'd) before any counter of it is used, and starts above the last mark, so a clock that went
back is never followed into reuse. A robot without a clock it can trust and without its file
refuses to start (`CounterFileLost`): only a new key makes its counters safe again.

The receiver keeps, per (sender, link), the floor below which everything is stale (persisted at
each new session) and the last `window` counters accepted above it, so reordered frames are
accepted once and replays are not. Its file lost, the floor is the wall clock less `SKEW_S`: a
frame recorded earlier than that is refused, and a peer whose counters follow its clock is
accepted at once.
"""
from __future__ import annotations

import bisect
import json
import os
import tempfile
import threading
import time
from pathlib import Path
from typing import Callable, Protocol

from radio.events import PeerStale
from radio.frame import MAX_COUNTER, Reason

BLOCK = 1 << 20  # counters reserved per write of the file: ~10.5 s of clock ticks
EPOCH = 1420070400  # 2015-01-01 UTC, the epoch of MAVLink's signing timestamp
TICKS_PER_S = 100_000  # 10 µs ticks, as MAVLink's
CLOCK_FLOOR = 1704067200  # 2024-01-01 UTC: a wall clock earlier than this was never set
SKEW_S = 60.0  # how far the two ends' clocks may disagree (MAVLink's one minute)
STALE_RUN = 16  # authenticated frames refused in a row before the link says its peer is behind


def clock_counter(wall: float) -> int:
    """The counter the wall clock `wall` (s since 1970) stands for."""
    return min(MAX_COUNTER, max(0, int((wall - EPOCH) * TICKS_PER_S)))


def clock_trusted(wall: float) -> bool:
    """Whether a wall clock reading can be a real date (not a clock that was never set)."""
    return wall >= CLOCK_FLOOR


class CounterExhausted(RuntimeError):
    """The 48-bit counter space of a (sender, link) is used up: rotate the key."""


class CounterFileLost(ValueError):
    """No counters file to trust and no clock to start from: only a new key is safe."""


class CounterStore(Protocol):
    def next_tx(self, sender: int, link: int) -> int: ...
    def rx_floor(self, sender: int, link: int) -> int: ...
    def set_rx_floor(self, sender: int, link: int, counter: int) -> None: ...


class MemoryCounterStore:
    """Counters that live as long as the process: for simulations and tests. With a `wall`
    clock they follow it as a file's do, so a peer that lost its own file accepts them."""

    def __init__(self, start: int = 1, wall: Callable[[], float] | None = None) -> None:
        self._next: dict[tuple[int, int], int] = {}
        self._floor: dict[tuple[int, int], int] = {}
        self._start, self._wall = start, wall

    def next_tx(self, sender: int, link: int) -> int:
        c = self._next.get((sender, link), self._start)
        if self._wall is not None:
            c = max(c, clock_counter(self._wall()))
        if c > MAX_COUNTER:
            raise CounterExhausted(f"counter of sender {sender} link {link} exhausted; rotate the key")
        self._next[(sender, link)] = c + 1
        return c

    def rx_floor(self, sender: int, link: int) -> int:
        return self._floor.get((sender, link), 0)

    def set_rx_floor(self, sender: int, link: int, counter: int) -> None:
        self._floor[(sender, link)] = max(counter, self.rx_floor(sender, link))


def write_fresh(path: str | os.PathLike[str]) -> None:
    """A counters file for a key never used: nothing sent, nothing accepted (`keygen`,
    `btf-robot run --new-key`)."""
    _atomic_write(Path(path), json.dumps({"tx": {}, "rx": {}}))


class FileCounterStore:
    """Counters persisted in a small JSON file, rewritten atomically with fsync, and kept
    ahead by the wall clock where it can be trusted (`clock`: the host has one; a robot says
    in `[link] clock`). `note` says how the counters started when the file was not there."""

    def __init__(self, path: str | os.PathLike[str], block: int = BLOCK, *, clock: bool = True,
                 wall: Callable[[], float] = time.time) -> None:
        self.path = Path(path)
        self.block = block
        self._wall = wall
        self._lock = threading.Lock()
        self._reserved: dict[str, int] = {}
        self._floor: dict[str, int] = {}
        self._lost_floor = 0  # the floor of every peer when the file was lost
        self.note = ""  # how the counters started, when that needs saying
        self.save_error = ""  # the last write of the file that failed (a full disk)
        now = wall()
        self.clock = clock and clock_trusted(now)
        problem = self._load()
        if problem:
            if not self.clock:
                why = ("[link] clock = \"none\"" if not clock else
                       f"the wall clock reads {time.strftime('%Y-%m-%d', time.gmtime(now))}, never set")
                raise CounterFileLost(
                    f"counters file {self.path} {problem} and {why}: a counter of this key may be "
                    "used again; rotate the key ('btf-host keygen --out KEY --force' on the host, copy "
                    "KEY here) and start once with 'btf-robot run --new-key'")
            self._lost_floor = max(0, clock_counter(now - SKEW_S))
            self.note = (f"counters file {self.path} {problem} (a first start, or a lost file): counters "
                         f"start from the wall clock, frames older than {SKEW_S:.0f} s are refused")
        # Everything below the last reservation may have been used before a restart.
        self._next = dict(self._reserved)

    def _load(self) -> str:
        """Read the file; what is wrong with it ("" when it was read)."""
        try:
            data = json.loads(self.path.read_text())
            self._reserved = {str(k): int(v) for k, v in data.get("tx", {}).items()}
            self._floor = {str(k): int(v) for k, v in data.get("rx", {}).items()}
            return ""
        except FileNotFoundError:
            return "is missing"
        except (OSError, ValueError, TypeError, AttributeError) as exc:
            self._reserved, self._floor = {}, {}
            return f"is unreadable ({exc})"

    def next_tx(self, sender: int, link: int) -> int:
        k = f"{sender}:{link}"
        with self._lock:
            c = max(self._next.get(k, 1), 1)
            if self.clock:
                c = max(c, clock_counter(self._wall()))
            if c > MAX_COUNTER:
                raise CounterExhausted(f"counter of sender {sender} link {link} exhausted; "
                                       "rotate the key")
            held = self._reserved.get(k, 0)
            if c >= held:
                self._reserved[k] = min(c + self.block, MAX_COUNTER + 1)
                if not self._try_save() and not self.clock:
                    # Without a clock, a counter above the file's mark could be reused after a
                    # restart: send nothing until the mark is written.
                    self._reserved[k] = held
                    raise OSError(f"counters file {self.path} cannot be written: {self.save_error}")
            self._next[k] = c + 1
            return c

    def rx_floor(self, sender: int, link: int) -> int:
        return max(self._floor.get(f"{sender}:{link}", 0), self._lost_floor)

    def set_rx_floor(self, sender: int, link: int, counter: int) -> None:
        k = f"{sender}:{link}"
        with self._lock:
            if counter > self._floor.get(k, 0):
                self._floor[k] = counter
                self._try_save()  # kept in memory meanwhile; the clock floor covers a restart

    def _try_save(self) -> bool:
        try:
            _atomic_write(self.path, json.dumps({"tx": self._reserved, "rx": self._floor}, sort_keys=True))
        except OSError as exc:
            self.save_error = f"{exc.strerror or exc}"
            return False
        self.save_error = ""
        return True


def _atomic_write(path: Path, text: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    dfd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dfd)
    finally:
        os.close(dfd)


class ReplayWindow:
    """The `size` highest counters accepted, and the floor at or below which every counter is
    stale. Counted in accepted frames, not in counter values: counters that follow a clock are
    thousands apart, and a frame overtaken by a few others is still accepted once."""

    def __init__(self, size: int = 64, floor: int = 0) -> None:
        self.size = size
        self.floor = floor  # the highest counter forgotten (or the persisted session floor)
        self._seen: list[int] = []  # ascending, above the floor

    @property
    def top(self) -> int:
        return self._seen[-1] if self._seen else self.floor

    def check(self, counter: int) -> Reason | None:
        """None if `counter` is fresh; otherwise why not. Does not record it."""
        if counter <= self.floor:
            return Reason.STALE
        i = bisect.bisect_left(self._seen, counter)
        return Reason.REPLAY if i < len(self._seen) and self._seen[i] == counter else None

    def accept(self, counter: int) -> None:
        if self.check(counter) is not None:
            return
        bisect.insort(self._seen, counter)
        if len(self._seen) > self.size:
            self.floor = self._seen.pop(0)


class StaleRun:
    """Counts the peer's authenticated frames refused as stale or replayed since one was last
    accepted; at `STALE_RUN` in a row it says once, in one line, what is wrong and the remedy."""

    def __init__(self, peer: int) -> None:
        self.peer, self.run, self.said = peer, 0, False

    def accepted(self) -> None:
        self.run, self.said = 0, False

    def refused(self, reason: Reason) -> PeerStale | None:
        if reason not in (Reason.STALE, Reason.REPLAY):
            return None
        self.run += 1
        if self.run < STALE_RUN or self.said:
            return None
        self.said = True
        return PeerStale(self.peer, self.run, (
            f"every frame from node {self.peer} is refused as stale ({self.run} in a row): its "
            "counters are behind what this end accepted before (it lost its counters file, or its "
            "clock is behind); set its clock, or rotate the key ('btf-host keygen --force', copy it "
            "to the robot, start it once with 'btf-robot run --new-key')"))
