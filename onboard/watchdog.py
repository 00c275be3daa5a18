"""systemd notification (sd_notify) over $NOTIFY_SOCKET, with the standard library only.

`READY=1` once the runtime is up, `WATCHDOG=1` at least twice per WatchdogSec while
the main loop turns. Without $NOTIFY_SOCKET (not started by systemd) every call is a
no-op, and a send that fails never stops the robot.
"""
from __future__ import annotations

import os
import socket
import time


class Notifier:
    def __init__(self, address: str | None = None, clock=time.monotonic) -> None:
        addr = os.environ.get("NOTIFY_SOCKET") if address is None else address
        if addr and addr.startswith("@"):
            addr = "\0" + addr[1:]  # abstract namespace socket
        self._address = addr or None
        self._clock = clock
        self._interval = _watchdog_interval()
        self._last = float("-inf")

    @property
    def enabled(self) -> bool:
        return self._address is not None

    def notify(self, message: str) -> bool:
        """Send one notification; True when it was delivered to systemd."""
        if self._address is None:
            return False
        try:
            with socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM) as sock:
                sock.connect(self._address)
                sock.sendall(message.encode())
            return True
        except OSError:
            return False

    def ready(self, status: str = "") -> bool:
        return self.notify("READY=1" + (f"\nSTATUS={_line(status)}" if status else ""))

    def status(self, text: str) -> bool:
        """STATUS= for `systemctl status` (one line: a newline would start another field)."""
        return self.notify(f"STATUS={_line(text)}")

    def kick(self) -> bool:
        """WATCHDOG=1, rate-limited to half the configured watchdog interval."""
        if self._interval == float("inf"):  # the watchdog is another process's
            return False
        now = self._clock()
        if now - self._last < self._interval / 2:
            return False
        self._last = now
        return self.notify("WATCHDOG=1")


def _line(text: str) -> str:
    return " ".join(str(text).split())[:200]


def _watchdog_interval() -> float:
    """WATCHDOG_USEC from systemd, in seconds (when it is meant for this process)."""
    usec = os.environ.get("WATCHDOG_USEC")
    pid = os.environ.get("WATCHDOG_PID")
    if pid and pid != str(os.getpid()):
        return float("inf")
    try:
        return max(int(usec) / 1e6, 0.01) if usec else 2.0
    except ValueError:
        return 2.0
