"""`btf-robot run --hal fake` against a host-side receiver over a real pseudo-terminal pair."""
import os
import re
import subprocess
import sys
import time
import tty

import pytest

from radio import packets as pk
from radio.auth import MemoryCounterStore
from radio.keys import load_key, write_key
from radio.link import Delivered, Link
from radio.ports import FdPort
from radio.pump import LinkPump
from tests.support import ROOT
from tests.support.robots import LINKED, robot_toml


def receive_sweep(tmp_path, scene, rate=0.0, limit_s=120.0, radio=""):
    """The packets a host receives of one sweep; `radio`: the robot's port goes through the
    simulated lossy radio with these btfsim:// options."""
    key_path = tmp_path / "robot.key"
    write_key(key_path)
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    # Nothing here waits a fixed time: the host runs until the robot exits (every packet
    # acknowledged). The one wall-clock bound is the settle timeout, which ends a stalled
    # servo (an injected fault) after 3 s; a healthy move takes under 1.5 s however loaded.
    (tmp_path / "robot.toml").write_text(
        robot_toml({"hal": {"scene": scene, "size": [60, 80], "fault_rate": rate, "fault_seed": 5}}, LINKED,
                   {"sweep": {"settle_timeout_s": 3}}))
    robot = subprocess.Popen(
        [sys.executable, "-c", "import sys; from onboard.cli import main; sys.exit(main())", "run",
         "--config", str(tmp_path / "robot.toml"), "--hal", "fake",
         "--port", f"btfsim://?port={os.ttyname(slave)}&{radio}" if radio else os.ttyname(slave),
         "--exit-when-idle", "--max-seconds", str(limit_s)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    host = LinkPump(Link(2, 1, 1, load_key(key_path), MemoryCounterStore(wall=time.time), heartbeat=0.2,
                         link_timeout=30),
                    FdPort(master, timeout=0.01))
    got: dict[int, object] = {}
    t0 = time.monotonic()
    try:
        while robot.poll() is None and time.monotonic() - t0 < limit_s + 10:
            for ev in host.read():
                if isinstance(ev, Delivered):
                    got[ev.msg_id] = pk.decode(ev.payload)
            host.write()
        # Let the last acks out before the robot sees its outbox empty.
        err = robot.communicate(timeout=30)[1].decode()
    finally:
        if robot.poll() is None:
            robot.kill()
        os.close(master)
        os.close(slave)
    assert robot.returncode == 0, err
    return list(got.values())


@pytest.mark.parametrize("scene, labels", [("black", {1}), ("white", {2}), ("mixed", {1, 2})])
def test_fake_robot_sweep_reaches_the_receiver_over_a_pty(tmp_path, scene, labels):
    packets = receive_sweep(tmp_path, scene)
    models = [p for p in packets if isinstance(p, pk.ModelsPacket)]
    assert sorted(round(p.commanded[0]) for p in models) == [30, 40, 50, 60, 70, 80, 90]
    for p in models:
        assert set(p.models) == {(lab, b) for lab in labels for b in range(3)}


def test_with_faults_every_skipped_pose_reaches_the_receiver_with_its_reason(tmp_path):
    packets = receive_sweep(tmp_path, "black", rate=0.1)
    models = [p for p in packets if isinstance(p, pk.ModelsPacket)]
    skipped = [p for p in packets if isinstance(p, pk.StatusPacket) and p.report.sweep and p.report.sweep.skipped]
    done = [p for p in packets if isinstance(p, pk.StatusPacket) and p.text == "sweep done"]
    assert done
    # A skipped pose is tried again after the plan: each ends measured, or missing with its reason.
    measured = {round(p.commanded[0]) for p in models}
    missing = {round(m.elevation): m.reason for m in done[-1].report.sweep.missing.items}
    assert len(models) == len(measured) and not measured & set(missing)
    assert measured | set(missing) == {30, 40, 50, 60, 70, 80, 90}
    assert all(missing.values())
    # each skip is said with its reason, a retry with its count ("skipped pose again (try 2 of 3): ...")
    assert all(re.fullmatch(r"skipped pose( again \(try \d+ of \d+\))?: \S.*", p.text) for p in skipped), \
        [p.text for p in skipped]


def test_the_robot_runs_through_a_lossy_radio_named_by_its_url(tmp_path):
    packets = receive_sweep(tmp_path, "mixed", radio="loss=0.1&ber=1e-4&seed=4")
    models = [p for p in packets if isinstance(p, pk.ModelsPacket)]
    assert sorted(round(p.commanded[0]) for p in models) == [30, 40, 50, 60, 70, 80, 90]
