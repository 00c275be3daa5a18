"""What keeps the operator's page from being a way to stop the station, whoever connects to it:
the station's loop also turns the link and serves `cmd`, so no client of the page may take its
file descriptors, its memory or its loop.

- Connections: at most `connection_cap()` open at once (a share of the process's descriptor
  limit). One past it is answered `503` in one line and closed at once, its descriptor freed
  before more arrive (`ConnectionGate`, the listening socket's protocol factory).
- Time: a connection must send a whole request's headers within HEADER_TIMEOUT_S of opening, or
  of its previous request's end, or it is closed (a client that sends half a header and waits
  holds nothing for long); an idle keep-alive connection is closed the same way.
- Host: a request must name this page's own address in its `Host` header (`HostCheck`), so that
  a web page on another name whose DNS was pointed at this machine (DNS rebinding) cannot read it.
- Bad requests (a header or an address of 1 MiB, garbage): aiohttp answers 400 and logs the
  error with its traceback; `QuietLog` counts them instead.

Every refusal is counted and said in one line a second at most per kind (`Tally`), with how
many came meanwhile: the station's log, never a traceback.
"""
from __future__ import annotations

import asyncio
import ipaddress
import logging
import resource
from collections import Counter
from typing import Callable, Iterable
from urllib.parse import urlsplit

MAX_CONNECTIONS = 256  # open at once, however high the descriptor limit
RESERVED_FDS = 128  # descriptors left to the station itself (port, database, log, socket, workers)
HEADER_TIMEOUT_S = 15.0  # a request's headers must have arrived within this
BODY_TIMEOUT_S = 15.0  # a command's body too
SAY_EVERY_S = 1.0  # a kind of refusal is said at most this often
_LOOPBACK_NAMES = ("localhost",)


def connection_cap(fd_limit: int | None = None) -> int:
    """Page connections open at once: half the descriptors the station has not reserved for
    itself, at most MAX_CONNECTIONS (`fd_limit`: the soft RLIMIT_NOFILE, this process's if None)."""
    if fd_limit is None:
        fd_limit = resource.getrlimit(resource.RLIMIT_NOFILE)[0]
    if fd_limit == resource.RLIM_INFINITY:
        fd_limit = 1 << 20
    return max(8, min(MAX_CONNECTIONS, (fd_limit - RESERVED_FDS) // 2))


def _refusal(text: str) -> bytes:
    body = (text + "\n").encode()
    return (b"HTTP/1.1 503 Service Unavailable\r\nContent-Type: text/plain; charset=utf-8\r\n"
            b"Content-Length: %d\r\nConnection: close\r\n\r\n" % len(body)) + body


class _Refused(asyncio.Protocol):
    """A connection past the cap: one line and closed, without reading it."""

    def __init__(self, text: str) -> None:
        self.text = text

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        transport.write(_refusal(self.text))
        transport.close()


class _Held(asyncio.Protocol):
    """One open connection: aiohttp's protocol behind it, counted by the gate and closed when its
    headers are late."""

    def __init__(self, inner: asyncio.Protocol, gate: ConnectionGate) -> None:
        self.inner, self.gate = inner, gate
        self.transport: asyncio.Transport | None = None
        self._deadline: asyncio.TimerHandle | None = None

    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport
        self.gate.held[transport] = self
        self.wait_for_headers()
        self.inner.connection_made(transport)

    def wait_for_headers(self) -> None:
        self.stop_waiting()
        self._deadline = asyncio.get_running_loop().call_later(self.gate.header_timeout, self._late)

    def stop_waiting(self) -> None:
        if self._deadline is not None:
            self._deadline.cancel()
            self._deadline = None

    def _late(self) -> None:
        self._deadline = None
        self.gate.tally.add(f"page: connections closed, no whole request within {self.gate.header_timeout:g} s")
        if self.transport is not None:
            self.transport.abort()

    def data_received(self, data: bytes) -> None:
        self.inner.data_received(data)

    def eof_received(self) -> bool | None:
        return self.inner.eof_received()

    def pause_writing(self) -> None:
        self.inner.pause_writing()

    def resume_writing(self) -> None:
        self.inner.resume_writing()

    def connection_lost(self, exc: Exception | None) -> None:
        self.stop_waiting()
        self.gate.closed(self)
        self.inner.connection_lost(exc)


class ConnectionGate:
    """The page's protocol factory: aiohttp's (`factory`) while fewer than `cap` connections are
    open; past it, a one-line 503 and the connection closed; each counted in `tally`."""

    def __init__(self, factory: Callable[[], asyncio.Protocol], cap: int, tally: Tally,
                 header_timeout: float = HEADER_TIMEOUT_S) -> None:
        self.factory, self.cap, self.tally, self.header_timeout = factory, cap, tally, header_timeout
        self.open = 0
        self.held: dict[asyncio.BaseTransport, _Held] = {}

    def __call__(self) -> asyncio.Protocol:
        if self.open >= self.cap:
            self.tally.add(f"page: connections refused past its most of {self.cap} open")
            return _Refused(f"the station's page has {self.open} connections open, its most: try again later")
        self.open += 1
        return _Held(self.factory(), self)

    def closed(self, held: _Held) -> None:
        self.open -= 1
        self.held.pop(held.transport, None)

    def request_began(self, transport: asyncio.BaseTransport | None) -> None:
        """Its headers arrived: no deadline while the request is served (an event stream lasts)."""
        if transport in self.held:
            self.held[transport].stop_waiting()

    def request_ended(self, transport: asyncio.BaseTransport | None) -> None:
        """The next request's headers (or the end of the connection) are due within the timeout."""
        if transport in self.held:
            self.held[transport].wait_for_headers()


class HostCheck:
    """Which `Host` headers name this page: the address it is bound to, `names` (--http-host),
    `localhost` when bound to a loopback address, and when bound to every address (0.0.0.0,
    ::) any IP address (a rebinding attack needs a name of its own, never a bare address)."""

    def __init__(self, bound: str, names: Iterable[str] = ()) -> None:
        self.bound = bound.strip("[]").lower()
        self.names = {self.bound, *(n.strip().lower() for n in names if n.strip())}
        ip = _ip(self.bound)
        if self.bound in _LOOPBACK_NAMES or (ip is not None and ip.is_loopback):
            self.names.update(_LOOPBACK_NAMES)
        self.any_ip = ip is not None and ip.is_unspecified
        if self.any_ip:
            self.names.update(_LOOPBACK_NAMES)

    def refuses(self, host: str | None) -> str:
        """Why a request with this `Host` header is refused ('' when it is not; a request with
        none comes from no browser, so it is not refused)."""
        if host is None:
            return ""
        try:
            name = urlsplit("//" + host).hostname or ""
        except ValueError:
            name = ""
        if name in self.names or (self.any_ip and _ip(name) is not None):
            return ""
        shown = host if len(host) <= 80 else host[:77] + "..."
        served = sorted(n for n in self.names if not (_ip(n) and _ip(n).is_unspecified))
        served = (["any IP address"] if self.any_ip else []) + served
        return (f"Host {shown} is not this page's address ({', '.join(served)}): to serve it under another "
                "name, start the station with --http-host NAME")


def host_name(text: str) -> str:
    """A name given to --http-host, as a Host header carries it (lower case, no port); ValueError
    in one line when it is not a host name."""
    name = text.strip().lower()
    try:
        parsed = urlsplit("//" + name).hostname
    except ValueError:
        parsed = None
    if not name or parsed != name.strip("[]") or any(c in name for c in "/?#@ "):
        raise ValueError(f"--http-host {text!r}: expected a host name (station.local) or an address, without a port")
    return parsed


def _ip(text: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address | None:
    try:
        return ipaddress.ip_address(text)
    except ValueError:
        return None


class Tally:
    """Refusals counted by kind and said in one line per kind at most once a second, with how many
    came meanwhile and since the start (`flush` says what a burst left unsaid)."""

    def __init__(self, say: Callable[[str], None], clock: Callable[[], float]) -> None:
        self.say, self.clock = say, clock
        self.counts: Counter[str] = Counter()
        self._unsaid: Counter[str] = Counter()
        self._last: dict[str, str] = {}
        self._said_at: dict[str, float] = {}

    def add(self, kind: str, detail: str = "") -> None:
        self.counts[kind] += 1
        self._unsaid[kind] += 1
        self._last[kind] = detail
        self._say(kind)

    def flush(self) -> None:
        for kind in list(self._unsaid):
            self._say(kind)

    def _say(self, kind: str) -> None:
        now = self.clock()
        if now - self._said_at.get(kind, -1e9) < SAY_EVERY_S:
            return
        n, detail = self._unsaid.pop(kind), self._last.pop(kind, "")
        self._said_at[kind] = now
        self.say(f"{kind}: {n} ({self.counts[kind]} since the start)" + (f"; the last: {detail}" if detail else ""))


class QuietLog(logging.Handler):
    """aiohttp's per-request error records (a malformed request, with its traceback) counted in
    `tally` as bad requests, the error's first line kept; never a traceback on stderr."""

    KIND = "page: bad requests refused"

    def __init__(self, tally: Tally) -> None:
        super().__init__(logging.WARNING)
        self.tally = tally

    def emit(self, record: logging.LogRecord) -> None:
        exc = record.exc_info[1] if record.exc_info else None
        why = record.getMessage() if exc is None else getattr(exc, "message", None) or str(exc)
        why = " ".join(str(why).split())  # one line, whatever the client sent
        self.tally.add(self.KIND, why if len(why) <= 160 else why[:157] + "...")

    def attach(self) -> None:
        logger = logging.getLogger("aiohttp.server")
        logger.addHandler(self)
        logger.propagate = False  # not to the last-resort handler, which prints each traceback

    def detach(self) -> None:
        logger = logging.getLogger("aiohttp.server")
        logger.removeHandler(self)
        if not logger.handlers:
            logger.propagate = True
