"""A lost counters file, on either end: recorded frames are not accepted again (0 of 20), and the
link recovers by itself from the wall clock; a robot without a clock refuses to start and says
how to recover; an end refusing everything its peer sends as stale says so once, in one line."""
import os
import subprocess
import sys
import time
import tty
from pathlib import Path

import pytest

from radio import packets as pk
from radio.auth import SKEW_S, CounterFileLost, FileCounterStore, MemoryCounterStore, clock_counter, write_fresh
from radio.link import Delivered, Link, PeerStale
from radio.ports import FdPort
from radio.pump import LinkPump
from tests.support import ROOT
from tests.support.robots import IDLE, SMALL, robot_toml
from tools.station.receiver import HostSession, ItemKind, Receiver

KEY = bytes(range(32))
T0 = 1.8e9  # the wall clock of the first run (January 2027)
ROBOT, HOST, LINK = 1, 2, 1


class Wall:
    """A wall clock the test sets."""

    def __init__(self, t: float) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def exchange(a: Link, b: Link, t: float, seconds: float = 2.0, tap=None) -> tuple[list, list, float]:
    """Lossless exchange; (events at a, events at b, end time). `tap` sees what a sends."""
    ea, eb = [], []
    for _ in range(int(seconds / 0.01)):
        ab, ba = a.poll(t), b.poll(t)
        if tap is not None:
            tap(ab)
        b.receive(ab, t)
        a.receive(ba, t)
        ea += a.pop_events()
        eb += b.pop_events()
        t += 0.01
    return ea, eb, t


def delivered(events: list) -> list[bytes]:
    return [e.payload for e in events if isinstance(e, Delivered)]


def replayed(link: Link, recorded: list[bytes], t: float) -> list[bytes]:
    """What `link` delivers of the recorded bytes fed to it again."""
    for data in recorded:
        link.receive(data, t)
    return delivered(link.pop_events())


@pytest.fixture
def files(tmp_path):
    write_fresh(tmp_path / "host.counters.json")  # as `btf-host keygen` leaves it
    return tmp_path / "robot.counters.json", tmp_path / "host.counters.json"


def test_robot_loses_its_counters_file_replays_are_refused_and_the_link_recovers(files):
    robot_file, host_file = files
    wall = Wall(T0)
    robot = Link(ROBOT, HOST, LINK, KEY, FileCounterStore(robot_file, wall=wall))
    host = Link(HOST, ROBOT, LINK, KEY, FileCounterStore(host_file, wall=wall))
    recorded: list[bytes] = []
    for i in range(20):
        host.send(b"CAPTURE %d" % i, 0.0)
    _, er, t = exchange(host, robot, 0.0, tap=recorded.append)
    assert len(delivered(er)) == 20
    robot_file.unlink()  # a new SD card; the robot restarts ten minutes later
    wall.t = T0 + 600
    store = FileCounterStore(robot_file, wall=wall)
    assert "missing" in store.note and "wall clock" in store.note
    robot2 = Link(ROBOT, HOST, LINK, KEY, store)
    assert replayed(robot2, recorded, t) == []  # 0 of 20 recorded commands run again
    # Recovers by itself: its counters start from the clock, above what the host accepted.
    robot2.send(b"capture 1", t, msg_id=1)
    host.send(b"PING", t)
    eh, er2, _ = exchange(host, robot2, t)
    assert delivered(eh) == [b"capture 1"] and delivered(er2) == [b"PING"]
    assert not [e for e in eh + er2 if isinstance(e, PeerStale)]


def test_host_loses_its_counters_file_replays_are_refused_and_the_link_recovers(files):
    robot_file, host_file = files
    wall = Wall(T0)
    robot = Link(ROBOT, HOST, LINK, KEY, FileCounterStore(robot_file, wall=wall))
    host = Link(HOST, ROBOT, LINK, KEY, FileCounterStore(host_file, wall=wall))
    recorded: list[bytes] = []
    for i in range(20):
        robot.send(b"capture %d" % i, 0.0, msg_id=i + 1)
    _, eh, t = exchange(robot, host, 0.0, tap=recorded.append)
    assert len(delivered(eh)) == 20
    host_file.unlink()
    wall.t = T0 + 600
    host2 = Link(HOST, ROBOT, LINK, KEY, FileCounterStore(host_file, wall=wall))
    assert replayed(host2, recorded, t) == []  # 0 of 20 recorded captures taken again
    robot.send(b"capture 21", t, msg_id=21)
    host2.send(b"STATUS", t)
    er, eh2, _ = exchange(robot, host2, t)
    assert delivered(eh2) == [b"capture 21"] and delivered(er) == [b"STATUS"]


def test_a_lost_file_refuses_frames_older_than_the_skew_and_takes_a_peer_whose_clock_agrees(files):
    robot_file, host_file = files
    wall = Wall(T0)
    robot = Link(ROBOT, HOST, LINK, KEY, FileCounterStore(robot_file, wall=wall))
    recorded: list[bytes] = []
    robot.send(b"old", 0.0, msg_id=1)
    recorded.append(robot.poll(0.0))
    wall.t = T0 + SKEW_S + 1  # the host starts without its file a little over a minute later
    host_file.unlink()
    host = Link(HOST, ROBOT, LINK, KEY, FileCounterStore(host_file, wall=wall))
    assert replayed(host, recorded, 0.0) == []
    assert host.stats().rejected.get("stale", 0) >= 1


def test_a_robot_without_a_clock_refuses_to_start_without_its_file_and_says_how_to_recover(tmp_path):
    with pytest.raises(CounterFileLost, match=r"is missing.*clock = \"none\".*rotate the key.*--new-key"):
        FileCounterStore(tmp_path / "c.json", clock=False)
    with pytest.raises(CounterFileLost, match="never set"):  # a clock at 1970 is no clock
        FileCounterStore(tmp_path / "c.json", wall=lambda: 86400.0)
    write_fresh(tmp_path / "c.json")  # `btf-robot run --new-key`, after the key was rotated
    store = FileCounterStore(tmp_path / "c.json", clock=False)
    assert [store.next_tx(1, 1) for _ in range(3)] == [1, 2, 3]


def _robot_run(tmp_path: Path, *extra: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", "import sys; from onboard.cli import main; sys.exit(main())", "run",
         "--config", str(tmp_path / "robot.toml"), "--port", "loop://", "--max-seconds", "1", *extra],
        cwd=ROOT, capture_output=True, text=True, timeout=120)


def test_btf_robot_without_a_clock_and_its_counters_exits_2_with_the_remedy_then_runs_with_a_new_key(tmp_path):
    (tmp_path / "robot.toml").write_text(
        robot_toml(SMALL, IDLE, {"link": {"key_file": "robot.key", "clock": "none"}}, state_dir="state"))
    (tmp_path / "robot.key").write_text(KEY.hex())
    (tmp_path / "robot.key").chmod(0o600)
    proc = _robot_run(tmp_path)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr  # a person must act: not restarted
    assert "counters.json is missing" in lines[0] and "rotate the key" in lines[0] and "--new-key" in lines[0]
    proc = _robot_run(tmp_path, "--new-key")
    assert proc.returncode == 0, proc.stderr
    assert (tmp_path / "state" / "counters.json").exists()
    assert _robot_run(tmp_path).returncode == 0  # its file kept: no flag needed again


def test_a_peer_refused_as_stale_is_said_once_in_one_line_with_the_remedy(tmp_path):
    """The robot lost its file and its clock runs two hours behind: every frame is stale."""
    write_fresh(tmp_path / "host.json")
    host_store = FileCounterStore(tmp_path / "host.json", wall=lambda: T0)
    host_store.set_rx_floor(ROBOT, LINK, clock_counter(T0))  # the robot's last session, before
    robot = Link(ROBOT, HOST, LINK, KEY, FileCounterStore(tmp_path / "robot.json", wall=lambda: T0 - 7200))
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    host_link = Link(HOST, ROBOT, LINK, KEY, host_store)
    session = HostSession(LinkPump(host_link, FdPort(slave, timeout=0.001)), Receiver(None))
    items = []
    try:
        t = 0.0
        for _ in range(1500):  # 15 s of the robot's SYNs (one per RTO) and heartbeats
            os.write(master, robot.poll(t))
            items += session.step()
            t += 0.01
    finally:
        os.close(master)
        os.close(slave)
    said = [i for i in items if i.kind is ItemKind.LINK]
    assert len(said) == 1 and "\n" not in said[0].text
    assert "refused as stale" in said[0].text and "rotate the key" in said[0].text
    assert session.stats().rejected["stale"] > 2 * 16


def test_the_robot_logs_a_stale_peer_once_and_reports_it_in_status(fake_robot):
    from onboard.link.transport import MemoryTransport

    lines: list[str] = []
    tr = MemoryTransport()
    rt, _ = fake_robot(robot_toml(SMALL, IDLE), transport=tr, log=lines.append)
    rt.boot()
    tr.deliver(PeerStale(2, 16, "every frame from node 2 is refused as stale (16 in a row): ..."))
    rt.step()
    stale = [line for line in lines if "refused as stale" in line]
    assert len(stale) == 1 and any("refused as stale" in e for e in rt.state.errors)


def test_status_carries_the_link_s_rejections_by_reason(fake_robot):
    from onboard.link.transport import MemoryTransport

    tr = MemoryTransport()
    rt, _ = fake_robot(robot_toml(SMALL, IDLE), transport=tr)
    rt.boot()
    tr.rejected.update({"tag": 3, "stale": 2})
    report = rt.dispatch.status({}, None)
    assert report.rejected.items == (pk.Rejection("stale", 2), pk.Rejection("tag", 3))
    assert report.disk.state == "ok" and report.disk.free > 0


def test_a_host_s_memory_counters_can_follow_the_clock_as_its_file_s_do():
    now = time.time()
    store = MemoryCounterStore(wall=lambda: now)
    assert store.next_tx(1, 1) >= int((now - 1420070400) * 100_000)
