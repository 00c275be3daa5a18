"""examples/robot.toml lists every key of the configuration schema (onboard/config/) with its
default and meaning, and starts the robot on the fake and the emulated HAL."""
import dataclasses
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from onboard import config
from tests.support import ROOT

EXAMPLE = ROOT / "examples" / "robot.toml"
KEY_LINE = re.compile(r"^(#\s*)?([a-z_0-9]+) = (.*?)\s+#\s*(\S.*)$")


def schema() -> dict[str, object]:
    """Every key the loader reads, dotted, with its default as TOML writes it."""
    out = {}
    sections = {"": config.Config, **config._SECTIONS}
    for section, cls in sections.items():
        for f in dataclasses.fields(cls):
            if section == "" and (f.name in config._SECTIONS or f.name == "source"):
                continue
            default = f.default if f.default is not dataclasses.MISSING else f.default_factory()
            if isinstance(default, Path):
                default = str(default)
            elif isinstance(default, tuple):
                default = list(default)
            out[f"{section}.{f.name}" if section else f.name] = default
    return out


def example_lines() -> dict[str, tuple[bool, str]]:
    """dotted key -> (active, its comment and the comment lines continuing it)."""
    out: dict[str, tuple[bool, str]] = {}
    section, last = "", None
    for line in EXAMPLE.read_text(encoding="utf-8").splitlines():
        if line.startswith("["):
            section, last = line.strip("[]"), None
            continue
        m = KEY_LINE.match(line)
        if m:
            last = f"{section}.{m[2]}" if section else m[2]
            assert last not in out, f"{last} listed twice"
            out[last] = (m[1] is None, m[4])
        elif last is not None and re.match(r"^\s+#", line):
            active, text = out[last]
            out[last] = (active, text + " " + line.strip().lstrip("#").strip())
        else:
            last = None
    return out


def test_every_key_of_the_schema_is_listed_with_its_meaning_and_nothing_else():
    keys, listed = schema(), example_lines()
    assert sorted(set(keys) - set(listed)) == [], "keys the example leaves out"
    assert sorted(set(listed) - set(keys)) == [], "keys the schema does not know"
    assert all(len(text) > 10 for _, text in listed.values())


def test_every_value_is_the_default_or_its_comment_names_the_default():
    data = tomllib.loads(EXAMPLE.read_text(encoding="utf-8"))
    defaults = schema()
    for dotted, (active, text) in example_lines().items():
        if not active:
            continue
        section, _, key = dotted.rpartition(".")
        value = data[section][key] if section else data[key]
        if value != defaults[dotted]:
            assert "default" in text.lower(), f"{dotted} = {value!r} differs from the default {defaults[dotted]!r}"


def test_the_example_loads_and_its_segmentation_works_on_every_body(monkeypatch):
    cfg = config.load(EXAMPLE)
    assert cfg.segment.method != "scene"  # the fake camera's ground truth: fake only
    for body in ("fake", "emulated", "real"):
        config.check(dataclasses.replace(cfg, hal=dataclasses.replace(cfg.hal, body=body)))


@pytest.mark.parametrize("body", ["fake", "emulated"])
def test_the_example_starts_the_robot(tmp_path, body):
    shutil.copy(EXAMPLE, tmp_path / "robot.toml")
    (tmp_path / "robot.key").write_text("00" * 32)
    (tmp_path / "robot.key").chmod(0o600)
    robot = subprocess.Popen([sys.executable, "-c", "import sys; from onboard.cli import main; sys.exit(main())",
                              "run", "--config", str(tmp_path / "robot.toml"), "--hal", body, "--max-seconds", "120"],
                             stderr=subprocess.PIPE, text=True, cwd=ROOT)
    lines = []
    try:
        for line in robot.stderr:  # stopped once the first pose of its sweep is measured
            lines.append(line.rstrip("\n"))
            if line.startswith("sweep 1 pose 1/"):
                robot.terminate()
    finally:
        if robot.poll() is None:
            robot.kill()
    assert robot.wait(timeout=30) == 0, lines
    assert lines[0] == f"boot: robot 1 on the {body} HAL, mode sweeping, sweep 1 started", lines
    assert re.match(r"capture 1 compute: features [0-9.]+, segmentation [0-9.]+, fit [0-9.]+, dependence [0-9.]+, "
                    r"encode [0-9.]+; total [0-9.]+ ms$", lines[1]), lines
    assert re.match(r"sweep 1 pose 1/7 at 90\.0°/0\.0°: seq 1, measured", lines[2]), lines
