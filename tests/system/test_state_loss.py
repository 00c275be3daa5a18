"""A robot whose state was lost (a new SD card, a wiped state_dir) numbers its captures from 1
again: as a new incarnation, whose captures the host keeps, while it still refuses a genuine
duplicate. A damaged outbox is moved aside, not restarted over and over."""
import json
import shutil
import signal
import sqlite3
import subprocess
import sys
from collections import Counter
from pathlib import Path

from radio.auth import MemoryCounterStore
from radio.link import Delivered, Link
from tests.support import ROOT
from tests.support.packets import models_body
from tests.support.robots import LINKED, robot_toml
from tools.cli import main as host_main
from tools.demo.pty_cable import PtyCable
from tools.station.receiver import Receiver
from tools.store.database import Store

KEY = bytes(range(32))
CONFIG = robot_toml(LINKED, robot_id=5, state_dir="state")


def _sweep_into(tmp_path: Path, db: Path) -> list[dict]:
    """One robot run (the config's sweep, to the end) into `db` through `btf-host listen`; what
    listen printed."""
    bridge = PtyCable()
    try:
        robot = subprocess.Popen(
            [sys.executable, "-c", "import sys; from onboard.cli import main; sys.exit(main())", "run",
             "--config", str(tmp_path / "robot.toml"), "--port", bridge.paths[0], "--exit-when-idle",
             "--max-seconds", "90"], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        listen = subprocess.Popen(
            [sys.executable, "-c", "import sys; from tools.cli import main; sys.exit(main())", "listen",
             "--port", bridge.paths[1], "--db", str(db), "--key", str(tmp_path / "robot.key"),
             "--until-idle", "60", "--json"], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        err = robot.communicate(timeout=120)[1].decode()
        # the robot ends once every packet is acknowledged, so stored: listen has heard it all
        listen.send_signal(signal.SIGTERM)
        out, listen_err = listen.communicate(timeout=60)
    finally:
        bridge.close()
    assert robot.returncode == 0 and listen.returncode == 0, (err, listen_err)
    return [json.loads(line) for line in out.splitlines()]


def test_a_wiped_state_with_a_rotated_key_has_every_new_capture_stored(tmp_path, capsys):
    (tmp_path / "robot.toml").write_text(CONFIG)
    db = tmp_path / "host.sqlite"
    assert host_main(["keygen", "--out", str(tmp_path / "robot.key")]) == 0
    first = _sweep_into(tmp_path, db)
    shutil.rmtree(tmp_path / "state")  # a new SD card
    assert host_main(["keygen", "--out", str(tmp_path / "robot.key"), "--force"]) == 0
    second = _sweep_into(tmp_path, db)
    captures = [r for r in second if r["kind"] == "capture"]
    assert len(captures) == 7 and all(r["stored"] for r in captures)  # 100% of the new captures
    assert second[-1]["kind"] == "summary" and second[-1]["duplicates"] == 0
    assert [r["seq"] for r in captures] == [r["seq"] for r in first if r["kind"] == "capture"]  # 1..7 again
    with Store.open(db) as store:
        rows = store.captures(robot="5")
    by_incarnation = Counter(c.incarnation for c in rows)
    assert len(rows) == 14 and len(by_incarnation) == 2 and set(by_incarnation.values()) == {7}
    assert "" not in by_incarnation and {captures[0]["incarnation"]} < set(by_incarnation)


def test_the_host_refuses_a_genuine_duplicate_and_keeps_a_new_incarnation_s_capture(tmp_path):
    body = models_body(3)[0]
    with Store.open(tmp_path / "h.sqlite") as store:
        receiver = Receiver(store)
        assert receiver.handle(body, "aa01").stored
        assert not receiver.handle(body, "aa01").stored  # re-sent: the same robot state's capture 3
        assert receiver.handle(body, "bb02").stored  # a wiped robot's own capture 3
        assert receiver.duplicates == 1
        assert sorted(c.incarnation for c in store.captures()) == ["aa01", "bb02"]


def test_a_new_incarnation_s_messages_are_not_taken_for_the_old_one_s():
    """The link's dedup window holds message ids (outbox rows): a robot whose outbox is new
    reuses them, and its session says it is another incarnation."""
    host = Link(0, 1, 5, KEY, MemoryCounterStore())

    def deliver(robot: Link, t: float) -> list[Delivered]:
        got = []
        for i in range(100):
            host.receive(robot.poll(t + i * 0.01), t + i * 0.01)
            robot.receive(host.poll(t + i * 0.01), t + i * 0.01)
            got += [e for e in host.pop_events() if isinstance(e, Delivered)]
        return got

    old = Link(1, 0, 5, KEY, MemoryCounterStore(), incarnation=bytes.fromhex("aa01"))
    old.send(b"capture 1 of the old state", 0.0, msg_id=1)
    assert [(e.msg_id, e.incarnation) for e in deliver(old, 0.0)] == [(1, bytes.fromhex("aa01"))]
    again = Link(1, 0, 5, KEY, MemoryCounterStore(start=10_000), incarnation=bytes.fromhex("aa01"))
    again.send(b"capture 1 of the old state", 2.0, msg_id=1)  # restarted, the same state: a re-send
    assert deliver(again, 2.0) == []
    new = Link(1, 0, 5, KEY, MemoryCounterStore(start=20_000), incarnation=bytes.fromhex("bb02"))
    new.send(b"capture 1 of the new state", 4.0, msg_id=1)
    got = deliver(new, 4.0)
    assert [(e.msg_id, e.payload, e.incarnation) for e in got] == [(1, b"capture 1 of the new state",
                                                                   bytes.fromhex("bb02"))]


def test_a_bit_rotted_outbox_is_moved_aside_and_the_robot_runs_on_a_new_one(tmp_path):
    """It used to exit 1 ("Could not decode to UTF-8") at every start: a restart loop."""
    from onboard.link.outbox import Outbox

    (tmp_path / "robot.toml").write_text(CONFIG + '[sweep]\nautostart = false\n')
    (tmp_path / "robot.key").write_text(KEY.hex())
    (tmp_path / "robot.key").chmod(0o600)
    (tmp_path / "state").mkdir()
    box = Outbox(tmp_path / "state" / "outbox.sqlite")
    box.commit([(1, b"an unsent packet")], {"next_seq": "12", "note": "hello world"})
    old = box.incarnation
    box.close()
    raw = bytearray((tmp_path / "state" / "outbox.sqlite").read_bytes())
    raw[raw.index(b"hello world")] = 0xFF  # one flipped byte in the state table's text
    (tmp_path / "state" / "outbox.sqlite").write_bytes(bytes(raw))
    proc = subprocess.run(
        [sys.executable, "-c", "import sys; from onboard.cli import main; sys.exit(main())", "run",
         "--config", str(tmp_path / "robot.toml"), "--port", "loop://", "--max-seconds", "1"],
        cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    notes = [line for line in proc.stderr.splitlines() if "damaged" in line]
    assert len(notes) == 1 and "moved aside to outbox.sqlite.damaged-" in notes[0], proc.stderr
    aside = list((tmp_path / "state").glob("outbox.sqlite.damaged-*"))
    assert [p.name.endswith("Z") for p in aside if not p.name.endswith(("-wal", "-shm"))] == [True]
    with Outbox(tmp_path / "state" / "outbox.sqlite") as fresh:
        assert fresh.incarnation not in ("", old) and fresh.state("next_seq") is None
    # The damaged file is kept for inspection, untouched.
    damaged = sqlite3.connect(next(p for p in aside if not p.name.endswith(("-wal", "-shm"))))
    assert damaged.execute("SELECT COUNT(*) FROM outbox").fetchone()[0] == 1
    damaged.close()


def test_a_schema_7_database_keeps_every_row_and_its_models_when_captures_gain_incarnations(tmp_path):
    """Schema 8 rebuilds the captures table (a UNIQUE constraint changes only so); with foreign
    keys on, dropping the old table would have cascaded to every model."""
    from tests.support.databases import SCHEMA_1
    from tools.store.schema import _MIGRATIONS, APPLICATION_ID

    db = tmp_path / "v7.sqlite"
    con = sqlite3.connect(db)
    con.executescript(SCHEMA_1 + "".join(_MIGRATIONS[v] for v in range(1, 7))
                      + f"PRAGMA user_version = 7; PRAGMA application_id = {APPLICATION_ID};")
    con.close()
    with Store.open(tmp_path / "new.sqlite") as fresh:  # the rows a version-7 host wrote
        Receiver(fresh).handle(models_body(4)[0])
        rows = fresh._conn.execute("SELECT * FROM models").fetchall()
    con = sqlite3.connect(db)
    con.execute("INSERT INTO captures (id, robot, sequence, time, elevation, azimuth, space, bands)"
                " VALUES (1, '3', 4, 104.0, 60.2, 0.1, 'rgb', '[\"R\", \"G\", \"B\"]')")
    con.executemany(f"INSERT INTO models VALUES ({','.join('?' * len(rows[0]))})", rows)
    con.commit()
    con.close()
    with Store.open(db) as store:
        (old,) = store.captures()
        assert old.incarnation == "" and old.sequence == 4 and len(store.models(old.id)) == len(rows)
        receiver = Receiver(store)
        assert not receiver.handle(models_body(4)[0]).stored  # the same capture, sent again
        assert receiver.handle(models_body(4)[0], "0123456789abcdef").stored  # a new robot state's
        assert store._conn.execute("PRAGMA foreign_key_check").fetchall() == []
