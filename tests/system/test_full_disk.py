"""A full disk, on a real small one (a tmpfs in a mount namespace, tests/small_disk.py): the robot
pauses acquisition and says so in STATUS, keeps acknowledging, and resumes when room returns;
it restarts on a full disk instead of giving up; the host never acknowledges what it could not
store."""
import os
import subprocess
import time
import tty
from collections import Counter
from pathlib import Path

import pytest

from radio.auth import MemoryCounterStore
from radio.keys import load_key, write_key
from radio.link import Link
from radio.ports import FdPort
from radio.pump import LinkPump
from tests.support import ROOT
from tests.support.robots import EVERY_POSE, LINKED, SWEEP_TWO_AZIMUTHS, robot_toml
from tests.support.small_disk import SmallDisk, python, robot_argv
from tools.station.receiver import HOST_NODE, LINK_ID, ROBOT_NODE, HostSession, ItemKind, Receiver
from tools.store.database import Store

MiB = 1024 * 1024
DISK, MIN_FREE, RESERVE = 16 * MiB, 4 * MiB, 2 * MiB
ELEVATIONS = [90.0 - 2.0 * i for i in range(31)]
POSES = {(e, a) for a in (0.0, 90.0) for e in ELEVATIONS}
CONFIG = robot_toml(LINKED, EVERY_POSE, SWEEP_TWO_AZIMUTHS, robot_id=3, state_dir="state",
                    disk_min_free_bytes=MIN_FREE, disk_reserve_bytes=RESERVE)


class Bench:
    """A robot process whose state_dir is a small disk, on one end of a pty; the host here."""

    def __init__(self, tmp_path: Path) -> None:
        self.tmp = tmp_path
        (tmp_path / "state").mkdir()
        self.disk = SmallDisk(tmp_path / "state", DISK)
        write_key(tmp_path / "robot.key")
        (tmp_path / "robot.toml").write_text(CONFIG)
        self.master, self.slave = os.openpty()
        tty.setraw(self.master)
        tty.setraw(self.slave)
        self.store = Store.open(tmp_path / "host.sqlite")
        link = Link(HOST_NODE, ROBOT_NODE, LINK_ID, load_key(tmp_path / "robot.key"),
                    MemoryCounterStore(wall=time.time), heartbeat=0.2, link_timeout=30)
        self.host = HostSession(LinkPump(link, FdPort(self.master, timeout=0.005)), Receiver(self.store))
        self.items: list = []
        self.robot: subprocess.Popen | None = None

    def start(self, *extra: str) -> subprocess.Popen:
        argv = robot_argv("run", "--config", str(self.tmp / "robot.toml"), "--hal", "fake",
                          "--port", os.ttyname(self.slave), "--max-seconds", "120", *extra)
        self.robot = subprocess.Popen(self.disk.argv(argv), cwd=ROOT, stdout=subprocess.DEVNULL,
                                      stderr=subprocess.PIPE)
        return self.robot

    def pump_until(self, done, limit_s: float = 60.0) -> bool:
        end = time.monotonic() + limit_s
        while time.monotonic() < end and self.robot.poll() is None:
            self.items += self.host.step()
            if done():
                return True
        return done()

    def captures(self) -> list:
        return [i.packet for i in self.items if i.kind is ItemKind.CAPTURE]

    def statuses(self) -> list:
        return [i.packet for i in self.items if i.kind is ItemKind.STATUS]

    def why(self) -> str:
        """What the robot said, for a failed assertion."""
        err = ""
        if self.robot.poll() is not None:
            err = self.robot.communicate(timeout=10)[1].decode()
        return f"exit {self.robot.returncode}; statuses {[p.text for p in self.statuses()]}; stderr {err}"

    def every_pose_once(self) -> None:
        by_pose = Counter((c.commanded[0], c.commanded[1]) for c in self.store.captures())
        assert set(by_pose) == POSES and set(by_pose.values()) == {1}, by_pose

    def close(self) -> None:
        if self.robot is not None and self.robot.poll() is None:
            self.robot.kill()
            self.robot.wait(timeout=10)
        self.disk.close()
        self.store.close()
        os.close(self.master)
        os.close(self.slave)


@pytest.fixture
def bench(tmp_path):
    b = Bench(tmp_path)
    yield b
    b.close()


def _pressure(statuses: list) -> list:
    return [p for p in statuses if p.report.disk is not None and p.report.disk.state in ("low", "full")]


def test_a_disk_filled_mid_sweep_pauses_acquisition_says_so_and_every_pose_arrives_once(bench):
    robot = bench.start("--exit-when-idle")
    assert bench.pump_until(lambda: len(bench.captures()) >= 5), bench.why()
    assert bench.disk.fill() > MIN_FREE  # the disk had room, and has none now
    assert bench.pump_until(lambda: _pressure(bench.statuses()), 30), bench.why()
    paused_at = len(bench.captures())
    bench.pump_until(lambda: False, 1.5)  # captures already queued may still arrive; no new pose
    (bench.disk.path / "filler").unlink()
    bench.pump_until(lambda: robot.poll() is not None, 90)
    err = robot.communicate(timeout=30)[1].decode()
    assert robot.returncode == 0, err
    pressure = _pressure(bench.statuses())[0]
    back = [p for p in bench.statuses() if p.text.startswith("disk has room again")]
    assert back, [p.text for p in bench.statuses()]
    # Paused mid-sweep: no pose was measured between the two statuses.
    during = [c for c in bench.captures() if pressure.time < c.time < back[0].time]
    assert not during, [(c.seq, c.time) for c in during]
    assert 5 <= paused_at < len(POSES)
    assert pressure.state.name == "PAUSED" and "disk" in pressure.text
    bench.every_pose_once()


def test_a_robot_restarted_on_a_full_disk_runs_paused_says_why_and_resumes(bench):
    """Restarting on the full disk used to exit 2, which systemd does not restart."""
    robot = bench.start("--exit-when-idle")
    assert bench.pump_until(lambda: len(bench.captures()) >= 5), bench.why()
    robot.kill()  # mid-sweep, its state on the small disk
    robot.wait(timeout=10)
    bench.disk.fill()
    robot = bench.start("--exit-when-idle")
    assert bench.pump_until(lambda: _pressure(bench.statuses()), 30), bench.why()
    assert robot.poll() is None  # running, not exited
    (bench.disk.path / "filler").unlink()
    bench.pump_until(lambda: robot.poll() is not None, 90)
    err = robot.communicate(timeout=30)[1].decode()
    assert robot.returncode == 0, err
    bench.every_pose_once()


def test_with_no_room_even_to_open_its_state_the_robot_exits_1_to_be_retried(bench):
    bench.disk.fill()  # a fresh state_dir on a full disk: no reserve to release
    robot = bench.start()
    err = robot.communicate(timeout=120)[1].decode()
    errors = [line for line in err.splitlines() if ": error: " in line]
    assert robot.returncode == 1, err
    assert len(errors) == 1 and "state_dir" in errors[0] and "Traceback" not in err


class Listener:
    """`btf-host listen` on a small disk (its database there), and a robot link here."""

    def __init__(self, tmp_path: Path) -> None:
        from tools.demo.pty_cable import PtyCable

        self.key = write_key(tmp_path / "link.key")
        (tmp_path / "db").mkdir()
        self.disk = SmallDisk(tmp_path / "db", 2 * MiB)
        self.bridge = PtyCable()
        self.db = tmp_path / "db" / "host.sqlite"
        fd = os.open(self.bridge.paths[0], os.O_RDWR | os.O_NOCTTY)
        self.robot = LinkPump(Link(ROBOT_NODE, HOST_NODE, LINK_ID, load_key(self.key),
                                   MemoryCounterStore(wall=time.time), heartbeat=0.2), FdPort(fd, timeout=0.005))
        self.listen: subprocess.Popen | None = None
        self.events: list = []

    def start(self) -> None:
        self.listen = subprocess.Popen(self.disk.argv(python(
            "import sys; from tools.cli import main; sys.exit(main())", "listen", "--port", self.bridge.paths[1],
            "--db", str(self.db), "--key", str(self.key), "--until-idle", "30")), cwd=ROOT,
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    def pump(self, until, limit_s: float = 60.0) -> bool:
        end = time.monotonic() + limit_s
        while self.listen.poll() is None and time.monotonic() < end and not until():
            self.events += self.robot.step()
        for _ in range(50):  # what the host wrote before it exited
            self.events += self.robot.step()
        return until()

    def close(self) -> None:
        if self.listen is not None and self.listen.poll() is None:
            self.listen.kill()
            self.listen.wait(timeout=10)
        self.robot.close()
        self.bridge.close()
        self.disk.close()


@pytest.fixture
def listener(tmp_path):
    lst = Listener(tmp_path)
    yield lst
    lst.close()


def test_listen_started_on_a_full_disk_says_so_in_one_line_and_exits_1(listener):
    listener.disk.fill()
    listener.start()
    err = listener.listen.communicate(timeout=60)[1]
    lines = [line for line in err.splitlines() if line.strip()]
    assert listener.listen.returncode == 1, err
    assert lines[-1].startswith("btf-host: error: database") and "Traceback" not in err


def test_listen_whose_disk_fills_says_so_in_one_line_and_acknowledges_nothing_it_did_not_store(listener):
    from radio.link import Acked, LinkUp
    from tests.support.packets import models_body

    listener.start()
    assert listener.pump(lambda: any(isinstance(e, LinkUp) for e in listener.events)), "no link"
    listener.disk.fill()
    sent = listener.robot.send(models_body(7)[0], msg_id=7)
    listener.pump(lambda: listener.listen.poll() is not None)
    err = listener.listen.communicate(timeout=30)[1]
    lines = [line for line in err.splitlines() if line.strip()]
    assert listener.listen.returncode == 1, err
    assert lines[-1].startswith("btf-host: error: database") and "(0 bytes free on its disk)" in lines[-1], err
    assert "nothing unstored was acknowledged" in lines[-1] and "Traceback" not in err
    # The robot keeps the capture and sends it again to a host with room.
    assert not [e for e in listener.events if isinstance(e, Acked) and e.msg_id == sent]


def test_the_systemd_unit_retries_exit_1_for_as_long_as_it_takes_and_never_exit_2():
    import configparser

    unit = configparser.ConfigParser(interpolation=None, strict=False)
    unit.optionxform = str
    unit.read(ROOT / "examples" / "btf-robot.service")
    assert unit["Service"]["Restart"] == "on-failure"  # any non-zero exit, 1 included
    assert unit["Service"]["RestartPreventExitStatus"].split() == ["2"]
    assert unit["Unit"]["StartLimitIntervalSec"] == "0"  # a disk that stays full is retried, not given up on
    assert "time-sync.target" in unit["Unit"]["After"]  # [link] clock = "rtc" trusts the clock from the start


def test_disk_pressure_follows_the_free_room_and_a_failed_write_holds_until_the_reserve_fits(tmp_path):
    from types import SimpleNamespace

    from onboard.disk import Disk, Pressure

    free = [100 * MiB]
    disk = Disk(tmp_path, MIN_FREE, RESERVE, statvfs=lambda _: SimpleNamespace(f_bavail=free[0], f_frsize=1))
    assert disk.pressure() is Pressure.OK and disk.held()  # room: the reserve is made
    free[0] = MIN_FREE - 1
    assert disk.pressure() is Pressure.LOW and disk.held()  # paused before the disk fills
    disk.write_failed("a write found the disk full")
    assert not disk.held()  # released for the writes that free room
    free[0] = MIN_FREE + RESERVE - 1
    assert disk.pressure() is Pressure.FULL  # room for the minimum, not yet for the reserve too
    free[0] = MIN_FREE + RESERVE
    assert disk.pressure() is Pressure.OK and disk.held() and not disk.failed
