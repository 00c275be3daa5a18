"""`btf-host station`: the one process that owns the radio (`tools.station.station`), and with `--http`
the operator's page (`tools.page.server`); `--demo` runs it on a fake robot (`tools.demo.station_demo`)."""
from __future__ import annotations

import argparse
from pathlib import Path

from onboard.cli.runner import bounded
from tools.cli.options import BAUD, CliError
from tools.station.start import open_station, serve_to_exit

DEMO_HTTP = "127.0.0.1:8765"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = ("Holds the port for as long as it runs, stores every packet before its acknowledgement leaves, "
                     "and serves 'btf-host cmd' and 'watch' over a local socket beside the database (DB.sock); logs to"
                     " DB.log and stderr. With --http, serves the operator's page too. Needs --port, --db and --key, or --demo (a fake "
                     "robot with its own key and database).")
    add_station_options(p, required=False)
    p.add_argument("--status-every", type=bounded(float, 0, 86400, "s"), default=10.0, metavar="S",
                   help="ask the robot for its STATUS every S seconds while the link is up (0: never)")
    p.add_argument("--http", metavar="[ADDR:]PORT",
                   help="serve the operator's page at ADDR:PORT (ADDR 127.0.0.1 unless given; PORT 0: any free "
                        "one); its address with the token is printed on stderr")
    p.add_argument("--http-public", action="store_true",
                   help="anyone who reaches the page may watch without the token (commands still need it)")
    p.add_argument("--http-host", action="append", default=[], metavar="NAME",
                   help="a name the page is reached by, besides its address (repeat for more): a request "
                        "whose Host header names anything else is refused")
    p.add_argument("--robot-config", metavar="ROBOT_TOML",
                   help="the robot's config, when it is a fake one: the page shows its renders as measured frames")
    p.add_argument("--demo", nargs="?", const="station-demo", metavar="DIR",
                   help="run a fake robot on a pty cable and this station with its page (--http, default "
                        f"{DEMO_HTTP}); key, config and database in DIR (default ./station-demo)")


def add_station_options(p: argparse.ArgumentParser, required: bool = True, log: bool = True) -> None:
    """The options of whatever holds the port as the station: `station`, `listen` (no --log)."""
    unless = "" if required else "; required unless --demo"
    p.add_argument("--port", required=required, help="pyserial URL: /dev/ttyUSB0, a pty path, socket://host:port, "
                   f"btfsim://?port=URL&loss=0.2 (a simulated lossy radio){unless}")
    p.add_argument("--db", required=required, help=f"SQLite database (created if missing){unless}")
    p.add_argument("--key", required=required, help=f"link key file (btf-host keygen){unless}")
    p.add_argument("--baud", type=BAUD, default=115200, help="the serial port's speed, bits/s (default 115200)")
    p.add_argument("--scene", default="", help="scene name to file the captures under")
    p.add_argument("--socket", help="control socket path (default: DB.sock)")
    if log:
        p.add_argument("--log", help="JSON-lines log (default: DB.log)")


def page_options(args: argparse.Namespace, default: str | None = None):
    """The page's options from --http, --http-public, --http-host and --robot-config (None: no page)."""
    given = args.http or default
    if given is None:
        if args.http_public or args.robot_config or args.http_host:
            raise CliError("--http-public, --http-host and --robot-config are options of the page: "
                           "give --http [ADDR:]PORT")
        return None
    # heavy (aiohttp): loaded to serve the page, not for --help or a station without one
    from onboard.config import load
    from tools.page.guard import host_name
    from tools.page.server import PageOptions, parse_http

    try:
        host, port = parse_http(given)
        hosts = tuple(host_name(name) for name in args.http_host)
        fake = None if args.robot_config is None else load(args.robot_config).fake_hal
    except ValueError as exc:  # onboard.config.ConfigError too
        raise CliError(str(exc)) from None
    if args.robot_config and fake is None:
        raise CliError(f"--robot-config {args.robot_config}: not a fake robot's ([hal] body = \"fake\")")
    return PageOptions(host, port, public=args.http_public, fake=fake, hosts=hosts)


def run(args: argparse.Namespace) -> int:
    if args.demo is not None:
        if any(v is not None for v in (args.port, args.db, args.key)):
            raise CliError("--demo runs its own robot, key and database: leave out --port, --db and --key")
        from tools.demo.station_demo import run_demo  # the fake robot and its drawing: only with --demo

        return run_demo(Path(args.demo), page_options(args, DEMO_HTTP), args.status_every)
    missing = [f"--{k}" for k in ("port", "db", "key") if getattr(args, k) is None]
    if missing:
        raise CliError(f"{', '.join(missing)} required (or --demo for a fake robot)")
    page = page_options(args)
    parts = open_station(args.port, args.key, args.db, baud=args.baud, scene=args.scene, sock=args.socket,
                         log=args.log, status_every=args.status_every)
    return serve_to_exit(parts, page)
