"""The outbox keeps every packet until acknowledged, within its quota, across kill -9."""
from __future__ import annotations

import random
import sqlite3
import subprocess
import sys
import time

import pytest

from onboard.link.outbox import ROW_OVERHEAD, Outbox, OutboxError, OutboxFull


def test_put_pending_ack_in_order(tmp_path):
    with Outbox(tmp_path / "o.db") as box:
        ids = [box.put(1, f"body{i}".encode()) for i in range(5)]
        assert ids == sorted(ids) and len(set(ids)) == 5
        assert box.pending(10) == [(i, f"body{n}".encode()) for n, i in enumerate(ids)]
        assert box.pending(2) == [(ids[0], b"body0"), (ids[1], b"body1")]
        assert box.pending(10, after=ids[2]) == [(ids[3], b"body3"), (ids[4], b"body4")]
        assert box.ack(ids[1]) is True
        assert box.ack(ids[1]) is False  # a duplicate ack is harmless
        assert [i for i, _ in box.pending(10)] == [ids[0], ids[2], ids[3], ids[4]]
        assert len(box) == 4
        assert box.kind_of(ids[0]) == 1 and box.kind_of(ids[1]) is None


def test_rows_and_accounting_survive_reopen(tmp_path):
    path = tmp_path / "o.db"
    with Outbox(path) as box:
        a = box.put(2, b"x" * 100)
        b = box.put(3, b"y" * 50)
        box.ack(a)
        used = box.bytes_used
    assert used == 50 + ROW_OVERHEAD
    with Outbox(path) as box:
        assert len(box) == 1 and box.bytes_used == used
        assert box.pending(5) == [(b, b"y" * 50)]
        assert box.check() == "ok"


def test_ids_are_never_reused_after_the_newest_row_is_acked(tmp_path):
    path = tmp_path / "o.db"
    with Outbox(path) as box:
        first = box.put(1, b"a")
        box.ack(first)
    with Outbox(path) as box:
        assert box.put(1, b"b") > first


def test_database_is_in_wal_mode(tmp_path):
    path = tmp_path / "o.db"
    Outbox(path).close()
    conn = sqlite3.connect(path)
    assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    conn.close()


def test_quota_refuses_new_rows_and_drops_nothing(tmp_path):
    quota = 10 * (100 + ROW_OVERHEAD)
    with Outbox(tmp_path / "o.db", quota_bytes=quota) as box:
        ids = [box.put(1, bytes([i]) * 100) for i in range(10)]
        assert box.full
        with pytest.raises(OutboxFull, match="acquisition paused"):
            box.put(1, b"z" * 100)
        assert len(box) == 10
        assert [b for _, b in box.pending(20)] == [bytes([i]) * 100 for i in range(10)]
        box.ack(ids[0])
        assert not box.full
        box.put(1, b"z" * 100)
        with pytest.raises(OutboxFull):
            box.put(1, b"w")


@pytest.mark.parametrize(
    "kind, body, error",
    [(256, b"a", ValueError), (-1, b"a", ValueError), (True, b"a", ValueError),
     (1, b"", ValueError), (1, "text", TypeError)],
)
def test_bad_rows_are_refused(tmp_path, kind, body, error):
    with Outbox(tmp_path / "o.db") as box:
        with pytest.raises(error):
            box.put(kind, body)
        assert len(box) == 0


def test_bad_quota_and_corrupt_file_give_clear_errors(tmp_path):
    with pytest.raises(ValueError, match="quota"):
        Outbox(tmp_path / "o.db", quota_bytes=0)
    bad = tmp_path / "bad.db"
    bad.write_bytes(b"this is not a database" * 100)
    with pytest.raises(OutboxError, match="bad.db"):
        Outbox(bad)


WRITER = r"""
import sys
from onboard.link.outbox import Outbox
box = Outbox(sys.argv[1])
run = int(sys.argv[2])
print("ready", flush=True)
i = 0
while True:
    msg_id = box.put(7, f"{run}:{i}:".encode() + bytes(i % 200))
    print("put", msg_id, run, i, flush=True)
    if i % 3 == 2:
        oldest = box.pending(1)[0][0]
        print("acking", oldest, flush=True)
        box.ack(oldest)
        print("ack", oldest, flush=True)
    i += 1
"""


def test_kill_9_at_random_instants_loses_and_duplicates_nothing(tmp_path):
    path = tmp_path / "o.db"
    rng = random.Random(4)
    confirmed: dict[int, bytes] = {}
    acked: set[int] = set()
    acking: set[int] = set()  # an ack was under way: the row may or may not be gone
    for run in range(20):
        proc = subprocess.Popen(
            [sys.executable, "-c", WRITER, str(path), str(run)],
            stdout=subprocess.PIPE, text=True,
        )
        assert proc.stdout.readline().strip() == "ready"
        time.sleep(rng.uniform(0.0, 0.08))
        proc.kill()  # SIGKILL: no cleanup, no flush, no close
        out, _ = proc.communicate()
        for line in out.splitlines(keepends=True):
            if not line.endswith("\n"):
                continue  # the writer died mid-print: that call is unconfirmed
            parts = line.split()
            if parts[0] == "put":
                msg_id, r, i = int(parts[1]), int(parts[2]), int(parts[3])
                assert msg_id not in confirmed, "an id was reused"
                confirmed[msg_id] = f"{r}:{i}:".encode() + bytes(i % 200)
            elif parts[0] == "ack":
                acked.add(int(parts[1]))
            elif parts[0] == "acking":
                acking.add(int(parts[1]))

        conn = sqlite3.connect(path)
        assert conn.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        rows = conn.execute("SELECT id, body FROM outbox").fetchall()
        conn.close()
        bodies = [bytes(b) for _, b in rows]
        assert len(bodies) == len(set(bodies)), "a body is stored twice"
        stored = {i: bytes(b) for i, b in rows}
        for msg_id, body in confirmed.items():
            if msg_id in acked:
                assert msg_id not in stored, "an acknowledged row came back"
            elif msg_id in acking and msg_id not in stored:
                continue
            else:
                assert stored.get(msg_id) == body, "a confirmed put was lost"
    assert len(confirmed) > 20, "the writer never got going; the test proved nothing"
    with Outbox(path) as box:
        assert len(box) == len(box.pending(100000))


def test_a_reserve_keeps_room_below_the_quota_for_other_rows(tmp_path):
    row = 100 + ROW_OVERHEAD
    with Outbox(tmp_path / "o.db", quota_bytes=10 * row) as box:
        for _ in range(8):
            box.commit([(1, b"d" * 100)], reserve=2 * row)
        assert box.full_for(2 * row) and not box.full
        with pytest.raises(OutboxFull):
            box.commit([(1, b"d" * 100)], {"k": "v"}, reserve=2 * row)
        assert box.state("k") is None  # all or nothing
        box.put(2, b"r" * 100)  # a row without the reserve still fits
        box.put(2, b"r" * 100)
        assert box.full and len(box) == 10
