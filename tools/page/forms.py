"""The operator page's command forms, generated from the command table (`radio.packets.commands`):
one form per command, one field per argument (its help as the hint, its default filled in),
and the server's side of a submitted form: the fields parsed and checked as `btf-host cmd`
parses its options, one line naming the problem otherwise."""
from __future__ import annotations

import html
from typing import Any

from radio import FrameError
from radio.packets.commands import COMMANDS, Command, CommandName, check_args


def _value(default: Any) -> str:
    if default is None:
        return ""
    if isinstance(default, (list, tuple)):
        return ",".join(f"{v:g}" if isinstance(v, float) else str(v) for v in default)
    return f"{default:g}" if isinstance(default, float) else str(default)


def _field(cmd: Command, key: str) -> str:
    arg = cmd.arg(key)
    label = arg.cli.lstrip("-")
    example = arg.help.rpartition("e.g. ")[2] if "e.g. " in arg.help else ""  # the help's example as the hint
    return (f"<label title='{html.escape(arg.help)}'>{html.escape(label)} "
            f"<input name='{html.escape(key)}' value='{html.escape(_value(arg.default))}' "
            f"placeholder='{html.escape(example)}' autocomplete=off></label>")


def _usage(cmd: Command) -> str:
    if len(cmd.key_sets()) < 2:
        return ""
    return "give " + " or ".join("/".join(cmd.arg(k).cli.lstrip("-") for k in _ordered(cmd, form))
                                 for form in cmd.key_sets())


def _ordered(cmd: Command, keys) -> list[str]:
    return [a.key for a in cmd.args if a.key in keys]


def forms_html() -> str:
    """Every command of the table as a form: `data-command` its name, a submit button named
    after its `btf-host cmd` form, and a place for the robot's answer."""
    out = []
    for cmd in COMMANDS.values():
        kind = "interrupts" if cmd.interrupts else ("moves" if cmd.moves_arm else ("query" if cmd.query else "sets"))
        fields = "".join(_field(cmd, a.key) for a in cmd.args)
        usage = _usage(cmd)
        out.append(
            f"<form class='command {kind}' data-command='{cmd.name.name}' title='{html.escape(cmd.help)}'>"
            f"<button type=submit>{html.escape(cmd.cli)}</button><span class=fields>{fields}"
            + (f"<span class=usage>{html.escape(usage)}</span>" if usage else "")
            + "</span><output class=answer></output></form>")
    return "".join(out)


def parse_form(name: Any, fields: Any) -> tuple[CommandName, dict]:
    """(command, checked arguments) from a submitted form: `name` a command of the table and
    `fields` its text fields by key (blank ones left out). ValueError, one line, for anything
    the robot would refuse or the table does not know."""
    if not isinstance(name, str) or name not in CommandName.__members__:
        raise ValueError(f"unknown command {name!r}: one of {', '.join(CommandName.__members__)}")
    cmd = COMMANDS[CommandName[name]]
    if not isinstance(fields, dict):
        raise ValueError("fields must be an object of text values")
    keys = {a.key for a in cmd.args}
    unknown = sorted(str(k) for k in fields if k not in keys)
    if unknown:
        raise ValueError(f"{cmd.cli}: no field {unknown[0]!r}")
    given = {}
    for arg in cmd.args:
        text = fields.get(arg.key)
        if text is None or (isinstance(text, str) and not text.strip()):
            if arg.default is not None:  # as `btf-host cmd` fills in an option left out
                given[arg.key] = arg.default
            continue
        if not isinstance(text, str):
            raise ValueError(f"{cmd.cli} {arg.cli.lstrip('-')}: expected text")
        try:
            given[arg.key] = arg.parse(text.strip())
        except ValueError as exc:
            raise ValueError(f"{cmd.cli} {arg.cli.lstrip('-')}: {exc}") from None
    if not any(set(given) - cmd.optional == form for form in cmd.key_sets()):
        if _usage(cmd):
            raise ValueError(f"{cmd.cli}: {_usage(cmd)}")
        missing = [cmd.arg(k).cli.lstrip("-") for k in _ordered(cmd, cmd.key_sets()[0] - set(given))]
        raise ValueError(f"{cmd.cli}: {', '.join(missing)} needed")
    try:
        check_args(cmd.name, given)
    except FrameError as exc:
        raise ValueError(f"{cmd.cli}: {exc}") from None
    return cmd.name, given
