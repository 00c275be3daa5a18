"""One bound for a message: no packet body is longer than the link carries; a longer message is
refused by its sender, dropped by a receiver whose peer sent it anyway, and never holds up the
messages after it. Run through the sans-I/O link and the seeded channel simulator."""
import os

import pytest

from radio import packets as pk
from radio.auth import MemoryCounterStore
from radio.channel import Channel, ChannelConfig
from radio.fragment import MAX_MESSAGE
from radio.link import Acked, Delivered, Link, MessageTooLarge
from tests.support.worst_case import worst_models

KEY = bytes(range(32))
LOSSY = ChannelConfig(loss=0.1, latency=0.01)


def over_the_air(robot, host, seconds, config=LOSSY, dt=0.01):
    """Run both links over a lossy simulated radio; (messages the host delivered, ids the robot saw acked)."""
    there, back = Channel(config, seed=1), Channel(config, seed=2)
    got, acked, t = [], [], 0.0
    while t < seconds:
        there.transmit(robot.poll(t, there.room(t)), t)
        back.transmit(host.poll(t, back.room(t)), t)
        host.receive(there.deliver(t), t)
        robot.receive(back.deliver(t), t)
        got += [(e.msg_id, e.payload) for e in host.pop_events() if isinstance(e, Delivered)]
        acked += [e.msg_id for e in robot.pop_events() if isinstance(e, Acked)]
        t += dt
    return got, acked


def test_a_packet_body_and_a_link_message_share_one_bound():
    assert pk.MAX_BODY == MAX_MESSAGE == Link(1, 2, 1, KEY, MemoryCounterStore()).max_message


def test_the_sender_refuses_a_message_longer_than_the_link_carries_and_sends_the_next_ones():
    robot, host = Link(1, 2, 1, KEY, MemoryCounterStore()), Link(2, 1, 1, KEY, MemoryCounterStore())
    with pytest.raises(MessageTooLarge, match=f"{MAX_MESSAGE + 1} bytes exceeds the link's largest"):
        robot.send(b"x" * (MAX_MESSAGE + 1), 0.0, msg_id=1)
    assert robot.idle and robot.queued_bytes == 0  # nothing of it was queued
    small = {i: os.urandom(40 + 90 * i) for i in range(2, 12)}
    for i, m in small.items():
        robot.send(m, 0.0, msg_id=i)
    got, acked = over_the_air(robot, host, 30.0)
    assert got == list(small.items()) and sorted(acked) == list(small)


def test_a_receiver_drops_a_longer_message_a_peer_sent_anyway_and_delivers_the_ones_after_it():
    """A peer built with a larger bound sends 80 KiB, then small messages packed into the same frames
    as its tail: the receiver counts it refused (oversize) and delivers every one after it, in order."""
    robot = Link(1, 2, 1, KEY, MemoryCounterStore(), max_message=2 * MAX_MESSAGE)
    host = Link(2, 1, 1, KEY, MemoryCounterStore())
    robot.send(os.urandom(80 * 1024), 0.0, msg_id=1)
    small = {i: b"capture %d" % i for i in range(2, 30)}
    for i, m in small.items():
        robot.send(m, 0.0, msg_id=i)
    got, acked = over_the_air(robot, host, 60.0)
    assert got == list(small.items())
    assert host.stats().rejected == {"oversize": 1}
    assert robot.idle and set(acked) == {1, *small}  # the sender's queue drains: nothing stalls


def test_the_encoder_refuses_a_body_longer_than_a_link_message():
    with pytest.raises(pk.PacketTooLarge, match=r"MODELS body of \d+ bytes exceeds the link's largest message, 65536"):
        pk.encode(worst_models())
