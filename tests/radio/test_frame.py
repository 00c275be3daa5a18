"""Frames, counters, replay window and key files."""
import os
import random

import pytest
from cobs import cobs

from radio import FrameError
from radio.auth import CounterFileLost, FileCounterStore, ReplayWindow, clock_counter
from radio.frame import (
    OVERHEAD,
    Deframer,
    Frame,
    FrameKind,
    Reason,
    decode,
    decode_repaired,
    encode,
    max_payload,
    reason_of,
)
from radio.keys import KeyFileError, load_key, write_key

KEY = bytes(range(32))


def frame(payload=b"hello\x00world", counter=77):
    return Frame(FrameKind.DATA, 3, 9, 200, counter, payload)


def test_frame_round_trips_and_overhead_is_at_most_20_bytes():
    f = frame()
    wire = encode(f, KEY)
    assert wire[0] == 0 and wire[-1] == 0 and b"\x00" not in wire[1:-1]
    assert decode(wire[1:-1], KEY) == f
    assert OVERHEAD <= 20


@pytest.mark.parametrize("mtu", [40, 100, 255, 600])
def test_max_payload_fills_but_never_exceeds_the_mtu(mtu):
    n = max_payload(mtu)
    assert len(encode(frame(b"\x01" * n), KEY)) <= mtu
    assert len(encode(frame(b"\x01" * (n + 1 + mtu // 254)), KEY)) > mtu


def test_every_single_bit_flip_is_corrected_back_to_the_original_frame():
    f = frame()
    body = encode(f, KEY)[1:-1]
    raw = cobs.decode(body)
    for bit in range(8 * len(raw)):
        bad = bytearray(raw)
        bad[bit // 8] ^= 1 << (bit % 8)
        assert decode_repaired(cobs.encode(bytes(bad)), KEY) == (f, 1)
    assert decode_repaired(body, KEY) == (f, 0)


def test_multi_bit_errors_are_never_accepted():
    raw = cobs.decode(encode(frame(), KEY)[1:-1])
    rng = random.Random(5)
    reasons = set()
    for _ in range(20000):
        bad = bytearray(raw)
        for bit in rng.sample(range(8 * len(raw)), rng.randint(2, 5)):
            bad[bit // 8] ^= 1 << (bit % 8)
        with pytest.raises(FrameError) as e:
            decode(cobs.encode(bytes(bad)), KEY)
        reasons.add(reason_of(e.value))
    # Some patterns look like one flipped bit; the tag (or a header check) still refuses them.
    assert Reason.CRC in reasons and Reason.TAG in reasons


def test_wrong_key_is_a_tag_rejection():
    with pytest.raises(FrameError) as e:
        decode(encode(frame(), KEY)[1:-1], bytes(32))
    assert reason_of(e.value) is Reason.TAG


def test_deframer_resyncs_after_garbage_and_bounds_memory():
    a, b = encode(frame(b"a"), KEY), encode(frame(b"b", 78), KEY)
    d = Deframer(max_body=100)
    bodies = d.feed(b"\x13\x37garbage" + a + b"\xff" * 500 + b + a[:5])
    good = []
    for x in bodies:
        try:
            good.append(decode(x, KEY).payload)
        except FrameError:
            pass
    assert good == [b"a", b"b"]
    assert d.oversize == 1
    assert d.buffered <= 100


def test_counters_survive_restarts_without_reuse(tmp_path):
    path = tmp_path / "counters.json"
    seen = set()
    for _ in range(5):  # each store is a process killed after a few frames
        store = FileCounterStore(path, block=8)
        for _ in range(11):
            c = store.next_tx(1, 2)
            assert c not in seen and c > max(seen, default=0)
            seen.add(c)
    store.set_rx_floor(3, 2, 12345)
    assert FileCounterStore(path).rx_floor(3, 2) == 12345


def test_unreadable_counter_file_is_refused_without_a_clock_and_restarted_from_one(tmp_path):
    (tmp_path / "c.json").write_text("{not json")
    with pytest.raises(CounterFileLost, match="unreadable.*rotate the key.*--new-key"):
        FileCounterStore(tmp_path / "c.json", clock=False)
    store = FileCounterStore(tmp_path / "c.json", wall=lambda: 1.8e9)
    assert "unreadable" in store.note and store.next_tx(1, 2) >= clock_counter(1.8e9)


def test_replay_window_accepts_reordered_once_and_rejects_replays_and_stale():
    w = ReplayWindow(size=8, floor=100)
    assert w.check(100) is Reason.STALE and w.check(50) is Reason.STALE
    for c in (105, 103, 104, 101):
        assert w.check(c) is None
        w.accept(c)
    assert w.check(103) is Reason.REPLAY and w.check(102) is None
    # Counters from a clock lie far apart: a frame overtaken by others is still taken, once.
    for c in (100_000, 200_000, 300_000):
        w.accept(c)
    assert w.check(150_000) is None and w.check(200_000) is Reason.REPLAY
    for c in range(400_000, 400_008):  # 8 newer frames: the counters they pushed out are stale
        w.accept(c)
    assert w.check(300_000) is Reason.STALE and w.check(150_000) is Reason.STALE


def test_key_file_round_trip_and_clear_errors(tmp_path):
    p = tmp_path / "link.key"
    with pytest.raises(KeyFileError, match="no key, no link"):
        load_key(p)
    write_key(p)
    assert os.stat(p).st_mode & 0o777 == 0o600
    assert len(load_key(p)) == 32
    with pytest.raises(FileExistsError):
        write_key(p)
    os.chmod(p, 0o644)
    with pytest.raises(KeyFileError, match="chmod 600"):
        load_key(p)
    os.chmod(p, 0o600)
    p.write_text("abcd\n")  # a damaged copy: the fix is the other end's key, or a new one for both
    with pytest.raises(KeyFileError, match=r"holds 2 bytes, expected 32; copy the key from the other end"):
        load_key(p)
    p.write_text("zz" * 32)
    with pytest.raises(KeyFileError, match=r"hex digits; .*'btf-host keygen --out .* --force'"):
        load_key(p)
