"""`btf-robot`: the robot's command line.

Each subcommand lives in its own module `onboard/cmd_<name>.py`, exposing
`add_parser(subparsers)` and `run(args) -> int`. A configuration or usage problem
raises `CliError`: one line, exit status 2. `btf-host` shares this runner.
"""
from __future__ import annotations

import argparse
import importlib
import sys

PROG = "btf-robot"
COMMANDS: tuple[str, ...] = ("selftest", "run", "calibrate")


class CliError(Exception):
    """A problem with the user's input or configuration: one line, exit status 2."""


def build_parser(prog: str, package: str, commands: tuple[str, ...], description: str) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=prog, description=description)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in commands:
        module = importlib.import_module(f"{package}.cmd_{name.replace('-', '_')}")
        sub_parser = module.add_parser(sub)
        sub_parser.set_defaults(_run=module.run)
    return parser


def run_cli(parser: argparse.ArgumentParser, argv: list[str] | None) -> int:
    args = parser.parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except CliError as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


def main(argv: list[str] | None = None) -> int:
    return run_cli(build_parser(PROG, "onboard", COMMANDS, __doc__.splitlines()[0]), argv)


if __name__ == "__main__":
    sys.exit(main())
