"""`btf-host`: the base-station command line.

Each subcommand lives in its own module `tools/cli/<name>.py`, exposing
`add_parser(subparsers)` and `run(args) -> int`; the options several share are in
`tools.cli.options`. Bad input raises `CliError`, which prints one line and exits with
status 2.
"""
from __future__ import annotations

import argparse

from onboard.cli import runner
from tools.store.schema import CorruptDatabase

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
    "station",
    "listen",
    "cmd",
    "watch",
    "decode",
    "report",
)


def build_parser() -> argparse.ArgumentParser:
    return runner.build_parser(PROG, "tools.cli", COMMANDS, __doc__.splitlines()[0])


def main(argv: list[str] | None = None) -> int:
    # A damaged row met by any reader (synth, report, ...) is one line and status 2, as at opening.
    return runner.run_cli(build_parser(), argv, bad_input=(CorruptDatabase,))
