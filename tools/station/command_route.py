"""A command's way to the robot for `btf-host cmd`: through the station serving the database, or,
with none running, through a station of its own for as long as the command takes.

The command id is chosen here, once. When the station goes away before the answer (it was
stopped or killed), the same id is sent to the next one: the robot answers an id it has seen
from memory instead of running it again, so a command is carried out once and answered once.
"""
from __future__ import annotations

import argparse
import asyncio
import time
from pathlib import Path

from radio.packets.commands import CommandName
from tools.cli.options import CliError
from tools.station.control import StationClient, StationGone, socket_path
from tools.station.start import StationBusy, open_station, serve, station_runs


def ask(args: argparse.Namespace, name: CommandName, cargs: dict, command_id: int) -> dict:
    """The robot's answer (`{"ok", "type", "command_id", "text", ...}`) to one command."""
    path = Path(args.socket) if args.socket else socket_path(args.db)
    deadline = time.monotonic() + args.timeout
    while True:
        left = deadline - time.monotonic()
        if left <= 0 and path.exists() and args.db is not None and not station_runs(args.db):
            raise CliError(f"no station serves {args.db}: the last one ended without tidying up and none started "
                           f"within {args.timeout:g} s; start 'btf-host station --port URL --db DB --key KEY', or "
                           "give cmd --port and --key to open the port itself")
        if left <= 0:
            raise CliError(f"no answer from the robot within {args.timeout:g} s; a station keeps the command "
                           "until the robot hears it, and its log shows the answer")
        try:
            client = StationClient.connect(path, timeout=left)
        except OSError as exc:
            raise CliError(f"control socket {path}: {exc.strerror or exc}") from None
        if client is not None:
            try:
                return _through(client, name, cargs, command_id, deadline, args.timeout)
            except StationGone:
                continue  # it stopped or was killed: the next one gets the same command id
            finally:
                client.close()
        if args.port:
            try:
                return _own_station(args, name, cargs, command_id, deadline)
            except StationBusy as busy:
                if busy.port and not path.exists():
                    raise  # held by a station of another database
                time.sleep(0.05)  # another cmd is becoming this database's station: ask it
                continue
        if not path.exists():
            raise CliError(f"no station serves {args.db or path}: start 'btf-host station --port URL --db DB "
                           "--key KEY', or give cmd --port and --key to open the port itself")
        time.sleep(0.1)  # its socket is there: a station that is (re)starting, or one killed (said at the end)


def _through(client: StationClient, name: CommandName, cargs: dict, cid: int, deadline: float,
             timeout: float) -> dict:
    client.send({"op": "command", "name": name.name, "args": cargs, "command_id": cid})
    while True:
        try:
            msg = client.receive(timeout=max(0.001, deadline - time.monotonic()))
        except TimeoutError:
            raise CliError(f"no answer from the robot within {timeout:g} s; the station keeps the command "
                           "until the robot hears it, and its log shows the answer") from None
        if msg.get("op") == "answer" and msg.get("command_id") == cid:
            return msg["answer"]
        if msg.get("op") == "error":
            raise CliError(f"station: {msg.get('error')}")


def _own_station(args: argparse.Namespace, name: CommandName, cargs: dict, cid: int, deadline: float) -> dict:
    """Hold the port for this one command, serving other clients meanwhile, and store what
    arrives exactly as a station would."""
    parts = open_station(args.port, args.key, args.db, baud=args.baud, sock=args.socket, echo=None,
                         status_every=0)
    station = parts.station
    got: dict = {}

    async def command() -> None:
        _, answer = station.submit(name, cargs, cid)
        try:
            got["answer"] = await asyncio.wait_for(answer, max(0.001, deadline - time.monotonic()))
        except asyncio.TimeoutError:
            pass

    async def go() -> None:
        task = asyncio.ensure_future(command())
        # Done once answered and no other client's command is still on its way (or time is up).
        await serve(parts, until=lambda: task.done() and (
            not station.snapshot_json()["station"]["commands_pending"] or time.monotonic() > deadline))
        task.cancel()

    try:
        asyncio.run(go())
    finally:
        parts.close()
    if station.failure is not None:
        raise CliError(str(station.failure))
    if "answer" not in got:
        said = f": {station.wrong_key}" if station.wrong_key else ""
        raise CliError(f"no answer from the robot within {args.timeout:g} s{said}")
    return got["answer"]
