"""The sans-I/O link: sessions, ARQ, dedup across restarts, replay/forgery rejection, liveness."""
import os
import tty

import pytest

from radio.auth import FileCounterStore, MemoryCounterStore, write_fresh
from radio.link import Acked, Delivered, Link, LinkDown, LinkUp, QueueFull
from radio.ports import FdPort, open_url
from radio.pump import LinkPump

KEY = bytes(range(32))


def pair(**kw):
    robot = Link(1, 0, 5, KEY, MemoryCounterStore(), **kw)
    host = Link(0, 1, 5, KEY, MemoryCounterStore(), **kw)
    return robot, host


def fed(link, data, t):
    """Feed `data` to `link` at time t; the events it raised."""
    link.receive(data, t)
    return link.pop_events()


def pump(a, b, t, seconds, dt=0.01, tap=None):
    """Exchange bytes losslessly; returns (events at a, events at b, end time)."""
    ea, eb = [], []
    end = t + seconds
    while t < end:
        ab, ba = a.poll(t), b.poll(t)
        if tap:
            tap(ab)
        eb += fed(b, ab, t)
        ea += fed(a, ba, t)
        t += dt
    return ea, eb, t


def delivered(events):
    return [(e.msg_id, e.payload) for e in events if isinstance(e, Delivered)]


def test_messages_arrive_once_in_order_and_are_acked():
    robot, host = pair()
    msgs = {i: os.urandom(10 + 37 * i) for i in range(1, 40)}
    for i, m in msgs.items():
        robot.send(m, 0.0, msg_id=i)
    er, eh, _ = pump(robot, host, 0.0, 3.0)
    assert delivered(eh) == list(msgs.items())
    assert [e.msg_id for e in er if isinstance(e, Acked)] == list(msgs)
    assert robot.idle and robot.queued_bytes == 0
    assert any(isinstance(e, LinkUp) for e in eh)


def test_commands_flow_the_other_way_with_automatic_ids():
    robot, host = pair()
    ids = [host.send(b"cmd%d" % i, 0.0) for i in range(5)]
    er, eh, _ = pump(robot, host, 0.0, 1.0)
    assert [p for _, p in delivered(er)] == [b"cmd%d" % i for i in range(5)]
    assert [e.msg_id for e in eh if isinstance(e, Acked)] == ids


def test_sender_restart_resends_unacked_and_receiver_reacks_without_redelivery(tmp_path):
    write_fresh(tmp_path / "c.json")  # a new key's counters (keygen): nothing used yet
    store = FileCounterStore(tmp_path / "c.json")
    host = Link(0, 1, 5, KEY, MemoryCounterStore())
    robot = Link(1, 0, 5, KEY, store)
    robot.send(b"capture-1", 0.0, msg_id=1)
    # Host delivers, but every ACK back to the robot is lost: the robot never sees Acked.
    t = 0.0
    got = []
    while not got and t < 2.0:
        got += delivered(fed(host, robot.poll(t), t))
        if not got:
            robot.receive(host.poll(t), t)
        t += 0.01
    assert got == [(1, b"capture-1")]
    # The robot is killed and restarted: same outbox row, fresh Link, same counter file.
    robot2 = Link(1, 0, 5, KEY, FileCounterStore(tmp_path / "c.json"))
    robot2.send(b"capture-1", t, msg_id=1)
    robot2.send(b"capture-2", t, msg_id=2)
    er, eh, _ = pump(robot2, host, t, 2.0)
    assert delivered(eh) == [(2, b"capture-2")]
    assert {e.msg_id for e in er if isinstance(e, Acked)} == {1, 2}
    assert host.stats().duplicates == 1


def test_receiver_restart_asks_for_a_new_session_and_nothing_is_lost():
    robot, host = pair()
    robot.send(b"a", 0.0, msg_id=1)
    _, eh, t = pump(robot, host, 0.0, 0.5)
    assert delivered(eh) == [(1, b"a")]
    host2 = Link(0, 1, 5, KEY, MemoryCounterStore())
    robot.send(b"b", t, msg_id=2)
    er, eh2, _ = pump(robot, host2, t, 2.0)
    assert delivered(eh2) == [(2, b"b")]
    assert 2 in {e.msg_id for e in er if isinstance(e, Acked)}


def test_replayed_frames_are_rejected_and_counted():
    robot, host = pair()
    captured = []
    robot.send(b"x" * 300, 0.0, msg_id=9)
    _, eh, t = pump(robot, host, 0.0, 1.0, tap=captured.append)
    assert delivered(eh) == [(9, b"x" * 300)]
    for wire in captured:
        assert not delivered(fed(host, wire, t))
    rej = host.stats().rejected
    assert rej.get("replay", 0) + rej.get("stale", 0) >= len([w for w in captured if w])


def test_replay_after_receiver_restart_is_not_accepted(tmp_path):
    write_fresh(tmp_path / "host.json")
    store = FileCounterStore(tmp_path / "host.json")
    robot = Link(1, 0, 5, KEY, MemoryCounterStore())
    host = Link(0, 1, 5, KEY, store)
    captured = []
    robot.send(b"move arm", 0.0, msg_id=3)
    _, eh, t = pump(robot, host, 0.0, 1.0, tap=captured.append)
    assert len(delivered(eh)) == 1
    host2 = Link(0, 1, 5, KEY, FileCounterStore(tmp_path / "host.json"))
    events = []
    for wire in captured:
        events += fed(host2, wire, t)
    assert not delivered(events)


def test_forged_frames_are_rejected_and_counted():
    robot, host = pair()
    forger = Link(1, 0, 5, bytes(32), MemoryCounterStore(start=10**9))
    forger.send(b"FORGED", 0.0, reliable=False)
    _, eh, _ = pump(robot, host, 0.0, 0.5)
    assert not delivered(fed(host, forger.poll(0.5), 0.5))
    assert host.stats().rejected["tag"] >= 2  # its SYN and its datagram


def test_frames_for_another_link_or_from_another_sender_are_rejected():
    robot, host = pair()
    other = Link(1, 0, 6, KEY, MemoryCounterStore())
    host.receive(other.poll(0.0), 0.0)
    host.receive(host.poll(0.0), 0.0)  # its own frames echoed back
    rej = host.stats().rejected
    assert rej["link"] == 1 and rej["sender"] == 1


def test_link_down_after_silence_and_up_again():
    robot, host = pair(heartbeat=0.2, link_timeout=1.0)
    er, eh, t = pump(robot, host, 0.0, 1.0)
    assert host.up and robot.up
    host.poll(t + 2.0)
    assert any(isinstance(e, LinkDown) for e in host.pop_events())
    assert not host.up
    _, eh, _ = pump(robot, host, t + 2.0, 1.0)
    assert any(isinstance(e, LinkUp) for e in eh) and host.up


def test_unreliable_datagrams_are_reassembled_and_deduplicated():
    robot, host = pair()
    mid = robot.send(b"s" * 500, 0.0, reliable=False)
    captured = []
    _, eh, t = pump(robot, host, 0.0, 0.5, tap=captured.append)
    assert delivered(eh) == [(mid, b"s" * 500)]


def test_bounded_queue_refuses_more():
    robot, _ = pair(max_queue_bytes=1000)
    robot.send(b"x" * 900, 0.0, msg_id=1)
    with pytest.raises(QueueFull, match="900 bytes already queued"):
        robot.send(b"x" * 200, 0.0, msg_id=2)


def test_unsent_datagrams_count_against_the_queue_bound():
    robot, _ = pair(max_queue_bytes=1000)
    robot.send(b"d" * 600, 0.0, reliable=False)
    with pytest.raises(QueueFull):
        robot.send(b"d" * 600, 0.0, reliable=False)
    robot.poll(0.0)  # the fragments go out and free their room
    robot.send(b"d" * 600, 0.0, reliable=False)


def test_two_links_over_a_real_pty_pair():
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    robot, host = pair()
    a = LinkPump(robot, open_url(os.ttyname(slave), timeout=0.005))
    b = LinkPump(host, FdPort(master, timeout=0.005))
    msgs = [os.urandom(200 + i) for i in range(10)]
    for i, m in enumerate(msgs):
        robot.send(m, 0.0, msg_id=i + 1)
    got, acked = [], set()
    try:
        for _ in range(400):
            for e in b.step():
                if isinstance(e, Delivered):
                    got.append(e.payload)
            acked |= {e.msg_id for e in a.step() if isinstance(e, Acked)}
            if len(acked) == len(msgs):
                break
    finally:
        a.close()
        b.close()
    assert got == msgs and acked == set(range(1, 11))


def test_a_dead_link_is_retried_with_backoff_not_flooded():
    robot, host = pair()
    for i in range(1, 41):
        robot.send(os.urandom(150), 0.0, msg_id=i)
    _, eh, t = pump(robot, host, 0.0, 0.03)  # session open, part of the window in flight
    from radio.frame import Deframer
    frames, end = 0, t + 20.0
    while t < end:  # the host is gone: nothing comes back
        frames += len(Deframer(200).feed(robot.poll(t)))
        t += 0.01
    # Backoff to max_rto (1 s) after two grace timeouts: about one window (64) a second,
    # where a fixed RTO resends the window several times a second (over 4000 frames here).
    assert 64 < frames < 25 * 64
    got = delivered(eh)
    assert len(got) < 40
    _, eh, _ = pump(robot, host, t, 3.0)  # the host is back: everything arrives, once
    assert [m for m, _ in got + delivered(eh)] == list(range(1, 41))


def test_single_bit_errors_are_repaired_and_counted():
    robot, host = pair()
    robot.send(b"q" * 60, 0.0, msg_id=1)
    t, got, flipped = 0.0, [], False
    while not got and t < 1.0:
        w = robot.poll(t)
        if b"qqqq" in w and not flipped:  # one bit of the DATA frame's payload
            bad = bytearray(w)
            bad[w.index(b"qqqq") + 2] ^= 0x04
            w, flipped = bytes(bad), True
        got += delivered(fed(host, w, t))
        robot.receive(host.poll(t), t)
        t += 0.01
    assert flipped and got == [(1, b"q" * 60)]
    assert host.stats().repaired == 1 and robot.stats().retransmissions == 0


def test_small_messages_with_clock_sized_automatic_ids_share_frames_and_all_arrive():
    """Automatic ids follow the counters, which follow the wall clock: 7-byte varints. A
    segment marked MORE must leave room for the next one's head, or the frame is refused."""
    from collections import deque

    from radio.fragment import AUTO_BASE, StreamAssembler, StreamPacker

    queue = deque((AUTO_BASE + 37_992_960_000_000 + i, b"CAPTURE %d" % i) for i in range(20))
    packer, assembler, got = StreamPacker(), StreamAssembler(4096), []
    while (nxt := packer.next_payload(queue, 78)) is not None:
        got += [msg for _, msg in assembler.add(nxt[0])]
    assert got == [b"CAPTURE %d" % i for i in range(20)]
