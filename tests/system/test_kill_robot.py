"""Killing `btf-robot run` at random instants over a real pty pair, many times: the host
still ends with every capture of the sweep exactly once.

Kills land while sweeping, around the last pose (before, during and after its capture and
the "sweep done" status), and in restarts after the sweep finished, which must not sweep
again. BTF_KILL_SEED picks other kill instants (to hunt for a failing schedule by hand)."""
import json
import os
import random
import signal
import sqlite3
import subprocess
import sys
import time
import tty
from collections import Counter
from contextlib import closing
from pathlib import Path

from radio.auth import MemoryCounterStore
from radio.keys import load_key, write_key
from radio.link import Link
from radio.ports import FdPort
from radio.pump import LinkPump
from tests.support import ROOT
from tests.support.robots import EVERY_POSE, LINKED, SWEEP_TWO_AZIMUTHS, robot_toml
from tools.station.receiver import HOST_NODE, LINK_ID, ROBOT_NODE, HostSession, ItemKind, Receiver
from tools.store.database import Store

# 62 poses (31 elevations at two azimuths) at ~0.03-0.13 s each: the ten kills while
# sweeping (at most ~1.6 s of it) leave the end for the kills around and after it.
ELEVATIONS = [90.0 - 2.0 * i for i in range(31)]
POSES = [(e, a) for a in (0.0, 90.0) for e in ELEVATIONS]
# The already-measured rule is off, so that it cannot hide a pose measured a second time.
CONFIG = robot_toml(LINKED, EVERY_POSE, SWEEP_TWO_AZIMUTHS)


def _robot(config: Path, port: str, limit_s: float) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-c", "import sys; from onboard.cli import main; sys.exit(main())", "run",
         "--config", str(config), "--hal", "fake", "--port", port, "--exit-when-idle",
         "--max-seconds", str(limit_s)],
        cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def _pump(host: HostSession, robot: subprocess.Popen, seconds: float, items: list,
          after_boot: bool = False, after_pose: tuple[float, float] | None = None) -> bool:
    """Run the host for `seconds`, counted from the robot's boot STATUS if `after_boot`, or
    from the arrival of the capture of `after_pose`; whether that count began."""
    waiting = after_boot or after_pose is not None
    end = time.monotonic() + (60.0 if waiting else seconds)
    while robot.poll() is None and time.monotonic() < end:
        new = host.step()
        items += new
        if waiting and any(i.kind is ItemKind.STATUS and i.text.endswith("boot") if after_boot else
                           i.kind is ItemKind.CAPTURE and _pose(i.packet) == after_pose for i in new):
            end, waiting = time.monotonic() + seconds, False
    return not waiting


def _pose(packet) -> tuple[float, float]:
    return (float(packet.commanded[0]), float(packet.commanded[1]))


def _captured(items: list) -> set:
    return {_pose(i.packet) for i in items if i.kind is ItemKind.CAPTURE}


def _wait_for_done(db: Path, poses: int, robot: subprocess.Popen, limit_s: float = 60.0) -> bool:
    """Poll the robot's state (read-only) until its sweep progress is past the last pose."""
    end = time.monotonic() + limit_s
    while time.monotonic() < end and robot.poll() is None:
        try:
            with closing(sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=1.0)) as conn:
                row = conn.execute("SELECT value FROM state WHERE key = 'sweep'").fetchone()
            if row is not None and json.loads(row[0])["next_index"] >= poses:
                return True
        except sqlite3.Error:
            pass  # not created yet, or busy: look again
        time.sleep(0.01)
    return False


def _kill(robot: subprocess.Popen) -> bool:
    """SIGKILL the robot if it is still running; whether it was."""
    if robot.poll() is not None:
        return False
    robot.send_signal(signal.SIGKILL)
    robot.wait(timeout=10)
    return True


def test_killed_robot_restarts_and_the_host_holds_every_capture_exactly_once(tmp_path):
    write_key(tmp_path / "robot.key")
    (config := tmp_path / "robot.toml").write_text(CONFIG)
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    store = Store.open(tmp_path / "host.sqlite")
    link = Link(HOST_NODE, ROBOT_NODE, LINK_ID, load_key(tmp_path / "robot.key"),
                MemoryCounterStore(wall=time.time), heartbeat=0.2, link_timeout=30)
    host = HostSession(LinkPump(link, FdPort(master, timeout=0.005)), Receiver(store))
    rng = random.Random(int(os.environ.get("BTF_KILL_SEED", "20240")))
    items: list = []
    kills = 0
    after_end = 0
    robot = None
    run = lambda: _robot(config, os.ttyname(slave), 60)  # noqa: E731
    try:
        for i in range(10):
            robot = run()
            # Mostly while sweeping (a pose takes ~0.03-0.13 s); some during start-up.
            if i % 4 == 3:
                _pump(host, robot, rng.uniform(0.1, 0.5), items)
            else:
                _pump(host, robot, rng.uniform(0.0, 0.12), items, after_boot=True)
            if len(_captured(items)) > len(POSES) - 16 or not _kill(robot):
                break  # near the end already: the kills below take over
            kills += 1
        # Around the end: once one of the last poses arrives the host falls silent, so the
        # robot goes on with its packets unacknowledged; a kill somewhere in the last poses.
        robot = run()
        if _pump(host, robot, 0.0, items, after_pose=POSES[-rng.randint(2, 5)]):
            time.sleep(rng.uniform(0.0, 0.25))
        _kill(robot)
        # The host silent throughout: killed just after the robot notes the sweep done, with
        # the last capture and "sweep done" still in its outbox.
        robot = run()
        assert _wait_for_done(tmp_path / "state" / "outbox.sqlite", len(POSES), robot), "sweep never ended"
        time.sleep(rng.uniform(0.0, 0.1))
        after_end += _kill(robot)
        # Restarts after the sweep finished, killed while the host is silent: a runtime that
        # swept again would queue captures now and the last run would deliver them.
        for _ in range(2):
            robot = run()
            time.sleep(rng.uniform(0.2, 0.6))
            after_end += _kill(robot)
        robot = run()  # the last run is left to finish
        _pump(host, robot, 70, items)
        err = robot.communicate(timeout=30)[1].decode()
        assert robot.returncode == 0, err
        captures = store.captures()
    finally:
        if robot is not None and robot.poll() is None:
            robot.kill()
        store.close()
        os.close(master)
        os.close(slave)
    assert kills >= 6 and after_end == 3, (kills, after_end)
    # Every pose of the sweep reached the host exactly once: a kill anywhere (even between
    # queueing a capture and noting the pose done, or after the last pose) repeats no pose.
    by_pose = Counter((c.commanded[0], c.commanded[1]) for c in captures)
    assert sorted(by_pose) == sorted(POSES)
    assert set(by_pose.values()) == {1}, {p: n for p, n in by_pose.items() if n > 1}
    # Nothing delivered twice: each (robot, sequence) was stored by exactly one delivery, and
    # a re-sent packet (killed before its ACK came back) was recognised, not stored again.
    stored = [(i.robot, i.seq) for i in items
              if i.kind in (ItemKind.CAPTURE, ItemKind.UNCHANGED) and i.stored]
    assert len(stored) == len(set(stored)) == len(captures) == len(POSES)
    statuses = [i.packet for i in items if i.kind is ItemKind.STATUS]
    assert [p.text for p in statuses].count("sweep done") >= 1
    # Boots after the sweep finished say so, and every boot names the one sweep.
    boots = [p for p in statuses if p.text == "boot"]
    assert boots[-1].report.sweep.boot == "finished", boots[-1].report
    assert {p.report.sweep.id for p in boots} == {1}
    # Restarts open new sessions above the persisted counters: no fresh frame was taken for
    # a replay (torn frames cut by a kill only fail their CRC or COBS).
    rejected = host.stats().rejected
    assert rejected.get("replay", 0) == 0 and rejected.get("stale", 0) == 0, rejected
    # Each boot opened a session, but the two killed while the host was silent, whose boot
    # STATUS the next run delivered from its outbox (so it is counted by its time, once).
    assert host.stats().sessions_opened >= len({p.time for p in boots}) - 2 >= kills // 2
