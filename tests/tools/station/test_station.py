"""The station owns the radio (on a real pty cable): a robot, a station and
three concurrent `cmd` clients through a 60-pose sweep; TORQUE_OFF -> TORQUE_ON -> SWEEP; and
what an operator meets around them (the socket, a second station, a wrong key)."""
import json
import os
import re
import stat
import subprocess
import threading
import time
from collections import Counter
from urllib.parse import urlsplit
from urllib.request import urlopen

import pytest

from tests.support.browser import page_address
from tests.support.robots import robot_toml
from tests.support.station_rig import PLAN, POSES, ROBOT, ROOT, Rig, kill9, python, robot_log


@pytest.fixture
def rig(tmp_path):
    r = Rig(tmp_path)
    yield r
    r.close()


# Each client's commands, run one after the other while the others run theirs.
CLIENTS = [
    [["status"], ["capture"], ["status"], ["capture"]],
    [["set", "skip.min_pixels", "20"], ["ping"], ["set", "sweep.azimuths", "[0,45]"], ["status"]],
    [["capture"], ["ping"], ["capture"], ["set", "skip.unchanged_tolerance", "0"]],
]


def run_clients(rig, clients):
    results = [[] for _ in clients]

    def client(i):
        for argv in clients[i]:
            results[i].append((argv, *rig.cmd(*argv)))

    threads = [threading.Thread(target=client, args=(i,)) for i in range(len(clients))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return [r for rs in results for r in rs]


def test_a_sweep_with_three_concurrent_clients_stores_every_capture_once_and_answers_every_command_once(rig):
    sweep_with_clients(rig, CLIENTS)


@pytest.mark.slow
@pytest.mark.skipif(not os.environ.get("BTF_STRESS"), reason="stress run only (make stress)")
def test_a_sweep_over_a_lossy_radio_with_three_busy_clients_stores_and_answers_everything_once(rig):
    sweep_with_clients(rig, [c * 4 for c in CLIENTS], radio="loss=0.1&ber=1e-4&dup=0.02&seed=9")


def sweep_with_clients(rig, clients, radio=""):
    robot = rig.robot()
    station = rig.station(*(("--port", f"btfsim://?port={rig.cable.paths[1]}&{radio}") if radio else ()))
    rig.wait_up(station)
    code, (sweep,), _ = rig.cmd("sweep", *PLAN)
    assert code == 0 and sweep["type"] == "ACK" and sweep["extras"]["poses"] == len(POSES)
    results = run_clients(rig, clients)
    rig.wait_for_poses(POSES, robot=robot)
    # every command printed exactly one answer, ACK (0) or NACK (1: a capture while a pose is measured)
    ids = []
    for argv, code, lines, err in results:
        assert code in (0, 1) and len(lines) == 1, (argv, code, lines, err)
        (answer,) = lines
        assert answer["ok"] == (code == 0) and answer["command"] == argv[0]
        assert answer["type"] == "ACK" or answer["reason"] == "BUSY", answer
        ids.append(answer["command_id"])
    assert len(set(ids)) == len(ids) == sum(map(len, clients))
    # the station sent each command once and routed one answer for each
    log = rig.log()
    for kind in ("command", "answer"):
        seen = Counter(e["command_id"] for e in log if e["kind"] == kind)
        assert all(seen[i] == 1 for i in ids), (kind, seen)
    # the robot ran each command once, and none reached it twice (answered again from memory)
    ran = Counter(int(line.split()[1]) for line in robot_log(rig.where) if line.startswith("command "))
    assert all(ran[i] == 1 for i in ids), ran
    # every pose of the sweep stored exactly once, and every capture the robot ACKed
    captured = [lines[0]["extras"]["seq"] for argv, code, lines, _ in results if argv == ["capture"] and code == 0]
    captures = rig.captures()
    commanded = Counter((c.commanded[0], c.commanded[1]) for c in captures)
    assert all(commanded[p] == 1 for p in POSES), {p: n for p, n in commanded.items() if n != 1}
    seqs = Counter(c.sequence for c in captures)
    assert set(seqs.values()) == {1} and set(captured) <= set(seqs)
    assert len(captures) == len(POSES) + len(captured)
    snap = rig.snapshot()
    assert snap["link"]["up"] and snap["captures"]["stored"] == len(captures)
    assert snap["sweep"]["id"] == sweep["extras"]["sweep"] and snap["sweep"]["poses"] == len(POSES)
    assert rig.stop(station) == 0 and rig.stop(robot) == 0


def test_torque_off_torque_on_sweep_completes_through_the_station(rig):
    robot = rig.robot()
    station = rig.station()
    rig.wait_up(station)
    assert rig.cmd("torque-off")[0] == 0
    code, (nack,), _ = rig.cmd("goto", "--elevation", "70")
    assert code == 1 and nack["reason"] == "TORQUE_OFF" and "send torque-on" in nack["text"]
    code, (nack,), _ = rig.cmd("sweep", "--elevations", "80,60,40")
    assert code == 1 and nack["reason"] == "TORQUE_OFF"
    code, (ack,), _ = rig.cmd("torque-on")
    assert code == 0 and ack["extras"]["torque"] is True
    code, (ack,), _ = rig.cmd("reboot-servo", "--servo-id", "1")  # from the CLI
    assert code == 0 and ack["extras"]["rebooted"] == 1
    code, (ack,), _ = rig.cmd("sweep", "--elevations", "80,60,40")
    assert code == 0 and ack["extras"]["poses"] == 3
    rig.wait_for_poses([(80.0, 0.0), (60.0, 0.0), (40.0, 0.0)], robot=robot)
    code, (status,), _ = rig.cmd("status")
    assert status["status"]["sweep"]["skipped"]["items"] == [] and status["status"]["sweep"]["next"] == 3
    assert rig.stop(station) == 0 and rig.stop(robot) == 0


def test_the_control_socket_is_private_and_one_station_holds_a_database_and_a_port(rig, tmp_path):
    station = rig.station()
    rig.wait_up(station)
    sock = tmp_path / "host.db.sock"
    assert stat.S_ISSOCK(os.stat(sock).st_mode) and stat.S_IMODE(os.stat(sock).st_mode) == 0o600
    for db, words in ((rig.db, "a station already runs on"), (tmp_path / "other.db", "is held by another process")):
        out = subprocess.run([*python("tools.cli"), "station", "--port", rig.cable.paths[1], "--db", str(db),
                              "--key", str(rig.key)], cwd=ROOT, capture_output=True, text=True, timeout=60)
        assert out.returncode == 2 and len(out.stderr.splitlines()) == 1 and words in out.stderr, out.stderr
    assert rig.stop(station) == 0 and not sock.exists()
    code, _, err = rig.cmd("status")
    assert code == 2 and "no station serves" in err and len(err.splitlines()) == 1


def test_cmd_after_a_station_was_killed_says_none_serves_not_that_the_robot_is_silent(rig, tmp_path):
    """A station killed with -9 leaves its socket behind. cmd waits for the next one (a service
    manager restarts it), and when none came it blamed the robot; the lock the kernel let go of
    tells it no station ran."""
    station = rig.station()
    rig.wait_up(station)
    station.kill()
    station.wait(timeout=30)
    assert (tmp_path / "host.db.sock").exists()
    code, _, err = rig.cmd("status", timeout=2)
    assert code == 2 and len(err.splitlines()) == 1, err
    assert "no station serves" in err and "ended without tidying up" in err and "robot" not in err


def test_a_wrong_key_is_said_in_one_line_and_the_station_goes_on_listening(rig, tmp_path):
    """Listening with the wrong key once exited 0 printing `rejected {'tag': 20}`. The
    person is told in one line, on stderr, in the log, in `watch` and on the page; frames anyone
    on the radio can send never end the station, and listen ends only when told to."""
    from radio.keys import write_key

    robot = rig.robot()
    other = write_key(tmp_path / "other.key")
    out = subprocess.run([*python("tools.cli"), "listen", "--port", rig.cable.paths[1], "--db", str(rig.db),
                          "--key", str(other), "--until-idle", "5"], cwd=ROOT, capture_output=True, text=True,
                         timeout=120)
    lines = out.stderr.strip().splitlines()
    assert out.returncode == 2 and lines[-1].startswith("btf-host: error: wrong key?"), out.stderr
    assert [x for x in lines if x.startswith("btf-host: error")] == [lines[-1]] and "Traceback" not in out.stderr
    station = rig.station("--http", "127.0.0.1:0", "--http-public", key=other)
    err = tmp_path / f"station-{rig.stations}.err"
    url = urlsplit(page_address(err))
    end = time.monotonic() + 60
    while "rejected: wrong key?" not in err.read_text() and time.monotonic() < end:
        time.sleep(0.2)
    said = [x for x in err.read_text().splitlines() if x.startswith("rejected: wrong key?")]
    assert said and "failed authentication and none passed: --key must hold" in said[0], err.read_text()
    assert any(e.get("wrong_key") and e["text"] == said[0].removeprefix("rejected: ") for e in rig.log())
    watch = subprocess.run([*python("tools.cli"), "watch", "--db", str(rig.db), "--snapshot"], cwd=ROOT,
                           capture_output=True, text=True, timeout=60)
    assert watch.returncode == 0 and "wrong key?" in watch.stdout, watch.stdout
    with urlopen(f"http://{url.hostname}:{url.port}/api/state", timeout=30) as resp:
        events = json.load(resp)["events"]
    assert any(e["text"].startswith("wrong key?") for e in events)
    tags = rig.snapshot()["link"]["rejected"]["tag"]
    end = time.monotonic() + 60  # still listening: it goes on refusing the robot's frames
    while rig.snapshot()["link"]["rejected"]["tag"] <= tags and time.monotonic() < end:
        time.sleep(0.1)
    assert station.poll() is None and rig.snapshot()["link"]["rejected"]["tag"] > tags
    assert rig.stop(station) == 0 and rig.stop(robot) == 0


def test_a_restarted_station_says_the_robots_resync_as_such_and_not_as_refused_frames(rig):
    (rig.where / "robot.toml").write_text(robot_toml(*ROBOT, {"sweep": {"start": 90, "stop": 30, "step": 1}}))
    robot = rig.robot()
    station = rig.station()
    rig.wait_up(station)
    ups = []
    for stored in (3, 6, 9):  # a restart whose robot had just opened a new session has nothing to re-sync
        end = time.monotonic() + 60
        while len(rig.captures()) < stored and time.monotonic() < end:
            time.sleep(0.05)
        kill9(station)  # mid-sweep: the robot goes on in its session with the station that is gone
        station = rig.station()
        rig.wait_up(station)
        end = time.monotonic() + 60
        while not (up := [e for e in rig.log()[restarted(rig.log()):] if e["kind"] == "link" and e["up"]]):
            assert time.monotonic() < end, "the link never came up after the restart"
            time.sleep(0.05)
        after = rig.log()[restarted(rig.log()):]
        assert not [e for e in after if e["kind"] == "rejected" and e["reason"] == "stale_session"], after
        assert "stale_session" not in rig.snapshot()["link"]["rejected"]  # the page's refused frames
        ups.append(up[0]["text"])
        if "re-synced after this station's start: " in ups[-1]:
            break
    assert re.search(r"re-synced after this station's start: \d+ frames? of the robot's earlier session", ups[-1]), ups
    assert rig.stop(station) == 0 and rig.stop(robot) == 0


def restarted(log: list[dict]) -> int:
    """Where the last station's part of the log begins."""
    return max(i for i, e in enumerate(log) if e["kind"] == "station" and e["text"].startswith("started"))


def test_cmd_without_a_station_stores_what_arrives_and_acknowledges_nothing_it_drops(rig):
    """`cmd capture` once used to ACK the robot's captures and discard them."""
    autonomous = {"sweep": {"start": 90, "stop": 60, "step": 10}}
    (rig.where / "robot.toml").write_text(robot_toml(*ROBOT, autonomous))
    robot = rig.robot("--exit-when-idle")
    acked = []
    for _ in range(2):
        code, (ans,), err = rig.cmd("--port", rig.cable.paths[1], "--key", str(rig.key), "capture")
        assert code in (0, 1), err
        if code == 0:
            acked.append(ans["extras"]["seq"])
    # what the robot still holds goes to a station; the robot exits once all is acknowledged
    station = rig.station()
    rig.wait_up(station)
    assert robot.wait(timeout=120) == 0
    assert rig.stop(station) == 0
    seqs = Counter(c.sequence for c in rig.captures())
    last = max(int(line.split("seq ")[1].split(",")[0]) for line in robot_log(rig.where) if ": seq " in line)
    # every capture the robot made (sweep and commands) is stored, once: none was ACKed and dropped
    assert sorted(seqs) == list(range(1, max([last, *acked]) + 1)) and set(seqs.values()) == {1}
    assert set(acked) <= set(seqs)


def test_a_control_socket_path_too_long_for_the_system_is_one_line(tmp_path, capsys):
    from radio.keys import write_key
    from tools.cli import main

    key = write_key(tmp_path / "robot.key")
    long = tmp_path / ("s" * 120)
    assert main(["station", "--port", "loop://", "--db", str(tmp_path / "h.db"), "--key", str(key),
                 "--socket", str(long)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "give --socket a shorter one" in err[0]
