"""The station's control socket: a local AF_UNIX stream socket beside the database
(`scene.db.sock`, mode 0600), carrying one JSON object a line each way.

Requests, and what the station answers:

- `{"op": "command", "name": "GOTO", "args": {"elevation": 70, "azimuth": 0}, "command_id": N}`
  (`command_id` optional: the station picks one) -> `{"op": "sent", "command_id": N}` at once,
  then `{"op": "answer", "command_id": N, "answer": {"ok", "type", "text", "reason"?, "extras"?}}`
  once the robot answered. A connection may have many commands outstanding.
- `{"op": "snapshot"}` -> `{"op": "snapshot", "snapshot": {...}}` (`Station.snapshot_json`).
- `{"op": "subscribe"}` -> `{"op": "subscribed", "snapshot": {...}}`, then `{"op": "event",
  "event": {...}}` for every event from then on (a `lost` event when this client fell behind).
- anything else -> `{"op": "error", "error": "..."}`; the connection stays open.

The client side (`StationClient`, blocking, for `btf-host cmd` and `watch`) is here too.
"""
from __future__ import annotations

import asyncio
import json
import os
import socket
from contextlib import suppress
from pathlib import Path
from typing import Any, Iterator

from radio.packets.commands import CommandName
from tools.station.station import Station

LINE_LIMIT = 1 << 20  # bytes in one request line
MAX_PATH = 107  # an AF_UNIX path's room on Linux, less its terminating NUL


def socket_path(db: str | os.PathLike) -> Path:
    """Where the station of database `db` listens."""
    return Path(str(db) + ".sock")


def check_path(path: Path) -> None:
    if len(os.fsencode(path)) > MAX_PATH:
        raise ValueError(f"control socket {path}: a path of {len(os.fsencode(path))} bytes, over the "
                         f"{MAX_PATH} a local socket takes; give --socket a shorter one")


class ControlServer:
    def __init__(self, station: Station, path: Path) -> None:
        self.station, self.path = station, path
        self._server: asyncio.AbstractServer | None = None
        self._tasks: set[asyncio.Task] = set()

    async def start(self) -> None:
        """Listen at `path` (a stale socket file there is replaced: the caller holds the lock).

        The new socket is bound beside it and renamed over it, so a client retrying across a
        restart always finds a file there: the killed station's, then this one's."""
        check_path(self.path)
        fresh = self.path.with_name(self.path.name + ".new")
        if len(os.fsencode(fresh)) > MAX_PATH:
            fresh = self.path  # no room for the name beside it: replace in place
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        old = os.umask(0o177)  # the socket is created 0600: only this user commands the robot
        try:
            with suppress(FileNotFoundError):
                fresh.unlink()
            sock.bind(str(fresh))
            os.replace(fresh, self.path)
        except BaseException:
            sock.close()
            raise
        finally:
            os.umask(old)
        self._server = await asyncio.start_unix_server(self._client, sock=sock, limit=LINE_LIMIT)

    async def close(self) -> None:
        if self._server is not None:
            self._server.close()
            for task in list(self._tasks):
                task.cancel()
            await asyncio.gather(*self._tasks, return_exceptions=True)
            with suppress(FileNotFoundError):
                self.path.unlink()

    async def _client(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        task = asyncio.current_task()
        self._tasks.add(task)
        self.station.snapshot.clients += 1
        lock = asyncio.Lock()
        jobs: set[asyncio.Task] = set()

        async def send(obj: dict) -> None:
            async with lock:
                writer.write(json.dumps(obj, separators=(",", ":")).encode() + b"\n")
                await writer.drain()

        try:
            while True:
                try:
                    line = await reader.readline()
                except (ValueError, asyncio.LimitOverrunError):
                    await send({"op": "error", "error": f"request longer than {LINE_LIMIT} bytes"})
                    break
                if not line:
                    break
                job = asyncio.ensure_future(self._request(line, send))
                jobs.add(job)
                job.add_done_callback(jobs.discard)
        except (ConnectionError, asyncio.CancelledError):
            pass
        finally:
            for job in list(jobs):
                job.cancel()
            self.station.snapshot.clients -= 1
            self._tasks.discard(task)
            writer.close()
            with suppress(Exception):
                await writer.wait_closed()

    async def _request(self, line: bytes, send) -> None:
        try:
            req = json.loads(line)
            op = req.get("op") if isinstance(req, dict) else None
            if op == "command":
                await self._command(req, send)
            elif op == "snapshot":
                await send({"op": "snapshot", "snapshot": self.station.snapshot_json()})
            elif op == "subscribe":
                await self._subscribe(req, send)
            else:
                await send({"op": "error", "error": f"unknown request {op!r}: command, snapshot or subscribe"})
        except (ValueError, TypeError, KeyError, RuntimeError) as exc:
            with suppress(ConnectionError):
                await send({"op": "error", "error": str(exc)})
        except ConnectionError:
            pass

    async def _command(self, req: dict, send) -> None:
        name = req.get("name")
        if name not in CommandName.__members__:
            raise ValueError(f"unknown command {name!r}: one of {', '.join(CommandName.__members__)}")
        args = req.get("args") or {}
        if not isinstance(args, dict):
            raise ValueError("args must be an object")
        cid = req.get("command_id")
        if cid is not None and (type(cid) is not int or not 0 <= cid < 2**32):
            raise ValueError(f"command_id must be an integer in 0..2**32-1, got {cid!r}")
        cid, answer = self.station.submit(CommandName[name], args, cid)
        await send({"op": "sent", "command_id": cid})
        await send({"op": "answer", "command_id": cid, "answer": await answer})

    async def _subscribe(self, req: dict, send) -> None:
        size = req.get("queue", 256)
        sub = self.station.bus.subscribe(size if type(size) is int and 1 <= size <= 65536 else 256)
        try:
            await send({"op": "subscribed", "snapshot": self.station.snapshot_json()})
            while True:
                await send({"op": "event", "event": (await sub.get()).to_json()})
        finally:
            sub.close()


class StationGone(ConnectionError):
    """The station closed the connection (it stopped, or was killed)."""


class StationClient:
    """A blocking connection to a station's control socket."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self._file = sock.makefile("rb")

    @classmethod
    def connect(cls, path: Path, timeout: float | None = None) -> StationClient | None:
        """A connection, or None when no station listens there."""
        s = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        s.settimeout(timeout)
        try:
            s.connect(str(path))
        except (FileNotFoundError, ConnectionRefusedError):
            s.close()
            return None
        except OSError:
            s.close()
            raise
        return cls(s)

    def send(self, obj: dict) -> None:
        try:
            self.sock.sendall(json.dumps(obj).encode() + b"\n")
        except (BrokenPipeError, ConnectionResetError) as exc:
            raise StationGone(str(exc)) from None

    def receive(self, timeout: float | None = None) -> dict[str, Any]:
        """The next line from the station; TimeoutError, or StationGone when it hung up."""
        self.sock.settimeout(timeout)
        try:
            line = self._file.readline()
        except ConnectionResetError as exc:
            raise StationGone(str(exc)) from None
        except socket.timeout:
            raise TimeoutError("no word from the station") from None
        if not line:
            raise StationGone("the station closed the connection")
        return json.loads(line)

    def lines(self) -> Iterator[dict[str, Any]]:
        while True:
            yield self.receive()

    def close(self) -> None:
        self._file.close()
        self.sock.close()
