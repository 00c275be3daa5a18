"""The command-line runner both CLIs share: `btf-robot` (onboard.cli) and `btf-host` (tools.cli).

A CLI is a package of subcommand modules `<package>/<name>.py`, each exposing
`add_arguments(parser)` and `run(args) -> int`, and a table of `Subcommand`s that says what each
does; only the module of the command being run is imported. A configuration or usage problem raises
`CliError`: one line, exit status 2 (restarting cannot mend it); a broken environment (a full
disk, a device not there yet) raises `RetryLater`: one line, exit status 1 (a supervisor
restarts it). Ctrl-C is status 130, and a reader that went away
(`... | head`) ends the command quietly with 141, as the shell's own tools do.
"""
from __future__ import annotations

import argparse
import importlib
import math
import os
import re
import sys
import textwrap
from collections.abc import Callable
from dataclasses import dataclass


class CliError(Exception):
    """A problem with the user's input or configuration: one line, exit status 2."""


class RetryLater(Exception):
    """The environment is broken (a full disk, a device not there yet): one line, exit status 1."""


class HelpFormatter(argparse.HelpFormatter):
    """argparse's formatter, but a description or epilog keeps its line breaks (an example
    stays on its own line) while each line is still wrapped to the terminal."""

    def _fill_text(self, text: str, width: int, indent: str) -> str:
        return "\n".join(textwrap.fill(line, width, initial_indent=indent, subsequent_indent=indent)
                         if line.strip() else "" for line in text.splitlines())


class Parser(argparse.ArgumentParser):
    """argparse's parser, but a usage error is one line: the problem, and where the options are
    told (argparse's own prints the usage first)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {usage_line(message, self.prog)}\n")


# argparse's "argument --x: VALUE: problem" from a `bounded` type: said as "--x VALUE: problem".
_VALUE_REFUSED = re.compile(r"argument (\S+): (\S+): (.+)", re.DOTALL)


def usage_line(message: str, prog: str) -> str:
    """argparse's message as one line naming the option, the value and the fix."""
    refused = _VALUE_REFUSED.fullmatch(message)
    if refused:
        option = refused[1].split("/")[-1]
        return " ".join(f"{option} {refused[2]}: {refused[3]}".split())
    message = re.sub(r"^argument (\S+): ", lambda m: m[1].split("/")[-1] + ": ", message)
    told = "" if "choose from" in message else f" ('{prog} --help' lists the options)"
    return " ".join(message.split()) + told


def bounded(kind: type, lo: float, hi: float | None = None, unit: str = "") -> Callable[[str], float]:
    """An argparse type: a finite `kind` (int or float) in lo..hi (from lo up when hi is None);
    anything else is refused with the range, at parse time."""
    said = f" {unit}" if unit else ""
    if hi is None:
        want = f"must be at least {number_text(lo)}{said}"
    else:
        want = f"must lie in {number_text(lo)}..{number_text(hi)}{said}"

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text}: not {'a whole' if kind is int else 'a'} number; "
                                             f"{want}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"{text}: not a finite number; {want}")
        if value < lo or (hi is not None and value > hi):
            raise argparse.ArgumentTypeError(f"{text}: {want}")
        return value

    parse.__name__ = kind.__name__
    return parse


def number_text(v: float) -> str:
    """A bound as a person writes it: 4294967295, 0.1, 1e-06."""
    return str(int(v)) if float(v).is_integer() and abs(v) < 1e16 else f"{v:g}"


SEED = bounded(int, 0, 2**32 - 1)  # any seed numpy's generators take, said as a range


@dataclass(frozen=True, slots=True)
class Subcommand:
    """A subcommand as `--help` lists it: its module's name, one line saying what it does, and
    one example command line (without the program's name)."""

    name: str
    summary: str
    example: str


def build_parser(prog: str, package: str, commands: tuple[Subcommand, ...], description: str,
                 chosen: str | None = None) -> argparse.ArgumentParser:
    """The parser; only the `chosen` subcommand's module is imported for its arguments (all of
    them when None), so listing the subcommands imports none of them."""
    parser = Parser(prog=prog, description=description, formatter_class=HelpFormatter,
                    epilog=f"'{prog} COMMAND --help' shows a command's options and an example.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for c in commands:
        p = sub.add_parser(c.name, help=c.summary, description=c.summary[:1].upper() + c.summary[1:] + ".",
                           epilog=f"example:\n  {prog} {c.example}",
                           formatter_class=HelpFormatter)
        if chosen in (None, c.name):
            module = importlib.import_module(f"{package}.{c.name.replace('-', '_')}")
            module.add_arguments(p)
            p.set_defaults(_run=module.run)
    return parser


def chosen_command(argv: list[str], commands: tuple[Subcommand, ...]) -> str:
    """The subcommand `argv` names ("" when none does, as for a bare `--help`)."""
    names = {c.name for c in commands}
    first = next((a for a in argv if not a.startswith("-")), "")
    return first if first in names else ""


# Exit status of a command whose reader went away (`... | head`): 128 + SIGPIPE, as the shell's tools.
BROKEN_PIPE = 141


def main(prog: str, package: str, commands: tuple[Subcommand, ...], description: str,
         argv: list[str] | None, bad_input: tuple[type[Exception], ...] = ()) -> int:
    """Parse `argv` (sys.argv when None) and run the subcommand it names; the exit status.
    `bad_input`: more exceptions that are one line and status 2 wherever a subcommand meets them
    (the host's damaged database)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser(prog, package, commands, description, chosen_command(argv, commands))
    return run_cli(parser, argv, bad_input)


def run_cli(parser: argparse.ArgumentParser, argv: list[str] | None,
            bad_input: tuple[type[Exception], ...] = ()) -> int:
    try:
        try:
            args = parser.parse_args(argv)
        except SystemExit as done:  # --help, or a usage error (its one line said): the status
            sys.stdout.flush()  # the help too may meet a closed pipe
            return done.code if isinstance(done.code, int) else 2
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
