"""`btf-robot`: the robot's command line.

Each subcommand lives in its own module `onboard/cli/<name>.py`, exposing
`add_arguments(parser)` and `run(args) -> int`, run by `onboard.cli.runner`
(shared with `btf-host`). A configuration or usage problem raises `CliError`:
one line, exit status 2.
"""
from __future__ import annotations

import argparse

from onboard.cli import runner
from onboard.cli.runner import Subcommand

PROG = "btf-robot"
COMMANDS: tuple[Subcommand, ...] = (
    Subcommand("run", "run the robot: sweeps, remote commands, the outbox and the failsafe",
               "run --config robot.toml --port /dev/ttyUSB0"),
    Subcommand("calibrate", "calibrate the arm against the tracker, check the tracker's mounting, or choose "
                            "the sweep's exposure", "calibrate arm --config robot.toml"),
    Subcommand("selftest", "exercise every device once and print one JSON line per device",
               "selftest --config robot.toml"),
)
DESCRIPTION = "The robot of btfscout: measure views of a clutter sample and send their models to the base."


def build_parser() -> argparse.ArgumentParser:
    """The whole parser, every subcommand's arguments included."""
    return runner.build_parser(PROG, "onboard.cli", COMMANDS, DESCRIPTION)


def main(argv: list[str] | None = None) -> int:
    return runner.main(PROG, "onboard.cli", COMMANDS, DESCRIPTION, argv)

