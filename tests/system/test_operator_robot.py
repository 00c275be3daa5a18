"""What an operator met on the robot side: torque that could not
come back, errors after a clean boot, a settable key that could not be set, send-mask's seq,
a state dir that cannot be used, and a robot that said nothing."""
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

from radio import packets as pk
from radio.auth import MemoryCounterStore
from radio.channel import ChannelConfig
from radio.channel_port import Cable
from radio.link import Delivered, Link
from radio.packets.base import iso_time
from radio.pump import LinkPump
from tests.support import ROOT
from tests.support.robots import IDLE, SMALL, robot_toml
from tools.cli import build_parser
from tools.cli.cmd import command_of
from tools.station.snapshot import StationSnapshot

C = pk.CommandName
ROBOT = robot_toml(IDLE)
ISO = r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ"


def command(rt, tr, cid, name, **args):
    """Deliver one command, turn the robot once, and return its answer."""
    tr.receive(pk.encode(pk.CommandPacket(cid, name, args)))
    rt.step()
    return answers(tr)[cid]


def answers(tr):
    out = {}
    for _, body in tr.sent:
        p = pk.decode(body)
        if isinstance(p, (pk.AckPacket, pk.NackPacket)):
            out[p.command_id] = p
    return out


def run_sweep(rt, tr):
    rt.run(lambda r: r.progress is not None and r.idle())
    return [p for p in map(pk.decode, (b for _, b in tr.sent)) if isinstance(p, pk.ModelsPacket)]


def test_torque_off_then_goto_and_sweep_are_refused_with_how_to_recover(fake_robot):
    rt, tr = fake_robot(ROBOT)
    rt.boot()
    assert isinstance(command(rt, tr, 1, C.TORQUE_OFF), pk.AckPacket)
    for cid, name, args in ((2, C.GOTO, {"elevation": 70.0, "azimuth": 0.0}),
                            (3, C.SWEEP, {"elevations": [80.0, 60.0], "azimuths": [0.0]})):
        nack = command(rt, tr, cid, name, **args)
        assert isinstance(nack, pk.NackPacket) and nack.reason is pk.Reason.TORQUE_OFF
        assert "send torque-on" in nack.text
    assert rt.progress is None  # the refused sweep was never started, so no pose is skipped


def test_torque_off_says_it_ended_the_running_sweep_and_where(fake_robot):
    rt, tr = fake_robot(ROBOT)
    rt.boot()
    assert isinstance(command(rt, tr, 1, C.SWEEP, elevations=[80.0, 60.0, 40.0]), pk.AckPacket)
    rt.step()  # the first pose
    before = len(tr.sent)
    assert isinstance(command(rt, tr, 2, C.TORQUE_OFF), pk.AckPacket)
    (said,) = [p for p in map(pk.decode, (b for _, b in tr.sent[before:]))
               if isinstance(p, pk.StatusPacket) and p.text.startswith("torque-off ended sweep")]
    p = rt.progress
    assert 0 < p.next_index < 3 and not p.active  # stopped part-way
    assert f"sweep {p.sweep_id} at pose {p.next_index + 1} of 3" in said.text and said.report.sweep.active is False


def test_torque_off_torque_on_sweep_measures_every_pose(fake_robot):
    rt, tr = fake_robot(ROBOT)
    rt.boot()
    command(rt, tr, 1, C.TORQUE_OFF)
    ack = command(rt, tr, 2, C.TORQUE_ON)
    assert isinstance(ack, pk.AckPacket) and ack.extras["torque"] is True
    goto = command(rt, tr, 3, C.GOTO, elevation=70.0, azimuth=0.0)
    assert isinstance(goto, pk.AckPacket) and abs(goto.extras["elevation"] - 70.0) < 3
    assert isinstance(command(rt, tr, 4, C.SWEEP, elevations=[80.0, 60.0, 40.0], azimuths=[0.0]), pk.AckPacket)
    models = run_sweep(rt, tr)
    assert [round(p.commanded[0]) for p in models] == [80, 60, 40] and not rt.progress.skipped


def linked(fake_robot):
    """A robot and a host link over a simulated cable on a clock the test turns."""
    t = [0.0]
    clock = lambda: t[0]  # noqa: E731
    cable = Cable(ChannelConfig(latency=0.0, bandwidth=1e7, buffer=1 << 20), clock=clock)
    key = bytes(range(32))
    rt, _ = fake_robot(robot_toml(IDLE, {"link": {"heartbeat_s": 0.2, "failsafe_s": 1.0}}),
                       transport=LinkPump(Link(1, 2, 1, key, MemoryCounterStore(), heartbeat=0.2,
                                               link_timeout=1.0), cable.ends[0], clock=clock), clock=clock)
    host = LinkPump(Link(2, 1, 1, key, MemoryCounterStore(), heartbeat=0.2, link_timeout=1.0),
                    cable.ends[1], clock=clock)
    got = []

    def turn(n, host_on=True):
        for _ in range(n):
            t[0] += 0.05
            rt.step()
            if host_on:
                got.extend(pk.decode(e.payload) for e in host.step() if isinstance(e, Delivered))

    return rt, host, turn, got


def test_a_clean_boot_and_a_lost_link_leave_no_errors_and_status_times_are_iso(fake_robot):
    rt, host, turn, got = linked(fake_robot)
    rt.boot()
    turn(20)
    host.send(pk.encode(pk.CommandPacket(1, C.STATUS, {})))
    turn(20)
    turn(40, host_on=False)  # the base silent for 2 s: failsafe
    turn(40)
    host.send(pk.encode(pk.CommandPacket(2, C.STATUS, {})))
    turn(20)
    status = {p.command_id: p for p in got if isinstance(p, pk.AckPacket)}
    assert set(status) == {1, 2}
    for ack in status.values():
        assert ack.status.errors.items == () and ack.status.mode == "idle"
    # times travel as clock seconds and are shown as ISO 8601 (the station's snapshot, its page)
    snap = StationSnapshot("pty", "db", 0.0)
    snap.note_status_answer(status[2].status, 1.0)
    (event,) = snap.to_json(1.0)["robot"]["failsafe"]
    assert re.fullmatch(ISO + r" for \d+\.\d s", event), event
    report = next(p for p in got if isinstance(p, pk.StatusPacket) and p.text.startswith("failsafe"))
    (held,) = report.report.failsafe.items
    assert re.fullmatch(ISO, iso_time(held.since)) and held.until - held.since >= 0.0


def test_set_takes_a_list_as_the_packet_carries_it(fake_robot):
    rt, tr = fake_robot(ROBOT)
    rt.boot()
    # `btf-host cmd set sweep.azimuths [0,45]` sends a list, which the decoder hands over as a tuple
    ack = command(rt, tr, 1, C.SET, key="sweep.azimuths", value=[0, 45])
    assert isinstance(ack, pk.AckPacket), ack
    assert rt.cfg.sweep.azimuths == (0.0, 45.0)
    # and `cmd sweep` without --azimuths sweeps them: the command leaves them to the robot
    name, args = command_of(build_parser().parse_args(["cmd", "--port", "x", "--key", "k", "sweep", "--start", "80",
                                                       "--stop", "70", "--step", "10"]))
    ack = command(rt, tr, 2, name, **args)
    assert isinstance(ack, pk.AckPacket) and ack.extras["poses"] == 4, ack


def test_send_mask_sends_the_map_of_the_capture_named_or_refuses(fake_robot):
    rt, tr = fake_robot(ROBOT)
    rt.boot()
    seq = command(rt, tr, 1, C.CAPTURE).extras["seq"]
    nack = command(rt, tr, 2, C.SEND_MASK, seq=999)
    assert isinstance(nack, pk.NackPacket) and nack.reason is pk.Reason.NOT_FOUND
    assert f"seq {seq}" in nack.text and "capture 999" in nack.text
    masks = lambda: [p for p in map(pk.decode, (b for _, b in tr.sent)) if isinstance(p, pk.MaskPacket)]  # noqa: E731
    before = len(masks())
    ack = command(rt, tr, 3, C.SEND_MASK, seq=seq)
    assert isinstance(ack, pk.AckPacket) and len(masks()) == before + 1
    sent = masks()[-1]
    assert sent.seq == seq
    np.testing.assert_array_equal(sent.full_size(), rt.captures.last_labels)


def _robot(config: Path, *argv: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", "import sys; from onboard.cli import main; sys.exit(main())",
                           "run", "--config", str(config), *argv], capture_output=True, text=True,
                          timeout=timeout, cwd=ROOT)


def test_a_state_dir_that_cannot_be_used_is_one_line_and_exit_2(tmp_path):
    (tmp_path / "robot.key").write_text("00" * 32)
    (tmp_path / "robot.key").chmod(0o600)
    (tmp_path / "a-file").write_text("")
    for where, words in (("a-file", "not a directory"), ("/proc/btf-state", "cannot create it"),
                         ("/proc/self/status/state", "cannot create it")):
        config = tmp_path / "robot.toml"
        config.write_text(robot_toml({"link": {"key_file": "robot.key"}}, state_dir=where))
        out = _robot(config, "--max-seconds", "5")
        lines = out.stderr.strip().splitlines()
        assert out.returncode == 2 and len(lines) == 1, out.stderr
        assert "state_dir" in lines[0] and words in lines[0] and "Traceback" not in out.stderr


def test_the_robot_says_a_line_per_pose_and_command_on_its_console(tmp_path):
    (tmp_path / "robot.key").write_text("00" * 32)
    (tmp_path / "robot.key").chmod(0o600)
    config = tmp_path / "robot.toml"
    config.write_text(robot_toml(SMALL, {"link": {"key_file": "robot.key"}, "sweep": {"start": 90, "stop": 70}}))
    # loop:// hears only itself: nothing is acknowledged, so it runs until it is stopped
    robot = subprocess.Popen([sys.executable, "-c", "import sys; from onboard.cli import main; sys.exit(main())",
                              "run", "--config", str(config), "--port", "loop://", "--max-seconds", "120"],
                             stderr=subprocess.PIPE, text=True, cwd=ROOT)
    lines = []
    try:
        for line in robot.stderr:
            lines.append(line.rstrip("\n"))
            if line.startswith("sweep 1 done"):
                robot.terminate()  # SIGTERM: the runtime stops at its next turn, status 0
    finally:
        if robot.poll() is None:
            robot.kill()
    assert robot.wait(timeout=30) == 0, lines
    text = "\n".join(lines)
    assert lines[0] == "boot: robot 1 on the fake HAL, mode sweeping, sweep 1 started"
    poses = [x for x in lines if x.startswith("sweep 1 pose ")]
    assert [x.split(":")[0] for x in poses] == [f"sweep 1 pose {i}/3 at {e}.0°/0.0°"
                                                 for i, e in ((1, 90), (2, 80), (3, 70))]
    assert all(re.search(r": seq \d+, measured [\d.]+°/[\d.]+°, \d+ models$", x) for x in poses), poses
    assert "sweep 1 done: 3 measured, 0 missing" in lines
    assert "\x1b" not in text and "\r" not in text  # no colours, no progress bars
