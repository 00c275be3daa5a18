"""Starting a station: the checks (key, database, one station per database, the port held
exclusively), then the event loop that turns the link and serves the control socket.
`btf-host station`, `listen` and a `cmd` without a station all start one here."""
from __future__ import annotations

import asyncio
import fcntl
import os
import signal
import sys
import time
from contextlib import suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Awaitable, Callable, TextIO

from onboard.cli.runner import CliError, RetryLater
from radio.auth import FileCounterStore
from radio.keys import KeyFileError, counters_beside, load_key
from radio.link import Link
from radio.ports import PortBusy, open_url
from radio.pump import LinkPump
from tools.station.control import ControlServer, check_path, socket_path
from tools.station.events import StationEvent
from tools.station.log import StationLog
from tools.station.receiver import HOST_NODE, LINK_ID, ROBOT_NODE, Receiver
from tools.station.station import Station
from tools.store.database import CorruptDatabase, Store, StoreUnavailable


class StationBusy(CliError):
    """Another station holds this database (or, with `port`, this port)."""

    def __init__(self, text: str, port: bool = False) -> None:
        super().__init__(text)
        self.port = port


@dataclass
class StationParts:
    station: Station
    socket: Path
    store: object
    lock_fd: int

    def close(self) -> None:
        self.station.pump.close()  # closed by the station's run already, unless it never ran
        self.station.log.close()
        self.store.close()
        os.close(self.lock_fd)  # releases the lock


def lock_path(db: str | os.PathLike) -> Path:
    return Path(str(db) + ".lock")


def take_lock(db: str | os.PathLike) -> int:
    """An exclusive lock on the database's station (released when the process ends, however)."""
    path = lock_path(db)
    folder = path.parent if str(path.parent) else Path(".")
    if not folder.is_dir():  # a mistyped path: no wait mends it
        raise CliError(f"database {db}: folder {folder} does not exist; create it, or give --db a path "
                       "in one that does")
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
    except OSError as exc:  # a full disk or a read-only one: the environment (exit 1)
        raise RetryLater(f"database {db}: cannot create its station lock {path}: {exc.strerror or exc}") from None
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        held = os.read(fd, 32).decode(errors="replace").strip()
        os.close(fd)
        raise StationBusy(f"a station already runs on {db} (pid {held or '?'}); "
                          f"'btf-host cmd --db {db} ...' talks to it") from None
    try:  # the pid only tells a second station who holds the lock: a full disk may refuse it
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
    except OSError:
        pass
    return fd


def station_runs(db: str | os.PathLike) -> bool:
    """Whether a station holds the database's lock now (a killed one holds none: the kernel let go)."""
    try:
        fd = os.open(lock_path(db), os.O_RDONLY)
    except OSError:
        return False
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        os.close(fd)  # a lock taken here goes with it
    return False


def open_station(port_url: str, key_file: str, db: str, *, baud: int = 115200, scene: str = "",
                 sock: str | None = None, log: str | None = None, echo: TextIO | None = sys.stderr,
                 status_every: float = 10.0, on_item=None) -> StationParts:
    """Everything a station needs, checked; CliError (one line) for any problem, StationBusy
    when another station holds the database or the port."""
    try:
        key = load_key(key_file)
        # Counters survive restarts (replays stay refused, a running robot accepts the next
        # session) and, by the clock, a lost file; they live beside the key, shared by every
        # station and cmd speaking as this base.
        counters = FileCounterStore(counters_beside(key_file))
    except (KeyFileError, ValueError) as exc:
        raise CliError(str(exc)) from None
    path = Path(sock) if sock else socket_path(db)
    try:
        check_path(path)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    fd = take_lock(db)
    undo: list[Callable[[], None]] = [lambda: os.close(fd)]
    try:
        try:
            port = open_url(port_url, baud, timeout=0.02, exclusive=True)
        except PortBusy:
            raise StationBusy(f"port {port_url} is held by another process (a station? "
                              "'btf-host cmd --db ITS_DATABASE ...' talks to it)", port=True) from None
        except Exception as exc:
            raise CliError(f"port {port_url}: cannot open: {exc}") from None
        undo.append(port.close)
        try:
            store = Store.open(db)
        except StoreUnavailable as exc:  # a full disk, an I/O error: not the file's fault (exit 1)
            raise RetryLater(str(exc)) from None
        except CorruptDatabase as exc:
            raise CliError(str(exc)) from None
        undo.append(store.close)
        link = Link(HOST_NODE, ROBOT_NODE, LINK_ID, key, counters, heartbeat=1.0, link_timeout=5.0)
        station = Station(LinkPump(link, port), Receiver(store, scene),
                          StationLog(Path(log) if log else Path(str(db) + ".log"), echo),
                          port=port_url, db=str(db), status_every=status_every, on_item=on_item)
        if counters.note:  # the counters file was lost (or this base's first run with a key not from keygen)
            station.emit(StationEvent(time.time(), counters.note))
    except BaseException:
        for step in reversed(undo):
            step()
        raise
    return StationParts(station, path, store, fd)


async def serve(parts: StationParts, until: Callable[[], bool] | None = None, page=None,
                echo: TextIO | None = sys.stderr, beside: Callable[[Station], Awaitable[None]] | None = None) -> None:
    """Run the station and its control socket (and, given `page`, a `tools.page.server.PageOptions`,
    the operator's page) until stopped (SIGTERM, SIGINT, `until()`), or until it fails
    (`parts.station.failure`). The page's address with its token goes to `echo` only. `beside(station)`
    runs alongside for as long as the station does (the demo's watch on its robot)."""
    station = parts.station
    server = ControlServer(station, parts.socket)
    try:
        await server.start()
    except OSError as exc:
        raise CliError(f"control socket {parts.socket}: {exc.strerror or exc}") from None
    web = None
    if page is not None:
        web = await _start_page(parts, page, echo)
        if web is None:
            await server.close()
            raise CliError(f"--http {page.host}:{page.port}: cannot listen there (in use, or not this machine's)")
    loop = asyncio.get_running_loop()
    handled = []
    for sig in (signal.SIGTERM, signal.SIGINT):
        with suppress(ValueError, RuntimeError):  # not the main thread: the caller stops it
            loop.add_signal_handler(sig, station.stop)
            handled.append(sig)
    pump = asyncio.ensure_future(station.run())
    companion = None if beside is None else asyncio.ensure_future(beside(station))
    try:
        while until is not None and not pump.done():
            await asyncio.sleep(0.02)  # first: the station starts its run before `until` is asked
            if until():
                station.stop()
                break
        await pump
    finally:
        if companion is not None:
            companion.cancel()
            await asyncio.gather(companion, return_exceptions=True)
        for sig in handled:
            loop.remove_signal_handler(sig)
        if web is not None:
            await web.close()
        await server.close()


async def _start_page(parts: StationParts, options, echo: TextIO | None):
    """The page server, started (None when its address cannot be had)."""
    from tools.page.server import PageServer  # aiohttp and the drawing code: only with --http

    def announce(url: str) -> None:  # once it can draw: the station's radio runs meanwhile
        who = "anyone who can reach it watches; commands need the token" if options.public else "it needs the token"
        parts.station.emit(StationEvent(parts.station.wall(), f"page at {url} ({who})"))
        if echo is not None:  # the token goes to the operator's terminal only, never to the log file
            print(f"page: {url}?token={options.token}", file=echo, flush=True)

    web = PageServer(parts.station, parts.station.snapshot.db, options)
    try:
        await web.start(on_ready=announce)
    except OSError:
        await web.close()
        return None
    return web


def serve_to_exit(parts: StationParts, page=None, beside=None) -> int:
    """Serve until stopped, close, and turn how the station ended into the CLI's exit status
    (a failure that needs the setup fixed is a CliError: one line, exit 2)."""
    try:
        asyncio.run(serve(parts, page=page, beside=beside))
    finally:
        parts.close()
    failure = parts.station.failure
    if failure is not None and failure.status == 2:
        raise CliError(str(failure))
    return 0 if failure is None else failure.status
