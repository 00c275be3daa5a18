"""Ports a link runs over, each named by a pyserial URL: a device (`/dev/ttyUSB0`), a pty path,
`loop://`, `socket://host:port`, or `btfsim://?...` (the seeded lossy radio of
`radio.channel_port`, wrapping any of the others). `FdPort` is a raw file descriptor, e.g. the
master side of a pseudo-terminal, which has no path to open by URL."""
from __future__ import annotations

import fcntl
import os
import select
import sys
import termios
from typing import Protocol

HANDLERS = "radio.urlhandler"  # holds protocol_btfsim: pyserial looks up `btfsim://` there


class Port(Protocol):
    """What a link pump needs of a port: pyserial's read/write/in_waiting/close, and its
    timeout (seconds a read waits for the first byte)."""

    timeout: float | None

    @property
    def in_waiting(self) -> int: ...
    def read(self, size: int = 1) -> bytes: ...
    def write(self, data: bytes) -> int | None: ...
    def close(self) -> None: ...


def open_url(url: str, baudrate: int = 115200, timeout: float = 0.01, exclusive: bool = False) -> Port:
    """A pyserial port for `url`; raises pyserial's errors (or ValueError) when it cannot be opened.

    `exclusive`: hold an advisory lock on the device (flock) for as long as it is open, so a
    second process asking for it exclusively is refused (`PortBusy`); URLs without a device
    (loop://, socket://) ignore it."""
    import serial

    if HANDLERS not in serial.protocol_handler_packages:
        serial.protocol_handler_packages.append(HANDLERS)
    try:
        return serial.serial_for_url(url, baudrate=baudrate, timeout=timeout, exclusive=exclusive or None)
    except serial.SerialException as exc:
        if exclusive and "exclusively lock" in str(exc):
            raise PortBusy(f"{url} is held by another process") from None
        raise


class PortBusy(OSError):
    """Another process holds the port (opened with `exclusive`)."""


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
