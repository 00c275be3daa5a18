"""A message the base could not use comes back as a NACK UNUSABLE naming it: the robot moves it
into its outbox's dead letters (its body kept when it still held it), never offers it again,
counts it, and says so in STATUS and its errors."""
import sqlite3

from onboard.link import dead_letters
from onboard.link.outbox import Outbox
from onboard.link.transport import MemoryTransport
from radio import packets as pk
from tests.support.robots import IDLE, SMALL, robot_toml

ROBOT = robot_toml(SMALL, IDLE)


def test_a_message_set_aside_leaves_the_queue_with_its_body_and_is_counted_once(tmp_path):
    path = tmp_path / "o.sqlite"
    with Outbox(path) as box:
        a, b = box.put(3, b"bad status"), box.put(1, b"a capture")
        assert box.set_aside(a, "sweep must be an int", refused=100.0) is True
        assert box.pending(10) == [(b, b"a capture")] and len(box) == 1 and box.bytes_used == 9 + 64
        assert box.set_aside(a, "again") is False  # refused twice (a re-delivery): one dead letter
        assert box.set_aside(777, "acknowledged before the refusal came", refused=101.0) is False
    with Outbox(path) as box:  # durable
        count, letters = box.dead_letters()
        assert count == 2 and [(d.msg_id, d.kind, d.body) for d in letters] == [(777, None, None), (a, 3, b"bad status")]
        assert letters[1].reason == "sweep must be an int" and box.pending(10) == [(b, b"a capture")]


def test_only_the_newest_dead_letters_are_kept_and_all_are_counted(tmp_path, monkeypatch):
    monkeypatch.setattr(dead_letters, "KEPT", 3)
    with Outbox(tmp_path / "o.sqlite") as box:
        ids = [box.put(3, bytes([i])) for i in range(5)]
        for n, i in enumerate(ids):
            box.set_aside(i, f"refusal {n}", refused=float(n))
        count, letters = box.dead_letters()
        assert count == 5 and [d.msg_id for d in letters] == ids[:1:-1]


def test_an_outbox_from_before_dead_letters_gains_them(tmp_path):
    path = tmp_path / "o.sqlite"
    with Outbox(path) as box:
        mid = box.put(3, b"x")
    con = sqlite3.connect(path)
    con.executescript("DROP TABLE dead_letters; PRAGMA user_version = 3;")
    con.close()
    with Outbox(path) as box:
        assert box.set_aside(mid, "refused") and box.dead_letters()[0] == 1


def test_the_robot_sets_aside_what_the_base_refuses_and_says_so_in_status(fake_robot):
    tr = MemoryTransport(auto_ack=False)  # nothing acknowledged: the refusal alone takes it out
    rt, _ = fake_robot(ROBOT, transport=tr)
    rt.boot()
    rt.step()
    (boot_id, boot_body), = [(m, b) for m, b in tr.sent if pk.decode(b).text == "boot"]
    tr.receive(pk.encode(pk.NackPacket(0, pk.Reason.UNUSABLE, "the base could not use it", msg_id=boot_id)))
    rt.step()
    assert boot_id not in [m for m, _ in rt.outbox.pending(100)]
    count, (letter,) = rt.outbox.dead_letters()
    assert count == 1 and letter.body == boot_body and letter.kind == int(pk.Kind.STATUS)
    assert any(f"refused message {boot_id}" in e for e in rt.state.errors)
    tr.receive(pk.encode(pk.CommandPacket(5, pk.CommandName.STATUS, {})))
    rt.step()
    answer = next(p for p in map(pk.decode, (b for _, b in tr.sent)) if isinstance(p, pk.AckPacket))
    shown = answer.status.dead_letters
    assert shown.count == 1 and shown.latest.items[0].msg_id == boot_id
    assert shown.latest.items[0].kind is pk.Kind.STATUS and shown.latest.items[0].reason == "the base could not use it"
