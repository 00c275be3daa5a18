"""A serial cable made of two real pseudo-terminal pairs: each end is a pty path a process opens
like a serial device (the robot one end, the station the other). `btf-host station --demo` and
the tests that run the robot and the host as separate processes use it; `cut()` takes the cable
out of range and `restore()` brings it back, as a radio link comes and goes."""
from __future__ import annotations

import os
import select
import threading
import tty


class PtyCable:
    """Two pty pairs joined master to master by a thread: `paths[0]` and `paths[1]` are the two
    ends. What one end writes while nobody reads the other is dropped once the pty's buffer is
    full, as a radio drops it (a reader that is down never stalls the cable); while the cable is
    cut, everything either end writes is dropped."""

    def __init__(self) -> None:
        self.ends = [os.openpty() for _ in range(2)]
        for m, s in self.ends:
            tty.setraw(m)
            tty.setraw(s)
            os.set_blocking(m, False)
        self.paths = [os.ttyname(s) for _, s in self.ends]
        self._stop = threading.Event()
        self._connected = threading.Event()
        self._connected.set()
        self._thread = threading.Thread(target=self._pump, daemon=True)
        self._thread.start()

    @property
    def connected(self) -> bool:
        return self._connected.is_set()

    def cut(self) -> None:
        """Out of range: from now on nothing crosses (what either end writes is lost)."""
        self._connected.clear()

    def restore(self) -> None:
        self._connected.set()

    def _pump(self) -> None:
        a, b = self.ends[0][0], self.ends[1][0]
        peer = {a: b, b: a}
        while not self._stop.is_set():
            for fd in select.select([a, b], [], [], 0.05)[0]:
                try:
                    data = os.read(fd, 4096)
                    if self._connected.is_set():
                        os.write(peer[fd], data)
                except OSError:  # EAGAIN: the far end's buffer is full (nobody reads it); EIO
                    pass

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        for m, s in self.ends:
            os.close(m)
            os.close(s)
