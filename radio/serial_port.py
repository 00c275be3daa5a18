"""Binds a Link to a port: any pyserial URL (a device, a pty path, `loop://`) or a raw fd."""
from __future__ import annotations

import fcntl
import os
import select
import sys
import termios
import time
from typing import Callable, Protocol

from radio.link import Event, Link


class Port(Protocol):
    def read(self, size: int = 1) -> bytes: ...
    def write(self, data: bytes) -> int | None: ...
    def close(self) -> None: ...


def open_url(url: str, baudrate: int = 115200, timeout: float = 0.01) -> Port:
    """A pyserial port for `url` (`/dev/ttyUSB0`, a pty path, `loop://`, `socket://...`)."""
    import serial

    return serial.serial_for_url(url, baudrate=baudrate, timeout=timeout)


class FdPort:
    """A port over a raw file descriptor, e.g. the master side of a pseudo-terminal."""

    def __init__(self, fd: int, timeout: float = 0.01) -> None:
        self.fd, self.timeout = fd, timeout

    @property
    def in_waiting(self) -> int:
        buf = fcntl.ioctl(self.fd, termios.FIONREAD, b"\0\0\0\0")
        return int.from_bytes(buf, sys.byteorder)

    def read(self, size: int = 1) -> bytes:
        if not select.select([self.fd], [], [], self.timeout)[0]:
            return b""
        return os.read(self.fd, max(size, 1))

    def write(self, data: bytes) -> int:
        view = memoryview(data)
        while view:
            select.select([], [self.fd], [], self.timeout)
            n = os.write(self.fd, view)
            view = view[n:]
        return len(data)

    def close(self) -> None:
        os.close(self.fd)


class SerialLink:
    """Pumps bytes between a port and a Link; `step` reads what is there and writes what's due."""

    def __init__(self, link: Link, port: Port, clock: Callable[[], float] = time.monotonic,
                 chunk: int = 4096, max_write: int = 1024) -> None:
        # max_write paces the link to what a port's buffer absorbs per step, so a full
        # window never blocks a write while the other end is not reading.
        self.link, self.port, self.clock = link, port, clock
        self.chunk, self.max_write = chunk, max_write

    def step(self) -> list[Event]:
        """One read (waiting at most the port's timeout) and one write."""
        waiting = getattr(self.port, "in_waiting", 0) or 1
        data = self.port.read(min(max(waiting, 1), self.chunk))
        now = self.clock()
        events = self.link.receive(data, now) if data else self.link.pop_events()
        out = self.link.poll(now, self.max_write)
        if out:
            self.port.write(out)
        return events + self.link.pop_events()

    def close(self) -> None:
        self.port.close()
