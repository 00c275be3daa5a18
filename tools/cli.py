"""`btf-host`: the base-station command line.

Each subcommand lives in its own module `tools/cmd_<name>.py`, exposing
`add_parser(subparsers)` and `run(args) -> int`. Bad input raises `CliError`,
which prints one line and exits with status 2.
"""
from __future__ import annotations

import argparse
import sys

from onboard import cli as onboard_cli
from onboard.cli import CliError  # noqa: F401  (subcommands raise it)

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


def build_parser() -> argparse.ArgumentParser:
    return onboard_cli.build_parser(PROG, "tools", COMMANDS, __doc__.splitlines()[0])


def main(argv: list[str] | None = None) -> int:
    return onboard_cli.run_cli(build_parser(), argv)


if __name__ == "__main__":
    sys.exit(main())
