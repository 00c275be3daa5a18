"""The command-line runner both CLIs share: `btf-robot` (onboard.cli) and `btf-host` (tools.cli).

A CLI is a package of subcommand modules `<package>/<name>.py`, each exposing
`add_parser(subparsers)` and `run(args) -> int`. A configuration or usage problem raises
`CliError`: one line, exit status 2 (restarting cannot mend it); a broken environment (a full
disk, a device not there yet) raises `RetryLater`: one line, exit status 1 (a supervisor
restarts it). Ctrl-C is status 130, and a reader that went away
(`... | head`) ends the command quietly with 141, as the shell's own tools do.
"""
from __future__ import annotations

import argparse
import importlib
import os
import sys


class CliError(Exception):
    """A problem with the user's input or configuration: one line, exit status 2."""


class RetryLater(Exception):
    """The environment is broken (a full disk, a device not there yet): one line, exit status 1."""


def build_parser(prog: str, package: str, commands: tuple[str, ...], description: str) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=prog, description=description)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in commands:
        module = importlib.import_module(f"{package}.{name.replace('-', '_')}")
        sub_parser = module.add_parser(sub)
        sub_parser.set_defaults(_run=module.run)
    return parser


# Exit status of a command whose reader went away (`... | head`): 128 + SIGPIPE, as the shell's tools.
BROKEN_PIPE = 141


def run_cli(parser: argparse.ArgumentParser, argv: list[str] | None,
            bad_input: tuple[type[Exception], ...] = ()) -> int:
    """Run the parsed subcommand; `bad_input`: more exceptions that are one line and status 2
    wherever a subcommand meets them (the host's damaged database)."""
    try:
        try:
            args = parser.parse_args(argv)
        except SystemExit:  # --help or a usage error: its text too may meet a closed pipe
            sys.stdout.flush()
            raise
        code = int(args._run(args) or 0)
        sys.stdout.flush()  # a closed pipe shows here, not at interpreter exit
        return code
    except (CliError, *bad_input) as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    except RetryLater as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        _silence_stdout()
        return BROKEN_PIPE


def _silence_stdout() -> None:
    """Point stdout at /dev/null so the interpreter's last flush does not hit the closed pipe."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):  # stdout replaced by something without a descriptor
        pass
