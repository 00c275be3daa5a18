"""systemd notification from the runtime over a real AF_UNIX datagram socket, and the
example unit that relies on it (Type=notify, WatchdogSec, Restart=on-failure)."""
import configparser
import os
import socket

import pytest

from onboard import cli
from onboard.runtime import Mode
from onboard.watchdog import Notifier
from tests.support import ROOT
from tests.support.robots import robot_toml

UNIT = ROOT / "examples" / "btf-robot.service"
ROBOT = robot_toml({"hal": {"scene": "black"}, "sweep": {"start": 90, "stop": 60, "step": 10}})


@pytest.fixture
def systemd(tmp_path, monkeypatch):
    """A bound datagram socket standing in for systemd's $NOTIFY_SOCKET."""
    path = tmp_path / "notify"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(path))
    sock.setblocking(False)
    monkeypatch.setenv("NOTIFY_SOCKET", str(path))
    yield sock
    sock.close()


def drain(sock) -> list[str]:
    out = []
    while True:
        try:
            out.append(sock.recv(4096).decode())
        except BlockingIOError:
            return out


def unit() -> configparser.ConfigParser:
    parser = configparser.ConfigParser(interpolation=None, strict=False)
    parser.optionxform = str  # systemd keys are case-sensitive
    parser.read(UNIT)
    return parser


def watchdog_usec() -> int:
    text = unit()["Service"]["WatchdogSec"].strip()
    return int(float(text.removesuffix("s")) * 1_000_000)


def test_runtime_says_ready_kicks_the_watchdog_at_half_its_period_and_reports_status(
        fake_robot, systemd, monkeypatch):
    monkeypatch.setenv("WATCHDOG_USEC", str(watchdog_usec()))  # as systemd sets it from the unit
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()))
    period = watchdog_usec() / 1e6
    now = [0.0]
    notifier = Notifier(clock=lambda: now[0])
    assert notifier.enabled
    rt, _ = fake_robot(ROBOT, notifier=notifier)
    rt.boot()
    got = [(now[0], m) for m in drain(systemd)]
    assert got[0][1].startswith("READY=1\nSTATUS=btf-robot running")
    # The loop turns every period/8 of (watchdog) time: kicks come every period/2.
    tick = period / 8
    for _ in range(40):
        now[0] += tick
        rt.step()
        got += [(now[0], m) for m in drain(systemd)]
    kicks = [t for t, m in got if m == "WATCHDOG=1"]
    assert kicks[0] == tick and len(kicks) == 10  # from the first turn, every 4th of 40
    assert all(b - a == pytest.approx(period / 2) for a, b in zip(kicks, kicks[1:]))
    statuses = [m.removeprefix("STATUS=") for _, m in got if m.startswith("STATUS=")]
    assert statuses[0] == "boot"
    assert [s for s in statuses if " pose " in s] == [
        f"sweep 1: measured pose {i} of 4" for i in range(1, 5)]
    assert statuses[-1] == "sweep 1 done: 4 measured, 0 missing" and rt.mode is Mode.IDLE
    assert all("=" in field for _, m in got for field in m.split("\n"))  # KEY=value lines only


def test_watchdog_meant_for_another_process_is_not_kicked(systemd, monkeypatch):
    monkeypatch.setenv("WATCHDOG_USEC", "1000000")
    monkeypatch.setenv("WATCHDOG_PID", str(os.getpid() + 1))
    notifier = Notifier(clock=lambda: 100.0)
    assert notifier.kick() is False
    assert notifier.status("line one\nline two") is True
    assert drain(systemd) == ["STATUS=line one line two"]  # a newline would be a new field


def test_without_notify_socket_every_call_is_a_no_op(monkeypatch, tmp_path):
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    notifier = Notifier()
    assert not notifier.enabled
    assert notifier.ready() is False and notifier.kick() is False
    # A socket that vanished (systemd restarted) never stops the robot.
    gone = Notifier(address=str(tmp_path / "nobody"))
    assert gone.enabled and gone.notify("WATCHDOG=1") is False


def test_example_unit_matches_the_runtime():
    service = unit()["Service"]
    assert service["Type"] == "notify"  # the runtime sends READY=1 itself
    assert service["NotifyAccess"] in ("main", "all")
    assert service["Restart"] == "on-failure"
    assert 1 <= watchdog_usec() / 1e6 <= 300
    # Exit 2 is btf-robot's configuration error, which a restart cannot fix.
    assert service["RestartPreventExitStatus"].split() == ["2"]
    assert cli.main(["run", "--config", "/nonexistent/robot.toml"]) == 2
    # ExecStart names a command line btf-robot accepts.
    exe, *argv = service["ExecStart"].split()
    assert exe.endswith("/btf-robot")
    parser = cli.build_parser()
    args = parser.parse_args(argv)
    assert args.command == "run" and args.config and not args.new_sweep
