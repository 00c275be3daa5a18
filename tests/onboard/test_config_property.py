"""A bad configuration stops `btf-robot run` with exit status 2 (systemd does not restart it),
one line on stderr naming the problem, no traceback, and nothing created on disk: whatever is
wrong, whichever key. The configurations are drawn by hypothesis from the schema itself
(`onboard.config.keys`, `BOUNDS`, `CHOICES`): a value of the wrong type, a number outside its
bounds, a word not among the choices, an unknown key, arrays or tables nested thousands deep,
frames larger than a camera gives, an empty file."""
from __future__ import annotations

import contextlib
import io
import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any
from unittest import mock

import pytest
from hypothesis import given
from hypothesis import strategies as st

from onboard import config
from onboard.cli import main
from onboard.config import BOUNDS, CHOICES, CameraValue
from tests.support import ROOT
from tests.support.robots import LINKED, merged

KEYS = config.keys()
INT64 = 2**63 - 1  # TOML's integers are 64-bit


def toml(value: Any) -> str:
    """A value as TOML writes it (inline tables for maps)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, list):
        return "[" + ", ".join(toml(v) for v in value) + "]"
    return "{" + ", ".join(f"{k} = {toml(v)}" for k, v in value.items()) + "}"


def render(sections: dict[str, dict[str, Any]], top: dict[str, Any], tail: str = "") -> str:
    lines = [f"{k} = {toml(v)}" for k, v in top.items()] + ([tail] if tail else [])
    for name, keys in sections.items():
        lines += [f"[{name}]", *(f"{k} = {toml(v)}" for k, v in keys.items())]
    return "\n".join(lines) + "\n"


def good() -> tuple[dict[str, dict[str, Any]], dict[str, Any]]:
    """A configuration `btf-robot run` starts with (a fake robot with its key beside it)."""
    return merged(LINKED), {"robot_id": 3, "state_dir": "state"}


text_values = st.text(st.characters(blacklist_categories=("Cs", "Cc")), max_size=12)
words = st.from_regex(r"[a-z][a-z_0-9]{0,11}", fullmatch=True)
scalars = st.one_of(st.integers(-INT64, INT64), st.floats(allow_nan=False, width=64), st.booleans(), text_values)
tables = st.dictionaries(words, scalars, min_size=0, max_size=3)


def wrong_type(kind: Any, in_list: bool = False) -> st.SearchStrategy:
    """Values of a TOML type the key's kind does not take (`in_list`: as an item of a list)."""
    lists = st.nothing() if in_list else st.lists(scalars, max_size=3)
    if isinstance(kind, tuple):  # a list key: not a list, or a list holding something of another kind
        item, length = kind
        n = st.just(length) if length else st.integers(1, 3)
        return st.one_of(scalars, tables, n.flatmap(lambda k: st.lists(wrong_type(item, True), min_size=k, max_size=k)))
    if kind is bool:
        return st.one_of(st.integers(-INT64, INT64), st.floats(), text_values, lists, tables)
    if kind is int:
        return st.one_of(st.floats(), st.booleans(), text_values, lists, tables)
    if kind is float:
        return st.one_of(st.booleans(), text_values, lists, tables)
    if kind is CameraValue:  # a number or a word
        return st.one_of(st.booleans(), lists, tables)
    return st.one_of(st.integers(-INT64, INT64), st.floats(), st.booleans(), lists, tables)  # str, Path


def out_of_bounds(dotted: str) -> st.SearchStrategy:
    """A number outside the key's bounds (an item of a list key)."""
    lo, hi = BOUNDS[dotted]
    kind = KEYS[dotted][0] if isinstance(KEYS[dotted], tuple) else KEYS[dotted]
    if kind is int:
        sides = [st.integers(-INT64, lo - 1)] + ([st.integers(hi + 1, INT64)] if hi < INT64 else [])
    else:
        sides = [st.floats(max_value=lo, exclude_max=True), st.floats(min_value=hi, exclude_min=True),
                 st.sampled_from([math.nan, math.inf, -math.inf])]
    number = st.one_of(*sides)
    if not isinstance(KEYS[dotted], tuple):
        return number
    length = KEYS[dotted][1] or 2
    return st.tuples(number, st.integers(0, length - 1)).map(
        lambda p: [p[0] if i == p[1] else (lo if kind is int else float(lo)) for i in range(length)])


def nested(depth: int, table: bool) -> str:
    return "{a = " * depth + "1" + "}" * depth if table else "[" * depth + "]" * depth


@st.composite
def bad_configs(draw) -> str:
    """The text of a configuration that must not start, each kind of fault with its own draw."""
    sections, top = good()
    fault = draw(st.sampled_from(["type", "bounds", "choice", "unknown", "nesting", "size", "empty"]))
    if fault == "empty":
        return ""
    if fault == "nesting":
        depth, table = draw(st.integers(200, 6000)), draw(st.booleans())
        return render(sections, top, f"deep = {nested(depth, table)}")
    if fault == "unknown":
        section = draw(st.sampled_from(["", *sections]))
        name = draw(words.filter(lambda w: (f"{section}.{w}" if section else w) not in KEYS
                                 and w not in sections))
        (sections[section] if section else top)[name] = draw(scalars)
        return render(sections, top)
    if fault == "size":  # frames larger than the fake camera (8192) or any packet (16384) allows
        side = draw(st.integers(8193, INT64))
        sections["hal"]["size"] = draw(st.permutations([side, draw(st.integers(8, INT64))]))
        return render(sections, top)
    dotted = draw(st.sampled_from(sorted({"type": KEYS, "bounds": BOUNDS, "choice": CHOICES}[fault])))
    value = draw({"type": lambda: wrong_type(KEYS[dotted]), "bounds": lambda: out_of_bounds(dotted),
                  "choice": lambda: text_values.filter(lambda w: w not in CHOICES[dotted])}[fault]())
    section, _, key = dotted.rpartition(".")
    (sections.setdefault(section, {}) if section else top)[key] = value
    return render(sections, top)


def started(text: str) -> tuple[int, str, set[str]]:
    """`btf-robot run` on `text` in this process, without BTF_HAL: (exit status, stderr, what its
    directory holds after)."""
    err = io.StringIO()
    with tempfile.TemporaryDirectory() as d, mock.patch.dict(os.environ), contextlib.redirect_stderr(err):
        os.environ.pop("BTF_HAL", None)
        where = Path(d)
        (where / "robot.key").write_text("00" * 32)
        (where / "robot.key").chmod(0o600)
        (where / "robot.toml").write_text(text, encoding="utf-8")
        code = main(["run", "--config", str(where / "robot.toml"), "--max-seconds", "0.5"])
        return code, err.getvalue(), {p.name for p in where.iterdir()}


def test_the_good_configuration_starts():
    """The base every bad one is drawn from does start: its faults alone stop it."""
    code, err, left = started(render(*good()))
    assert code == 0 and "state" in left, err


@given(text=bad_configs())
def test_a_bad_configuration_is_exit_2_one_line_and_nothing_on_disk(text):
    code, err, left = started(text)
    assert code == 2, err
    assert len(err.splitlines()) == 1 and err.startswith("btf-robot: error: ") and "Traceback" not in err
    assert left == {"robot.key", "robot.toml"}  # no state directory, nothing else


@pytest.mark.parametrize("text, said", [
    ("robot_id = -1\n[hal]\nbody = 'fake'\n", "robot_id must lie in 0..65535, got -1"),
    ("deep = " + nested(5000, False) + "\n[hal]\nbody = 'fake'\n", "nested too deeply"),
])
def test_btf_robot_run_refuses_a_bad_configuration_before_it_makes_its_state_directory(tmp_path, text, said):
    (tmp_path / "robot.key").write_text("00" * 32)
    (tmp_path / "robot.toml").write_text(text)
    env = {k: v for k, v in os.environ.items() if k != "BTF_HAL"}
    out = subprocess.run([sys.executable, "-c", "import sys; from onboard.cli import main; sys.exit(main())",
                          "run", "--config", str(tmp_path / "robot.toml")],
                         capture_output=True, text=True, timeout=60, cwd=ROOT, env=env)
    assert out.returncode == 2 and out.stderr.count("\n") == 1 and said in out.stderr, out.stderr
    assert "Traceback" not in out.stderr and not (tmp_path / "state").exists()
