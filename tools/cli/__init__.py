"""`btf-host`: the base-station command line.

Each subcommand lives in its own module `tools/cli/<name>.py`, exposing
`add_parser(subparsers)` and `run(args) -> int`; the options several share are in
`tools.cli.options`. Bad input raises `CliError`, which prints one line and exits with
status 2.
"""
from __future__ import annotations

import argparse

from onboard.cli import runner

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
    "btf",
    "export",
)


def build_parser() -> argparse.ArgumentParser:
    return runner.build_parser(PROG, "tools.cli", COMMANDS, __doc__.splitlines()[0])


def main(argv: list[str] | None = None) -> int:
    return runner.run_cli(build_parser(), argv)
