"""Every command of both CLIs explains itself: a description, an example that its own parser
accepts, help for every option, and plain text (no Markdown backticks) in all of it."""
from __future__ import annotations

import argparse
import shlex

import pytest

from onboard import cli as robot_cli
from tools import cli as host_cli

CLIS = {"btf-host": host_cli.build_parser, "btf-robot": robot_cli.build_parser}


def commands(parser: argparse.ArgumentParser, path: tuple[str, ...]):
    """(path, parser) of every command and subcommand under `parser` (cmd's commands, calibrate's targets)."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield (*path, name), sub
                yield from commands(sub, (*path, name))


def every_command():
    return [pytest.param(prog, path, id=" ".join((prog, *path)))
            for prog, build in CLIS.items() for path, _ in commands(build(), ())]


def find(prog: str, path: tuple[str, ...]) -> argparse.ArgumentParser:
    return dict(commands(CLIS[prog](), ()))[path]


def test_the_walk_finds_the_nested_commands():
    host = {p for p, _ in commands(host_cli.build_parser(), ())}
    robot = {p for p, _ in commands(robot_cli.build_parser(), ())}
    assert {("cmd", "goto"), ("cmd", "sweep"), ("synth",), ("station",)} <= host
    assert {("calibrate", "arm"), ("calibrate", "tracker"), ("calibrate", "exposure"), ("run",)} <= robot


@pytest.mark.parametrize(("prog", "path"), every_command())
def test_every_command_has_a_description_and_an_example_its_parser_accepts(prog, path):
    parser = find(prog, path)
    assert parser.description and parser.description.strip().endswith("."), parser.description
    _, _, example = (parser.epilog or "").partition("example:")
    assert example.strip(), f"{parser.prog}: no example"
    argv = shlex.split(example.strip())
    argv = argv[:next((i for i, w in enumerate(argv) if w in (">", "|", "<")), len(argv))]  # the shell's part
    words = iter(argv[1:])
    assert argv[0] == prog and all(name in words for name in path), argv  # the path's names, in order
    args = CLIS[prog]().parse_args(argv[1:])  # a refusal exits here (status 2)
    assert args.command == path[0]


@pytest.mark.parametrize(("prog", "path"), every_command())
def test_every_option_has_help_and_no_text_has_a_backtick(prog, path):
    parser = find(prog, path)
    texts = [parser.description or "", parser.epilog or ""]
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        name = "/".join(action.option_strings) or action.dest
        assert action.help, f"{parser.prog} {name}: no help"
        texts.append(action.help)
    for text in texts:
        assert "`" not in text, f"{parser.prog}: {text}"


@pytest.mark.parametrize("prog", CLIS)
def test_the_top_level_help_is_plain_text(prog):
    parser = CLIS[prog]()
    assert "`" not in parser.format_help()


def test_fixed_vocabularies_are_choices():
    ingest = find("btf-host", ("ingest",))
    choices = {a.dest: a.choices for a in ingest._actions}
    assert set(choices["layout"]) == {"curet", "utia", "folder"}
    assert set(choices["space"]) == {"rgb", "hsv", "gray", "raw"}


def test_station_help_says_what_is_required_without_demo():
    station = find("btf-host", ("station",))
    for action in station._actions:
        if action.dest in ("port", "db", "key"):
            assert "required unless --demo" in action.help


@pytest.mark.parametrize("target", ["arm", "tracker", "exposure"])
def test_each_calibration_target_has_its_own_help(target, capsys):
    assert robot_cli.main(["calibrate", target, "--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: btf-robot calibrate {target}")
    others = {"arm": "arm_calibration.json", "tracker": "tracker_remap", "exposure": "camera_exposure.json"}
    assert others[target] in out
    assert all(v not in out for k, v in others.items() if k != target)
