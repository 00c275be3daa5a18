"""listen, decode and cmd on the command line: recorded streams, bad input, no answer."""
import json
import os
import time
import tty

import pytest

from onboard.cli.runner import CliError
from radio import packets as pk
from radio.auth import MemoryCounterStore
from radio.keys import write_key
from radio.link import Link
from tests.support import ROOT
from tests.support.packets import models_body
from tests.support.robots import IDLE, LINKED, robot_toml
from tools.cli import main
from tools.demo.pty_cable import PtyCable
from tools.station import start as station_start


@pytest.fixture
def key(tmp_path):
    return write_key(tmp_path / "link.key")


def recording(key_path, tmp_path):
    from radio.keys import load_key

    robot = Link(1, 2, 1, load_key(key_path), MemoryCounterStore())
    robot.send(models_body(4)[0], 0.0)
    data = robot.poll(0.0) + robot.poll(0.5)  # SYN, then (unanswered) the SYN again
    # Without a peer the session never opens; hand-open it so DATA frames are recorded.
    host = Link(2, 1, 1, load_key(key_path), MemoryCounterStore())
    host.receive(data, 0.5)
    robot.receive(host.poll(0.5), 0.5)
    data += robot.poll(0.6)
    path = tmp_path / "stream.bin"
    path.write_bytes(b"\x01garbage" + data)
    return path


def test_decode_with_the_key_reassembles_the_models_packet(key, tmp_path, capsys):
    path = recording(key, tmp_path)
    assert main(["decode", str(path), "--key", str(key)]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert any("error" in r for r in rows)  # the leading garbage
    models = [r for r in rows if r.get("type") == "MODELS"]
    assert len(models) == 1 and models[0]["seq"] == 4 and len(models[0]["models"]) == 6


def test_decode_without_the_key_shows_headers_and_a_wrong_key_rejects_every_frame(key, tmp_path, capsys):
    path = recording(key, tmp_path)
    assert main(["decode", str(path), "--no-auth"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    kinds = {r.get("kind") for r in rows}
    assert {"SYN", "DATA"} <= kinds and all(r["authenticated"] is False for r in rows)
    other = write_key(tmp_path / "other.key")
    assert main(["decode", str(path), "--key", str(other)]) == 2
    said = capsys.readouterr()
    rows = [json.loads(line) for line in said.out.splitlines()]
    assert rows and all("error" in r for r in rows)
    (line,) = said.err.strip().splitlines()
    assert "authenticates with" in line and "wrong key?" in line


def test_decode_of_a_recording_begun_after_the_link_came_up_says_why_no_message_is_shown(key, tmp_path, capsys):
    whole = recording(key, tmp_path).read_bytes()
    frames = whole.split(b"\x00")
    syn = [i for i, f in enumerate(frames) if f and main_kind(f, key) == "SYN"]
    late = tmp_path / "late.bin"
    late.write_bytes(b"\x00".join(frames[syn[-1] + 1:]))
    assert main(["decode", str(late), "--key", str(key)]) == 0
    said = capsys.readouterr()
    assert not [r for r in map(json.loads, said.out.splitlines()) if "message" in r]
    assert "no message put together: the recording starts after its link came up" in said.err
    empty = tmp_path / "empty.bin"
    empty.write_bytes(b"")
    assert main(["decode", str(empty), "--no-auth"]) == 0 and "no frames" in capsys.readouterr().err


def main_kind(raw: bytes, key: bytes) -> str | None:
    from radio import FrameError
    from radio.frame import decode
    from radio.keys import load_key

    try:
        return decode(raw, load_key(key)).kind.name
    except FrameError:
        return None


@pytest.mark.parametrize("argv, needle", [
    (["decode", "missing.bin", "--no-auth"], "no such file"),
    (["listen", "--port", "loop://", "--db", "x.db", "--key", "nokey"], "no key file"),
    (["cmd", "--port", "loop://", "--key", "nokey", "--db", "x.db", "status"], "no key file"),
    (["cmd", "--port", "loop://", "--key", "nokey", "status"], "needs --db"),
])
def test_bad_input_is_one_line_and_status_2(argv, needle, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and len(err.splitlines()) == 1


@pytest.mark.parametrize("command", ["station", "listen"])
def test_a_database_in_a_folder_that_does_not_exist_is_a_mistake_not_a_wait(command, key, tmp_path, capsys):
    """Exit 1 (try again later) for a mistyped --db: a service manager restarted it forever."""
    assert main([command, "--port", "loop://", "--db", str(tmp_path / "nodir" / "x.db"), "--key", str(key)]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert f"folder {tmp_path / 'nodir'} does not exist; create it" in line


def test_listen_refuses_a_corrupt_database_and_leaves_it_untouched(key, tmp_path, capsys):
    db = tmp_path / "scene.db"
    db.write_bytes(b"not a database at all" * 10)
    before = db.read_bytes()
    assert main(["listen", "--port", "loop://", "--db", str(db), "--key", str(key)]) == 2
    assert "not an SQLite file" in capsys.readouterr().err
    assert db.read_bytes() == before


def test_listen_stores_what_arrives_then_exits_when_idle(key, tmp_path, capsys, monkeypatch):
    # loop:// echoes our own frames back: they are rejected as from the wrong sender, nothing stored.
    db = tmp_path / "scene.db"
    assert main(["listen", "--port", "loop://", "--db", str(db), "--key", str(key),
                 "--until-idle", "1", "--json"]) == 0
    out = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert out[-1]["kind"] == "summary" and out[-1]["captures"] == 0
    assert out[-1]["rejected"].get("sender", 0) > 0


def test_listen_counts_idle_time_from_when_it_listens_not_from_a_slow_start(key, tmp_path, capsys, monkeypatch):
    opened = station_start.ControlServer.start

    async def slow_start(self):  # a loaded machine: the station is ready well after it was built
        time.sleep(1.2)
        await opened(self)
    monkeypatch.setattr(station_start.ControlServer, "start", slow_start)
    assert main(["listen", "--port", "loop://", "--db", str(tmp_path / "scene.db"), "--key", str(key),
                 "--until-idle", "1", "--json"]) == 0
    out = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert out[-1]["kind"] == "summary" and out[-1]["rejected"].get("sender", 0) > 0  # it heard its own echo


def test_cmd_without_an_answer_times_out_with_one_line(key, tmp_path, capsys):
    master, slave = os.openpty()
    tty.setraw(master)
    try:
        assert main(["cmd", "--port", os.ttyname(slave), "--key", str(key), "--timeout", "0.3",
                     "--db", str(tmp_path / "host.db"), "goto", "--elevation", "45"]) == 2
    finally:
        os.close(master)
        os.close(slave)
    assert "no answer from the robot" in capsys.readouterr().err


def test_cmd_arguments_become_the_commands_the_robot_checks():
    from tools.cli import build_parser
    from tools.cli.cmd import command_of

    p = build_parser()
    name, args = command_of(p.parse_args(["cmd", "--port", "x", "--key", "k", "sweep",
                                          "--elevations", "90,60,30"]))
    assert name is pk.CommandName.SWEEP and args == {"elevations": [90.0, 60.0, 30.0]}  # azimuths: the robot's own
    name, args = command_of(p.parse_args(["cmd", "--port", "x", "--key", "k", "set", "skip.min_pixels", "32"]))
    assert (name, args) == (pk.CommandName.SET, {"key": "skip.min_pixels", "value": 32})
    assert pk.decode(pk.encode(pk.CommandPacket(1, name, args))).args == args
    name, args = command_of(p.parse_args(["cmd", "--port", "x", "--key", "k", "sweep",
                                          "--start", "90", "--stop", "30", "--step", "10"]))
    assert args == {"start": 90.0, "stop": 30.0, "step": 10.0}
    decoded = pk.decode(pk.encode(pk.CommandPacket(2, name, args))).args
    assert {k: list(v) if isinstance(v, tuple) else v for k, v in decoded.items()} == args


@pytest.mark.parametrize("extra", [["--start", "90", "--elevations", "90,80"], ["--start", "90", "--stop", "30"]])
def test_cmd_sweep_refuses_mixed_or_partial_ranges(extra):
    from tools.cli import build_parser
    from tools.cli.cmd import command_of

    args = build_parser().parse_args(["cmd", "--port", "x", "--key", "k", "sweep", *extra])
    with pytest.raises(CliError, match="sweep"):
        command_of(args)


@pytest.fixture(scope="module")
def robot_port(tmp_path_factory):
    """A running `btf-robot run --hal fake` on one end of a serial cable; yields (other end, key)."""
    import subprocess
    import sys

    work = tmp_path_factory.mktemp("robot")
    key = write_key(work / "robot.key")
    (work / "robot.toml").write_text(
        robot_toml(LINKED, IDLE, {"hal": {"size": [48, 64]}, "skip": None}, robot_id=4, state_dir="state"))
    bridge = PtyCable()
    with open(work / "stderr", "wb") as err:
        robot = subprocess.Popen(
            [sys.executable, "-c", "import sys; from onboard.cli import main; sys.exit(main())", "run",
             "--config", str(work / "robot.toml"), "--hal", "fake", "--port", bridge.paths[0],
             "--max-seconds", "600"], cwd=ROOT,
            stdout=subprocess.DEVNULL, stderr=err)
    try:
        yield bridge.paths[1], key
    finally:
        robot.terminate()
        robot.wait(timeout=10)
        bridge.close()


def _cmd(port, key, capsys, *argv):
    # no station runs: cmd holds the port for the command, storing what arrives beside the key
    code = main(["cmd", "--port", port, "--key", str(key), "--db", str(key.parent / "host.db"),
                 "--timeout", "20", "--json", *argv])
    out = capsys.readouterr().out.strip().splitlines()
    return code, json.loads(out[-1]) if out else None


def test_cmd_against_a_running_robot_gets_its_answers(robot_port, capsys):
    port, key = robot_port
    code, ans = _cmd(port, key, capsys, "status")
    assert code == 0 and ans["type"] == "ACK" and ans["ok"] and ans["text"] == "STATUS"
    assert ans["status"]["mode"] == "idle" and ans["status"]["faults"]["items"] == []
    code, ans = _cmd(port, key, capsys, "goto", "--elevation", "50", "--azimuth", "0")
    assert code == 0 and ans["type"] == "ACK"
    assert abs(ans["extras"]["elevation"] - 50.0) < 2.0  # the measured angle, not the commanded one
    code, ans = _cmd(port, key, capsys, "sweep", "--elevations", "60,40")
    assert code == 0 and ans["type"] == "ACK" and ans["extras"]["poses"] == 2
    _until_robot_idle(port, key, capsys)  # the sweep ends; the module's later commands find the arm free


def _until_robot_idle(port, key, capsys, seconds=120.0):
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        code, ans = _cmd(port, key, capsys, "status")
        if code == 0 and ans["status"]["mode"] == "idle":
            return
        time.sleep(0.5)
    raise AssertionError(f"the robot still sweeping after {seconds:.0f} s")


def test_cmd_against_a_running_robot_reports_a_refusal_with_its_reason(robot_port, capsys):
    port, key = robot_port
    code, ans = _cmd(port, key, capsys, "set", "link.no_such_key", "3")
    assert code == 1 and ans["type"] == "NACK" and not ans["ok"]
    assert ans["reason"] == "BAD_ARGUMENT" and "cannot be set at run time" in ans["text"]


def test_cmd_reaches_the_robot_through_a_lossy_radio_url(robot_port, capsys):
    port, key = robot_port
    code, ans = _cmd(f"btfsim://?port={port}&loss=0.2&seed=5", key, capsys, "status")
    assert code == 0 and ans["type"] == "ACK" and ans["text"] == "STATUS"


def test_ping_and_reboot_servo_have_command_line_forms_the_robot_answers(robot_port, capsys):
    port, key = robot_port
    code, ans = _cmd(port, key, capsys, "ping")
    assert code == 0 and ans["type"] == "ACK" and ans["text"] == "PING" and ans["extras"]["time"] > 0
    code, ans = _cmd(port, key, capsys, "reboot-servo", "--servo-id", "1")
    assert code == 0 and ans["type"] == "ACK" and ans["extras"]["rebooted"] == 1


def test_cmd_prints_an_answer_without_the_fields_left_empty(monkeypatch, capsys, tmp_path):
    import tools.cli.cmd as cmd_cli

    answer = {"command_id": 5, "ok": True, "type": "ACK", "text": "STATUS", "extras": {},
              "status": {"mode": "idle", "paused": "", "outbox": 0, "disk": {"state": "ok", "note": ""},
                         "faults": {"items": [], "left_out": 0}}}
    monkeypatch.setattr(cmd_cli, "ask", lambda *a: answer)
    assert main(["cmd", "--db", str(tmp_path / "s.db"), "status"]) == 0
    assert capsys.readouterr().out.splitlines() == ["ACK: STATUS", "  mode: idle", "  outbox: 0",
                                                    "  disk: {state=ok}", "  faults: none"]
    answer.update(text="SET", status=None, extras={"set": "skip.min_pixels", "camera": ""})
    assert main(["cmd", "--db", str(tmp_path / "s.db"), "set", "skip.min_pixels", "50"]) == 0
    assert capsys.readouterr().out == "ACK: SET (set=skip.min_pixels)\n"


def test_an_answers_angles_read_to_a_tenth_of_a_degree_and_its_clock_as_a_time():
    from tools.cli.cmd import _shown

    assert (_shown("elevation", 70.4848), _shown("azimuth", 0.102775)) == ("70.5", "0.1")
    assert _shown("time", 1795890000.25).startswith("2026-") and _shown("poses", 6) == 6
