"""`btf-robot`: the robot's command line.

Each subcommand lives in its own module `onboard/cli/<name>.py`, exposing
`add_parser(subparsers)` and `run(args) -> int`, run by `onboard.cli.runner`
(shared with `btf-host`). A configuration or usage problem raises `CliError`:
one line, exit status 2.
"""
from __future__ import annotations

from onboard.cli.runner import build_parser, run_cli

PROG = "btf-robot"
COMMANDS: tuple[str, ...] = ("selftest", "run", "calibrate")


def main(argv: list[str] | None = None) -> int:
    return run_cli(build_parser(PROG, "onboard.cli", COMMANDS, __doc__.splitlines()[0]), argv)

