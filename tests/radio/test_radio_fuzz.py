"""Fuzzing the decoder and the link: only FrameError escapes, nothing is accepted, memory bounded."""
import random

from hypothesis import given, settings
from hypothesis import strategies as st

from radio import FrameError
from radio.auth import MemoryCounterStore
from radio.frame import Frame, FrameKind, decode, encode
from radio.link import Delivered, Link

KEY = bytes(range(32))


def victim():
    return Link(0, 1, 5, KEY, MemoryCounterStore(), max_message=4096)


PAYLOADS = (bytes(range(256)) * 4, b"d" * 300)


def genuine_frames(n=40):
    robot = Link(1, 0, 5, KEY, MemoryCounterStore())
    robot.send(PAYLOADS[0], 0.0, msg_id=1)
    robot.send(PAYLOADS[1], 0.0, reliable=False)
    host = Link(0, 1, 5, KEY, MemoryCounterStore())
    wires = []
    for i in range(n):
        w = robot.poll(i * 0.01)
        wires.append(w)
        robot.receive(host.poll(i * 0.01), i * 0.01)
        host.receive(w, i * 0.01)
    return [w for w in wires if w]


GENUINE = genuine_frames()


@settings(max_examples=3000, deadline=None)
@given(st.binary(max_size=200))
def test_decoder_raises_only_frame_error(data):
    try:
        decode(data, KEY)
    except FrameError:
        pass


def delivered_payloads(wires):
    link = victim()
    link.receive(b"".join(wires), 0.0)
    events = link.pop_events()
    return [e.payload for e in events if isinstance(e, Delivered)]


def test_the_genuine_capture_delivers_both_messages():
    # The baseline for the mutation test below: the intact stream reaches delivery.
    assert sorted(delivered_payloads(GENUINE)) == sorted(PAYLOADS)


@settings(max_examples=1500, deadline=None)
@given(st.integers(0, len(GENUINE) - 1),
       st.lists(st.tuples(st.integers(0, 10**6), st.integers(0, 255)), min_size=1, max_size=6))
def test_mutated_genuine_traffic_is_never_accepted_as_anything_else(index, edits):
    wires = list(GENUINE)
    buf = bytearray(wires[index])
    for pos, val in edits:
        buf[pos % len(buf)] = val
    wires[index] = bytes(buf)
    got = delivered_payloads(wires)
    # A frame hit by one flipped bit is repaired from its CRC and is then genuine; nothing
    # else gets through, and nothing twice.
    assert all(p in PAYLOADS for p in got) and len(got) == len(set(got))


def test_seeded_flood_of_mutated_and_random_frames():
    rng = random.Random(1234)
    link = victim()
    for w in GENUINE:  # seen once, so any intact copy spliced in below is a replay
        link.receive(w, 0.0)
    link.pop_events()  # its deliveries are the baseline, not the flood's
    bodies = [encode(Frame(FrameKind(rng.randint(1, 7)), 1, 5, rng.randrange(256), rng.randrange(1, 1 << 48),
                           rng.randbytes(rng.randint(0, 77))), bytes(32)) for _ in range(200)]
    pieces = 0
    for i in range(100_000):
        choice = i % 4
        if choice == 0:
            data = rng.randbytes(rng.randint(1, 120))
        elif choice == 1:  # forged under another key, valid in every other respect
            data = rng.choice(bodies)
        else:  # genuine frames with bit flips, truncations or splices
            data = bytearray(rng.choice(GENUINE))
            for _ in range(rng.randint(1, 4)):
                data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
            if choice == 3:
                data = data[: rng.randrange(1, len(data) + 1)] + rng.choice(GENUINE)[rng.randrange(20):]
        link.receive(bytes(data), i * 1e-3)
        events = link.pop_events()
        assert not [e for e in events if isinstance(e, Delivered)]
        link.poll(i * 1e-3)
        assert link.buffered_bytes() <= 4 * 4096 + 64 * 100 + 100
        pieces += 1
    assert pieces == 100_000
    assert sum(link.stats().rejected.values()) > 90_000
