"""Decoded sizes are bounded by what a real sensor can send, and checked before allocation."""
import json
import subprocess
import sys
import textwrap

import msgpack
import pytest

from radio import FrameError
from radio import packets as pk
from radio.packets.base import (
    MAX_BANDS,
    MAX_FRAME_PIXELS,
    MAX_FRAME_SIDE,
    MAX_MASK_SIDE,
    SCHEMA_VERSION,
    Kind,
)
from radio.packets.models import LabelModels, ModelsPacket

# A MASK body once accepted, a 1 x 1 label map of a 65535 x 65535 frame, was schema 2; the same
# 20 bytes at the current schema version are what an authentic robot could send now.
ISSUE_MASK = bytes.fromhex("9a02020107cdffffcdffff0101c40101c4020001")


def _mask_body(fh: int, fw: int, h: int = 1, w: int = 1) -> bytes:
    runs = (h * w).to_bytes(2, "big")
    return msgpack.packb([SCHEMA_VERSION, int(Kind.MASK), 1, 7, fh, fw, h, w, b"\x01", runs],
                         use_bin_type=True)


HUGE_MASK = _mask_body(65535, 65535)


def test_the_twenty_byte_mask_of_a_65535_square_frame_is_refused():
    assert len(HUGE_MASK) == 20 and HUGE_MASK[2:] == ISSUE_MASK[2:]
    with pytest.raises(FrameError, match="frame height = 65535 outside"):
        pk.decode(HUGE_MASK)
    with pytest.raises(FrameError):
        pk.decode(ISSUE_MASK)


@pytest.mark.parametrize("shape", [(MAX_FRAME_SIDE + 1, 480), (480, MAX_FRAME_SIDE + 1)])
def test_a_frame_side_past_the_sensor_bound_is_refused(shape):
    with pytest.raises(FrameError, match=f"outside \\[1, {MAX_FRAME_SIDE}\\]"):
        pk.decode(_mask_body(*shape))


def test_the_largest_frame_a_sensor_can_have_still_decodes():
    p = pk.decode(_mask_body(MAX_FRAME_SIDE, MAX_FRAME_SIDE, 2, 2))
    assert p.frame_shape == (MAX_FRAME_SIDE, MAX_FRAME_SIDE) and p.shape == (2, 2)


def test_the_label_map_is_bounded_by_the_mask_side():
    side = MAX_MASK_SIDE + 1
    body = msgpack.packb([SCHEMA_VERSION, int(Kind.MASK), 1, 7, 4000, 4000, side, 1, b"\x01",
                          side.to_bytes(2, "big")], use_bin_type=True)
    with pytest.raises(FrameError, match="mask height"):
        pk.decode(body)


def _models(count: int, n_bands: int = 1) -> ModelsPacket:
    rec = LabelModels(1, count, 0, ((100, 200, 300, 400),) * n_bands)
    return ModelsPacket(1, 1, 1.0, (0.0, 0.0), (0.0, 0.0), "gray", tuple(f"B{i}" for i in range(n_bands)),
                        256, (rec,))


def test_a_region_holds_at_most_a_frames_pixels():
    assert pk.decode(pk.encode(_models(MAX_FRAME_PIXELS))).labels[0].count == MAX_FRAME_PIXELS
    with pytest.raises(ValueError, match="out of range"):
        pk.encode(_models(MAX_FRAME_PIXELS + 1))
    # The same packet built by hand (the encoder refuses it) is refused by the decoder.
    good = pk.encode(_models(MAX_FRAME_PIXELS))
    items = msgpack.unpackb(good, raw=False)
    blob = bytearray(items[7])
    # The one label's varint: count * 16 + z index, 5 bytes for 2**28 * 16; add one pixel.
    at = 10 + 1 + 1
    value = (MAX_FRAME_PIXELS + 1) << 4
    varint = bytearray()
    while value >= 0x80:
        varint.append(value & 0x7F | 0x80)
        value >>= 7
    varint.append(value)
    blob[at:at + len(varint)] = varint
    items[7] = bytes(blob)
    with pytest.raises(FrameError, match="pixel count"):
        pk.decode(msgpack.packb(items, use_bin_type=True))


def test_band_counts_are_bounded():
    assert len(pk.decode(pk.encode(_models(10, MAX_BANDS))).bands) == MAX_BANDS
    with pytest.raises(ValueError, match=f"1..{MAX_BANDS}"):
        pk.encode(_models(10, MAX_BANDS + 1))


_SURVIVE = textwrap.dedent("""
    import json, resource, sys
    limit = 1 << 30  # 1 GiB of address space: the old decoder asked for 4 GiB here
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))
    import numpy as np
    from radio import packets as pk
    from tools.station.receiver import Receiver, mask_key
    from tools.store.database import Store
    with Store.open(sys.argv[1]) as store:
        rx = Receiver(store)
        bad = rx.handle(bytes.fromhex(sys.argv[2]))
        labels = np.zeros((480, 640), np.uint8)
        labels[240:] = 1
        good = rx.handle(pk.encode_mask(labels, robot_id=1, seq=8))
        stored = store.mask(mask_key(8), "1")
        print(json.dumps({"bad": [bad.kind.value, bad.text], "good": [good.kind.value, good.stored],
                          "shape": list(stored.shape), "counts": rx.counts}))
""")


def test_the_receiver_refuses_it_within_a_1_gib_address_space_and_goes_on(tmp_path):
    out = subprocess.run([sys.executable, "-c", _SURVIVE, str(tmp_path / "scene.db"), HUGE_MASK.hex()],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout)
    assert doc["bad"][0] == "bad" and "frame height = 65535" in doc["bad"][1]
    assert doc["good"] == ["mask", True] and doc["shape"] == [480, 640]
    assert doc["counts"]["bad"] == 1 and doc["counts"]["mask"] == 1
