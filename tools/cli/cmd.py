"""`btf-host cmd`: one remote-control command to the robot, printing its answer.

The subcommands, their options and help come from the command table (`radio.packets.commands`).
"""
from __future__ import annotations

import argparse
import json
import secrets

from onboard.cli.runner import HelpFormatter, bounded, number_text
from radio import FrameError
from radio import packets as pk
from radio.packets.base import clock_time
from radio.packets.commands import COMMANDS, Arg, Command, CommandName
from tools.cli.options import BAUD, CliError
from tools.station.command_route import ask
from tools.station.station import empty


def _cli_type(arg: Arg):
    """An argparse type from the table's argument: its parser, then its range and the robot's own
    check, so a value the robot would refuse is a usage error naming the option and its range."""
    def convert(text: str):
        unit = f" {arg.unit}" if arg.unit else ""
        want = "" if arg.limits is None else f"must lie in {number_text(arg.limits[0])}..{number_text(arg.limits[1])}{unit}"
        try:
            value = arg.parse(text)
        except ValueError as exc:  # a builtin's message names Python's types, not the option's
            said = f"not {'a whole' if arg.parse is int else 'a'} number" if arg.parse in (int, float) else str(exc)
            raise argparse.ArgumentTypeError(f"{text}: {said}" + (f"; {want}" if want else "")) from None
        values = value if isinstance(value, list) else [value]
        if arg.limits is not None and not all(arg.limits[0] <= v <= arg.limits[1] for v in values):  # NaN too
            raise argparse.ArgumentTypeError(f"{text}: {want}")
        try:
            arg.check(value)
        except FrameError as exc:
            raise argparse.ArgumentTypeError(f"{text}: {exc}") from None
        return value
    convert.__name__ = getattr(arg.parse, "__name__", "value")
    return convert


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = ("Talks to the station serving DB over its control socket (DB.sock); with no station running and "
                     "--port given, opens the port itself for this one command and stores what arrives in DB as the "
                     "station would.")
    p.add_argument("--db", help="the station's database (its control socket is DB.sock)")
    p.add_argument("--socket", help="the station's control socket, if not DB.sock")
    p.add_argument("--port", help="with no station running: the pyserial URL to open for this command "
                   "(btfsim://?port=URL&loss=0.2: lossy)")
    p.add_argument("--key", help="with no station running: the link key file")
    p.add_argument("--baud", type=BAUD, default=115200,
                   help="with no station running: the serial port's speed, bits/s (default 115200)")
    p.add_argument("--timeout", type=bounded(float, 0.1, 3600, "s"), default=10.0,
                   help="seconds to wait for the answer (default 10)")
    p.add_argument("--json", action="store_true", help="print the answer as one JSON object")
    c = p.add_subparsers(dest="what", required=True, metavar="COMMAND",
                         help="the command to send (each has its own --help)")
    for cmd in COMMANDS.values():
        s = c.add_parser(cmd.cli, help=cmd.help, description=_description(cmd),
                         epilog=f"example:\n  btf-host cmd --db scene.db {cmd.cli} {cmd.example}".rstrip(),
                         formatter_class=HelpFormatter)
        required = set.intersection(*(set(f) for f in cmd.key_sets()))
        for arg in cmd.args:  # dest apart from cmd's own options (--key is the key file)
            kind = _cli_type(arg)
            if arg.cli.startswith("-"):
                s.add_argument(arg.cli, dest=_dest(arg.key), type=kind, default=arg.default, help=arg.help,
                               required=arg.key in required and arg.default is None,
                               metavar=arg.metavar or arg.key.upper())
            else:
                s.add_argument(_dest(arg.key), type=kind, help=arg.help, metavar=arg.metavar or arg.cli)


def _description(cmd: Command) -> str:
    """What the command does, and how the robot treats it while busy (from the command table)."""
    said = [cmd.help[:1].upper() + cmd.help[1:] + "."]
    if cmd.query:
        said.append("It only reads the robot's state: answered even in failsafe.")
    if cmd.interrupts:
        said.append("It ends the pose being measured.")
    elif cmd.moves_arm:
        said.append("Refused while a pose is being measured.")
    return " ".join(said)


def _dest(key: str) -> str:
    return f"arg_{key}"


def _by_cli(what: str) -> Command:
    return next(c for c in COMMANDS.values() if c.cli == what)


def command_of(args: argparse.Namespace) -> tuple[CommandName, dict]:
    """(CommandName, args) for the parsed subcommand, in one of the command's forms."""
    cmd = _by_cli(args.what)
    given = {a.key: getattr(args, _dest(a.key)) for a in cmd.args if getattr(args, _dest(a.key)) is not None}
    if not any(set(given) - cmd.optional == form for form in cmd.key_sets()):
        forms = " or ".join("/".join(cmd.arg(k).cli for k in sorted(form, key=_order(cmd)))
                            for form in cmd.key_sets())
        named = ", ".join(cmd.arg(k).cli for k in sorted(set(given) - cmd.optional, key=_order(cmd)))
        # one form short of an option or two: name what is missing, not the whole grammar
        short = [form - set(given) for form in cmd.key_sets() if set(given) - cmd.optional < form]
        if len(short) == 1:
            missing = " and ".join(cmd.arg(k).cli for k in sorted(short[0], key=_order(cmd)))
            raise CliError(f"{cmd.cli} {named}: {missing} missing ({cmd.cli} takes {forms})")
        raise CliError(f"{cmd.cli} takes {forms}, not {named or 'none of them'}")
    for key, value in given.items():
        if isinstance(value, list) and not value:
            raise CliError(f"{cmd.cli} {cmd.arg(key).cli}: needs at least one value")
    return cmd.name, given


def _order(cmd: Command):
    keys = [a.key for a in cmd.args]
    return keys.index


def run(args: argparse.Namespace) -> int:

    name, cargs = command_of(args)
    try:
        pk.encode(pk.CommandPacket(0, name, cargs))
    except ValueError as exc:
        raise CliError(f"{args.what}: {exc}") from None
    if not args.db and not args.socket:
        raise CliError("cmd needs --db DB: the database of the station to talk to (with no station running, "
                       "where what arrives is stored)")
    if args.port and not (args.key and args.db):
        raise CliError("cmd --port (no station running) needs --key KEY and --db DB: what arrives is stored")
    answer = ask(args, name, cargs, secrets.randbits(31))
    ok = bool(answer["ok"])
    if args.json:
        print(json.dumps({"command": args.what, **answer}))
    else:
        verdict = "ACK" if ok else f"NACK {answer.get('reason')}"
        extras = ", ".join(f"{k}={_shown(k, v)}" for k, v in (answer.get("extras") or {}).items()
                           if not empty(v))  # "paused=" says nothing
        print(f"{verdict}: {answer.get('text', '')}" + (f" ({extras})" if extras else ""))
        for key, value in (answer.get("status") or {}).items():  # STATUS's report, a field a line
            if not empty(value):  # "paused: " says nothing
                print(f"  {key}: {_brief(value)}")
    return 0 if ok else 1


def _shown(key: str, value):
    """An answer's value for a person: short floats, angles to a tenth of a degree, clock times in ISO 8601."""
    if key in ("time", "since", "until") and clock_time(value) is not None:
        return clock_time(value)
    if key in ("elevation", "azimuth") and isinstance(value, float):
        return f"{value:.1f}"  # a tenth of a degree: what the tracker resolves
    return f"{value:.6g}" if isinstance(value, float) else value


def _brief(value, key: str = "") -> str:
    """A field of the robot's report (its JSON form) for a person: lists with how many older
    items they left out, records as key=value."""
    if isinstance(value, dict) and set(value) == {"items", "left_out"}:
        items = ", ".join(_brief(v) for v in value["items"]) or "none"
        return items + (f" (+{value['left_out']} older)" if value["left_out"] else "")
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}={_brief(v, k)}" for k, v in value.items() if not empty(v)) + "}"
    if isinstance(value, list):
        return "[" + ", ".join(_brief(v) for v in value) + "]"
    return str(_shown(key, value))
