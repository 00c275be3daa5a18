"""`btf-host cmd`: one remote-control command to the robot, printing its answer.

The subcommands, their options and help come from the command table (`radio.commands`).
"""
from __future__ import annotations

import argparse
import json
import time

from radio.commands import COMMANDS, Command, CommandName
from tools.cli import CliError


def _cli_type(parse):
    """An argparse type from a table parser: a ValueError becomes argparse's own usage error."""
    def convert(text: str):
        try:
            return parse(text)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    convert.__name__ = getattr(parse, "__name__", "value")
    return convert


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser("cmd", help="send the robot a command and print its answer")
    p.add_argument("--port", required=True, help="pyserial URL of the link (btfsim://?port=URL&loss=0.2: lossy)")
    p.add_argument("--key", required=True, help="link key file")
    p.add_argument("--baud", type=int, default=115200)
    p.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for the answer")
    p.add_argument("--json", action="store_true", help="print the answer as one JSON object")
    c = p.add_subparsers(dest="what", required=True, metavar="COMMAND")
    for cmd in COMMANDS.values():
        s = c.add_parser(cmd.cli, help=cmd.help, description=cmd.help)
        required = set.intersection(*(set(f) for f in cmd.key_sets()))
        for arg in cmd.args:  # dest apart from cmd's own options (--key is the key file)
            kind = _cli_type(arg.parse)
            if arg.cli.startswith("-"):
                s.add_argument(arg.cli, dest=_dest(arg.key), type=kind, default=arg.default, help=arg.help,
                               required=arg.key in required and arg.default is None,
                               metavar=arg.metavar or arg.key.upper())
            else:
                s.add_argument(_dest(arg.key), type=kind, help=arg.help, metavar=arg.metavar or arg.cli)
    return p


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
        raise CliError(f"{cmd.cli} takes {forms}, not {named or 'none of them'}")
    for key, value in given.items():
        if isinstance(value, list) and not value:
            raise CliError(f"{cmd.cli} {cmd.arg(key).cli}: needs at least one value")
    return cmd.name, given


def _order(cmd: Command):
    keys = [a.key for a in cmd.args]
    return keys.index


def run(args: argparse.Namespace) -> int:
    from radio import packet as pk
    from tools.cmd_listen import open_session

    name, cargs = command_of(args)
    try:
        pk.encode(pk.CommandPacket(0, name, cargs))
    except ValueError as exc:
        raise CliError(f"{args.what}: {exc}") from None
    session, _ = open_session(args.port, args.key, None, args.baud)
    try:
        cid = session.command(name, cargs)
        t0 = time.monotonic()
        while cid not in session.answers:
            if time.monotonic() - t0 > args.timeout:
                raise CliError(f"no answer from the robot within {args.timeout:g} s")
            session.step()
        # One more turn so our acknowledgement of the answer goes out.
        session.step()
    finally:
        session.close()
    item = session.answers[cid]
    ok = isinstance(item.packet, pk.AckPacket)
    if args.json:
        print(json.dumps({"command": args.what, "ok": ok, **item.to_json()["packet"]}))
    else:
        extras = ", ".join(f"{k}={v}" for k, v in item.packet.extras.items())
        print(f"{item.text}" + (f" ({extras})" if extras else ""))
    return 0 if ok else 1
