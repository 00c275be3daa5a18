"""`btf-host station --demo DIR` as a newcomer runs it: from the repository root, DIR relative."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from tests.support import ROOT
from tools.demo.station_demo import ROBOT_CONFIG

UP_WITHIN_S = 20.0


def start_demo(where: Path) -> subprocess.Popen:
    relative = os.path.relpath(where, ROOT)
    assert not Path(relative).is_absolute()
    return subprocess.Popen([sys.executable, "-m", "tools.cli", "station", "--demo", relative, "--http", "127.0.0.1:0"],
                            cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)


def wait_for_event(log: Path, proc: subprocess.Popen, wanted) -> dict:
    """The first event of the station's log that `wanted(event)` accepts, within UP_WITHIN_S."""
    end = time.monotonic() + UP_WITHIN_S
    while time.monotonic() < end:
        assert proc.poll() is None, proc.communicate()[1]
        lines = log.read_text().splitlines() if log.exists() else []
        for ev in map(json.loads, lines):
            if wanted(ev):
                return ev
        time.sleep(0.2)
    raise AssertionError(f"no such event in {UP_WITHIN_S} s: {log.read_text() if log.exists() else 'no log'}")


def stop(proc: subprocess.Popen) -> tuple[int, str]:
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=30)
    return proc.returncode, err


def test_demo_from_the_repository_root_with_a_relative_directory_brings_the_link_up(tmp_path):
    proc = start_demo(tmp_path / "demo")
    try:
        wait_for_event(tmp_path / "demo" / "scene.db.log", proc, lambda e: e["kind"] == "link" and e.get("up"))
    finally:
        code, err = stop(proc)
    assert code == 0, err
    assert "Traceback" not in err and "demo robot failed" not in err
    assert "link: up" in err


def test_a_demo_robot_that_ends_is_said_once_in_the_log_and_the_exit_status(tmp_path):
    (tmp_path / "demo").mkdir()
    (tmp_path / "demo" / "robot.toml").write_text(ROBOT_CONFIG.replace('"robot.key"', '"no-such.key"'))
    proc = start_demo(tmp_path / "demo")
    try:
        ev = wait_for_event(tmp_path / "demo" / "scene.db.log", proc,
                            lambda e: e["kind"] == "station" and "demo robot" in e["text"])
    finally:
        code, err = stop(proc)
    assert "exited with status 2" in ev["text"] and "no-such.key" in ev["text"], ev
    assert "robot.log" in ev["text"]
    said = [line for line in err.splitlines() if "demo robot" in line]
    assert said == [f"station: {ev['text']}"]
    assert code == 1 and "Traceback" not in err


def test_a_broken_robot_config_in_the_demo_directory_is_one_line(tmp_path):
    (tmp_path / "demo").mkdir()
    (tmp_path / "demo" / "robot.toml").write_text('robot_id = 1\n[hal]\nbody = "no-such-body"\n')
    proc = start_demo(tmp_path / "demo")
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2
    assert len(err.splitlines()) == 1 and "no-such-body" in err and "robot.toml" in err, err
