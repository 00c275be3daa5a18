"""`btf-host`: the base-station command line.

Each subcommand lives in its own module `tools/cmd_<name>.py`, exposing
`add_parser(subparsers)` and `run(args) -> int`. Bad input raises `CliError`,
which prints one line and exits with status 2.
"""
from __future__ import annotations

import argparse
import importlib
import sys

PROG = "btf-host"
# Subcommand modules, in the order --help lists them.
COMMANDS: tuple[str, ...] = (
    "fit",
    "mask",
    "synth",
    "ingest",
    "compare",
    "pdfs",
    "resolve",
    "keygen",
    "linktest",
    "demo",
    "listen",
    "decode",
    "cmd",
    "report",
)


class CliError(Exception):
    """A problem with the user's input: printed as one line, exit status 2."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        module = importlib.import_module(f"tools.cmd_{name.replace('-', '_')}")
        sub_parser = module.add_parser(sub)
        sub_parser.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args._run(args) or 0)
    except CliError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
