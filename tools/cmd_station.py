"""`btf-host station`: the one process that owns the radio (`tools.station`)."""
from __future__ import annotations

import argparse

from tools.cli import CliError


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser("station", help="own the radio: store what the robot sends, serve cmd clients and subscribers",
                       description="Holds the port for as long as it runs, stores every packet before its "
                                   "acknowledgement leaves, and serves `btf-host cmd` and `watch` over a local "
                                   "socket beside the database (DB.sock); logs to DB.log and stderr.")
    add_station_options(p)
    p.add_argument("--status-every", type=float, default=10.0, metavar="S",
                   help="ask the robot for its STATUS every S seconds while the link is up (0: never)")
    return p


def add_station_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--port", required=True, help="pyserial URL: /dev/ttyUSB0, a pty path, socket://host:port, "
                   "btfsim://?port=URL&loss=0.2 (a simulated lossy radio)")
    p.add_argument("--db", required=True, help="SQLite database (created if missing)")
    p.add_argument("--key", required=True, help="link key file (btf-host keygen)")
    p.add_argument("--baud", type=int, default=115200)
    p.add_argument("--scene", default="", help="scene name to file the captures under")
    p.add_argument("--socket", help="control socket path (default: DB.sock)")
    p.add_argument("--log", help="JSON-lines log (default: DB.log)")


def run(args: argparse.Namespace) -> int:
    import asyncio

    from tools.station_run import open_station, serve

    if args.status_every < 0:
        raise CliError(f"--status-every {args.status_every}: must not be negative")
    parts = open_station(args.port, args.key, args.db, baud=args.baud, scene=args.scene, sock=args.socket,
                         log=args.log, status_every=args.status_every)
    try:
        asyncio.run(serve(parts))
    finally:
        parts.close()
    failure = parts.station.failure
    if failure is not None:
        if failure.status == 2:
            raise CliError(str(failure))
        return failure.status
    return 0
