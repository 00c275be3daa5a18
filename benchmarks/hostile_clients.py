"""Hostile clients of the operator's page, and what they must not take from the station: its
`cmd ping` time and its memory. Shared by `bench_hostile` and tests/tools/page/test_page_hostile.py."""
from __future__ import annotations

import resource
import socket
import statistics
import time
from pathlib import Path

FD_LIMIT = 1024  # the common default a station runs under


def limit_fds() -> None:
    """For a station's `preexec_fn`: the common descriptor limit, soft and hard."""
    resource.setrlimit(resource.RLIMIT_NOFILE, (FD_LIMIT, FD_LIMIT))


def room_for_sockets(n: int) -> tuple[int, int] | None:
    """Raise this process's soft descriptor limit to hold `n` client sockets; the limits before
    (to restore), or None when the hard limit is too low."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    want = n + 512 if hard == resource.RLIM_INFINITY else min(hard, n + 512)
    if want < n + 256:
        return None
    resource.setrlimit(resource.RLIMIT_NOFILE, (max(soft, want), hard))
    return soft, hard


class Client:
    """One connection of a hostile client, its request sent; `state()`: open (nothing said yet),
    refused (a 503, or closed without a word), else the answer's status (kept: a stream goes on)."""

    def __init__(self, address: tuple[str, int], request: bytes, source: str = "127.0.0.1") -> None:
        self.source = source
        self.sock = socket.create_connection(address, timeout=30, source_address=(source, 0))
        self.sock.sendall(request)
        self.sock.setblocking(False)
        self.answer: str | None = None

    def state(self) -> str:
        if self.answer in (None, "200"):
            try:
                data = self.sock.recv(65536)
            except BlockingIOError:
                return self.answer or "open"
            except ConnectionResetError:
                data = b""
            if self.answer is None:
                self.answer = "refused" if not data or data.startswith(b"HTTP/1.1 503") else data.split(b" ")[1].decode()
            elif not data:
                self.answer = "closed"
        return self.answer

    def close(self) -> None:
        self.sock.close()


def half_requests(address: tuple[str, int], host: str, n: int) -> list[Client]:
    """`n` connections, each half a request's headers, never finished (slowloris)."""
    half = f"GET / HTTP/1.1\r\nHost: {host}\r\nX-Slow: ".encode()
    return [Client(address, half) for _ in range(n)]


def event_streams(address: tuple[str, int], host: str, token: str, n: int, sources: int) -> list[Client]:
    """`n` event streams asked for, from `sources` loopback addresses in turn (127.0.0.2, ...)."""
    ask = f"GET /events HTTP/1.1\r\nHost: {host}\r\nX-BTF-Token: {token}\r\n\r\n".encode()
    return [Client(address, ask, f"127.0.0.{2 + i % sources}") for i in range(n)]


def until(predicate, limit_s: float) -> bool:
    end = time.monotonic() + limit_s
    while not predicate() and time.monotonic() < end:
        time.sleep(0.1)
    return bool(predicate())


def ping_s(station_socket: Path) -> float:
    """Seconds from a PING sent through the station's control socket to the robot's answer (what
    `btf-host cmd ping` waits for, without the start of a process)."""
    from tools.station.control import StationClient

    client = StationClient.connect(station_socket, timeout=30)
    if client is None:
        raise ConnectionRefusedError(f"no station at {station_socket}")
    try:
        t0 = time.perf_counter()
        client.send({"op": "command", "name": "PING", "args": {}})
        while (msg := client.receive(timeout=30))["op"] != "answer":
            pass
        if not msg["answer"]["ok"]:
            raise RuntimeError(f"PING refused: {msg['answer']}")
        return time.perf_counter() - t0
    finally:
        client.close()


def pings_s(station_socket: Path, n: int) -> list[float]:
    return [ping_s(station_socket) for _ in range(n)]


def median_ping_s(station_socket: Path, n: int = 5) -> float:
    return statistics.median(pings_s(station_socket, n))


def rss_kb(pid: int) -> int:
    """The process's resident memory (VmRSS), KiB."""
    with open(f"/proc/{pid}/status") as fh:
        return next(int(line.split()[1]) for line in fh if line.startswith("VmRSS:"))
