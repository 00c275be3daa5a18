"""`btf-host listen` on a database with a bad row: an UNCHANGED marker reads the referenced
capture's stored models, and a row that is not one we write ends listen with one line (exit 2:
the database needs a person), with nothing acknowledged; it used to end in a traceback."""
import os
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

from radio import packets as pk
from radio.auth import MemoryCounterStore
from radio.keys import load_key, write_key
from radio.link import Acked, Link, LinkUp
from radio.ports import FdPort
from radio.pump import LinkPump
from tests.support import ROOT
from tests.support.packets import models_body
from tools.demo.pty_cable import PtyCable
from tools.station.receiver import HOST_NODE, LINK_ID, ROBOT_NODE, Receiver, StoreFailed
from tools.store.database import Store


def _db_with_a_bad_model_row(path: Path) -> None:
    with Store.open(path) as store:
        assert Receiver(store).handle(models_body(1)[0]).stored
    conn = sqlite3.connect(path)
    conn.execute("UPDATE models SET gamma = 'not a number' WHERE label = (SELECT MIN(label) FROM models)")
    conn.commit()
    conn.close()


def _unchanged(seq: int, ref: int) -> bytes:
    return pk.encode(pk.UnchangedPacket(3, seq, 200.0, (60.0, 0.0), (60.2, 0.1), ref))


def test_the_receiver_turns_a_bad_referenced_row_into_one_line(tmp_path):
    _db_with_a_bad_model_row(tmp_path / "h.sqlite")
    with Store.open(tmp_path / "h.sqlite") as store:
        try:
            Receiver(store).handle(_unchanged(2, 1))
        except StoreFailed as exc:
            failed = exc
    assert failed.damaged and "\n" not in str(failed) and "gamma" in str(failed)


def test_listen_ends_with_one_line_and_acknowledges_nothing_on_a_bad_row(tmp_path):
    db = tmp_path / "h.sqlite"
    _db_with_a_bad_model_row(db)
    key = write_key(tmp_path / "link.key")
    bridge = PtyCable()
    robot = LinkPump(Link(ROBOT_NODE, HOST_NODE, LINK_ID, load_key(key), MemoryCounterStore(wall=time.time),
                          heartbeat=0.2), FdPort(os.open(bridge.paths[0], os.O_RDWR | os.O_NOCTTY), timeout=0.005))
    listen = subprocess.Popen(
        [sys.executable, "-c", "import sys; from tools.cli import main; sys.exit(main())", "listen",
         "--port", bridge.paths[1], "--db", str(db), "--key", str(key), "--until-idle", "30"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    events: list = []
    try:
        end = time.monotonic() + 60
        while listen.poll() is None and time.monotonic() < end and not any(isinstance(e, LinkUp) for e in events):
            events += robot.step()
        sent = robot.send(_unchanged(2, 1), msg_id=2)
        while listen.poll() is None and time.monotonic() < end:
            events += robot.step()
        for _ in range(50):
            events += robot.step()
        err = listen.communicate(timeout=30)[1]
    finally:
        if listen.poll() is None:
            listen.kill()
        robot.close()
        bridge.close()
    lines = [line for line in err.splitlines() if line.strip() and "counters file" not in line]
    assert listen.returncode == 2, err
    assert len(lines) == 1 and lines[0].startswith("btf-host: error: database") and "gamma" in lines[0], err
    assert not [e for e in events if isinstance(e, Acked) and e.msg_id == sent]
