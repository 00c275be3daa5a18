"""Acknowledged means durable: a power cut right after the robot's outbox empties loses no
capture the station acknowledged.

The station runs as a real `btf-host station` process under an LD_PRELOAD library
(tests/support/fsync_snapshot.c, built here with the system's C compiler) that copies the
database and its WAL at every fsync: the copies are what a power cut is sure to leave. A
fake robot sweeps 42 poses over a pty cable and exits once every packet is acknowledged (it
deletes its copy on each ACK); the station is killed at once, the copies are put back in its
place, and every capture the robot made must be in them."""
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from tests.support import ROOT
from tests.support.station_rig import Rig, kill9, robot_log
from tools.store.database import Store

# 42 poses: 21 elevations at two azimuths, swept at boot.
SWEEP = {"sweep": {"start": 90, "stop": 50, "step": 2, "azimuths": [0, 90]}}
POSES = 42


def build_shim(where: Path) -> Path:
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler (cc or gcc) to build the fsync snapshot library")
    out = where / "fsync_snapshot.so"
    subprocess.run([cc, "-shared", "-fPIC", "-O1", "-o", str(out), str(ROOT / "tests/support/fsync_snapshot.c"),
                    "-ldl", "-lpthread"], check=True, capture_output=True, timeout=120)
    return out


def restored(snapshots: Path, where: Path) -> Path:
    """The database as the last syncs left it: each file's last copy, in a directory of its own."""
    where.mkdir()
    for name in ("host.db", "host.db-wal", "host.db-journal"):
        if (snapshots / name).exists():
            shutil.copyfile(snapshots / name, where / name)
    return where / "host.db"


def test_a_power_cut_after_the_robots_outbox_empties_loses_no_acknowledged_capture(tmp_path):
    shim = build_shim(tmp_path)
    snapshots = tmp_path / "synced"
    snapshots.mkdir()
    rig = Rig(tmp_path, SWEEP)
    try:
        db = rig.db.resolve()
        station = rig.station(env={"LD_PRELOAD": str(shim), "BTF_POWERCUT_DB": str(db),
                                   "BTF_POWERCUT_DIR": str(snapshots)})
        rig.wait_up(station)
        robot = rig.robot("--exit-when-idle")
        assert robot.wait(timeout=240) == 0, robot_log(tmp_path)[-5:]  # every packet acknowledged
        kill9(station)  # the power goes, right after the last ACK
        live = {c.sequence for c in rig.captures()}
    finally:
        rig.close()
    made = {int(m[1]) for line in robot_log(tmp_path) if (m := re.search(r": seq (\d+)", line))}
    assert len(made) == POSES and live == made  # the sweep ran, and the station had it all
    syncs = (snapshots / "syncs").read_text().split()
    assert "host.db-wal" in syncs  # the shim saw the commits' syncs
    with Store.open(restored(snapshots, tmp_path / "after-the-cut")) as store:
        kept = {c.sequence for c in store.captures()}
    assert made - kept == set(), f"{len(made - kept)} of {len(made)} acknowledged captures lost"
