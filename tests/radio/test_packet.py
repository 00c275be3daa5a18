"""Packet bodies: exact model round trip, sizes, every kind, and strict rejection of bad fields."""
from __future__ import annotations

import math
import struct

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from btf.codec import Z_LADDER, PercentileCodec
from btf.dependence import Dependence
from btf.fit.fitter import FrameFitter, fit_histogram
from radio import FrameError
from radio.packets import (
    MAX_BODY,
    SCHEMA_VERSION,
    AckPacket,
    CommandName,
    CommandPacket,
    Kind,
    LabelModels,
    LogLevel,
    LogPacket,
    MaskPacket,
    ModelsPacket,
    NackPacket,
    Reason,
    RobotState,
    StatusPacket,
    UnchangedPacket,
    decode,
    downsample_labels,
    encode,
    encode_mask,
    encode_models,
    models_packet,
)
from radio.packets.base import MAX_FRAME_PIXELS
from radio.packets.dependence import decode_dependence, record_size
from radio.varint import get_varint

HEADER = dict(robot_id=3, seq=41, time=1_700_000_000.25, commanded=(45.0, 30.0),
              measured=(44.93, 29.87), feature_space="rgb")


def _fits(n_labels: int, n_bands: int, seed: int = 0, levels: int = 256) -> dict:
    """Fitter results over varied shapes: skewed, heavy-tailed, clipped, bounded, constant."""
    rng = np.random.default_rng(seed)
    fits = {}
    for lab in range(n_labels):
        n = int(rng.integers(300, 20000))
        for band in range(n_bands):
            shape = (lab + band) % 5
            if shape == 0:
                v = rng.normal(rng.uniform(30, 220), rng.uniform(2, 30), n)
            elif shape == 1:
                v = rng.gamma(rng.uniform(1, 4), rng.uniform(5, 20), n)
            elif shape == 2:
                v = 128 + rng.standard_t(3, n) * 10
            elif shape == 3:
                v = 255 * rng.beta(2, 5, n)
            else:
                v = np.full(n, float(rng.integers(0, levels)))
            v = np.clip(np.round(v * (levels / 256)), 0, levels - 1).astype(np.int64)
            fits[(lab * 3 + 1, band)] = fit_histogram(np.bincount(v, minlength=levels))
    return fits


def _bands(n: int) -> tuple[str, ...]:
    return tuple("RGBHSVXYZABCDEFQ"[:n])


def test_host_recomputes_the_robots_models_bit_for_bit():
    for seed in range(5):
        fits = _fits(6, 3, seed)
        packet = decode(encode_models(fits, bands=_bands(3), **HEADER))
        assert set(packet.models) == set(fits)
        for key, fit in fits.items():
            assert packet.models[key] == fit.model  # exact float equality of every parameter


def test_deeper_sensors_use_32_bit_codes_and_stay_exact():
    fits = _fits(3, 2, seed=7, levels=4096)
    body = encode_models(fits, bands=_bands(2), levels=4096, **HEADER)
    packet = decode(body)
    assert all(packet.models[k] == f.model for k, f in fits.items())
    assert packet.levels == 4096
    body8 = encode_models(_fits(3, 2, seed=7), bands=_bands(2), **HEADER)
    deep, shallow = _sections(body), _sections(body8)
    # 2 extra bytes per code; the data differ, so do their few read and censored records
    assert deep["codes"] - shallow["codes"] == 3 * 2 * 4 * 2
    assert len(body) - len(body8) == 3 * 2 * 4 * 2 + deep["records"] - shallow["records"]


def test_decoded_fields_match_what_was_sent():
    fits = _fits(4, 3)
    packet = decode(encode_models(fits, bands=("R", "G", "B"), censored={4: (0.25, 0.5)},
                                  extras={"exposure_us": 1200, "gain": 1.5}, **HEADER))
    assert isinstance(packet, ModelsPacket)
    assert (packet.robot_id, packet.seq, packet.time) == (3, 41, 1_700_000_000.25)
    assert packet.commanded == (45.0, 30.0) and packet.measured == (44.93, 29.87)
    assert packet.feature_space == "rgb" and packet.bands == ("R", "G", "B") and packet.levels == 256
    assert [r.label for r in packet.labels] == [1, 4, 7, 10]
    codec = PercentileCodec.for_levels(256)
    for rec in packet.labels:
        fit = fits[(rec.label, 0)]
        assert rec.count == fit.count
        # the label's z is its commonest among the models read unshifted; the others carry theirs
        zs = [Z_LADDER[rec.z_index if rec.tail(b) is None else rec.tail(b).z_index] for b in range(3)]
        assert zs == [fits[(rec.label, b)].z for b in range(3)]
        assert rec.codes[1] == codec.encode(fits[(rec.label, 1)].percentiles)
    by_label = {r.label: r for r in packet.labels}
    assert abs(by_label[4].censored_low - 0.25) <= 0.5 / 65535
    assert abs(by_label[4].censored_high - 0.5) <= 0.5 / 65535
    assert by_label[1].censored_low == 0.0 and by_label[1].censored_high == 0.0
    assert packet.extras == {"exposure_us": 1200, "gain": 1.5}


MAX_HEADER = dict(HEADER, robot_id=65535, seq=2**32 - 1, commanded=(-89.99, 359.99),
                  measured=(89.99, 359.99))


def test_a_capture_of_8_labels_by_3_bands_fits_in_300_bytes_even_with_maximal_header():
    fits = _fits(8, 3)
    body = encode_models(fits, bands=("R", "G", "B"), **MAX_HEADER)
    assert len(body) <= 300, len(body)


def test_a_gamma_tailed_frame_of_8_labels_by_3_bands_fits_in_300_bytes():
    # The benchmark's clutter: a 1000x1000 RGB frame, 8 regions of 125,000 pixels each with
    # gamma tails; a few regions are read at another spread or centre, the brightest saturates.
    rng = np.random.default_rng(20240601)
    side = 1000
    labels = ((np.arange(side)[:, None] * 8 // side + np.arange(side)[None, :] * 2 // side) % 8).astype(np.uint8)
    base = np.array([40, 70, 100, 130, 160, 190, 210, 90])[labels][..., None]
    frame = np.clip(base + rng.gamma(2.0, 8.0, (side, side, 3)), 0, 255).astype(np.uint8)
    fitter = FrameFitter(8, 3)
    fitter.add(frame, labels)
    fits = fitter.fit()
    assert any(f.censored_high for f in fits.values())
    body = encode_models(fits, bands=("R", "G", "B"), **MAX_HEADER)
    assert len(body) <= 300, len(body)
    packet = decode(body)
    assert all(packet.models[k] == f.model for k, f in fits.items())


def test_each_model_costs_eight_bytes_of_codes():
    fits3, fits4 = _fits(4, 3), _fits(4, 4)
    small = encode_models(fits3, bands=("R", "G", "B"), **HEADER)
    large = encode_models(fits4, bands=("R", "G", "B", "H"), **HEADER)
    a, b = _sections(small), _sections(large)
    assert a["codes"] == 4 * 3 * 8 and b["codes"] == 4 * 4 * 8
    # one more band: 4 models of 8 bytes, plus the band's name "H" (2 bytes), plus the records
    # of the models read another way or censored (and the label counts differ a little: the
    # fixture draws more per label)
    assert len(large) - len(small) == 4 * 8 + 2 + (b["labels"] - a["labels"]) + (b["records"] - a["records"])


def _sections(body: bytes) -> dict[str, int]:
    """Byte counts of the MODELS blob's parts (radio.packets.models doc)."""
    items = msgpack.unpackb(body)
    blob, n_bands = items[7], len(items[6])
    nb = blob[10] & 0x3F
    ids = [8 * j + i for j in range(nb) for i in range(8) if blob[11 + j] >> i & 1]
    pos = 11 + nb
    for _ in ids:
        _, pos = get_varint(blob, pos, "count", 6)
    levels = struct.unpack_from(">H", blob, 8)[0] + 1
    width = 2 if levels <= 256 else 4
    codes = len(ids) * n_bands * 4 * width
    start = pos + codes
    dependence = decode_dependence(blob, ids, n_bands, levels, start)[1] - start if blob[10] & 0x80 else 0
    return {"labels": pos - 10, "codes": codes, "dependence": dependence,
            "records": len(blob) - pos - codes - dependence}


def test_dependence_sits_between_codes_and_records_and_both_round_trip():
    fits = _fits(3, 3, seed=2)
    deps = {1: Dependence.from_lags((0.3, -0.2, 0.9), (0.8, 0.6, 0.4, 0.1), (0.7, 0.5, 0.2, 0.0)),
            7: Dependence.independent(3, radius=8)}  # labels 1, 4, 7; label 4 unmeasured
    packet = models_packet(fits, bands=("R", "G", "B"), censored={4: (0.01, 0.2)}, dependence=deps, **HEADER)
    body = encode(packet)
    parts = _sections(body)
    # header 3, kinds 1 (three labels), two grain records of radius 8: 3 correlations, 144 lags
    assert parts["dependence"] == 3 + 1 + 2 * record_size(3, 8, grain=True, observed=False) == 298
    assert parts["records"] > 0
    back = decode(body)
    assert back.dependence == packet.dependence and set(back.dependence) == {1, 7}
    assert back.models == decode(encode_models(fits, bands=("R", "G", "B"), censored={4: (0.01, 0.2)},
                                               **HEADER)).models


def test_fixed_point_error_is_at_most_half_a_step_under_a_hundredth_of_a_gray_level():
    codec = PercentileCodec.for_levels(256)
    assert codec.step == 2.0**-8
    x = np.random.default_rng(1).uniform(-0.5, 255.5, 20000)
    err = max(abs(codec.decode(codec.encode([v] * 4))[0] - v) for v in x)
    assert err <= 2.0**-9 < 0.01


def test_encoding_refuses_incomplete_or_inconsistent_fits():
    fits = _fits(2, 3)
    del fits[(1, 2)]
    with pytest.raises(ValueError, match="lacks a model"):
        encode_models(fits, bands=("R", "G", "B"), **HEADER)
    with pytest.raises(ValueError, match="outside the band list"):
        encode_models(_fits(2, 3), bands=("R", "G"), **HEADER)
    with pytest.raises(ValueError, match="elevation"):
        encode_models(_fits(2, 3), bands=("R", "G", "B"), **dict(HEADER, measured=(95.0, 0.0)))
    with pytest.raises(ValueError, match="censored"):
        encode_models(_fits(1, 3), bands=("R", "G", "B"), censored={1: (1.5, 0.0)}, **HEADER)
    with pytest.raises(ValueError, match="labels without models"):
        encode_models(_fits(1, 3), bands=("R", "G", "B"), censored={9: (0.1, 0.0)}, **HEADER)


def test_censored_halves_that_round_up_still_travel():
    packet = decode(encode_models(_fits(1, 3), bands=("R", "G", "B"), censored={1: (0.5, 0.5)}, **HEADER))
    assert abs(packet.labels[0].censored_low - 0.5) <= 1 / 65535


def test_angles_travel_at_a_hundredth_of_a_degree_and_azimuth_wraps():
    packet = decode(encode(UnchangedPacket(1, 9, 5.0, (30.004, -10.0), (29.996, 370.0), 4)))
    assert packet.commanded == (30.0, 350.0) and packet.measured == (30.0, 10.0)


# -- the other kinds -----------------------------------------------------------------------


@pytest.mark.parametrize("packet", [
    UnchangedPacket(1, 9, 5.0, (30.0, 0.0), (29.5, 359.5), 4),
    StatusPacket(2, 10.5, RobotState.SWEEPING, (45.0, 90.0), 12, 4096, 17, "sweep 3/20"),
    StatusPacket(2, 0.0, RobotState.PAUSED, None, 0, 0, None, "outbox full", {"disk_free": 10}),
    CommandPacket(7, CommandName.PING),
    CommandPacket(8, CommandName.GOTO, {"elevation": 45.0, "azimuth": -30.0}),
    CommandPacket(9, CommandName.SWEEP, {"elevations": (30.0, 60.0), "azimuths": (0.0, 90.0, 180.0)}),
    CommandPacket(10, CommandName.SET, {"key": "skip.min_pixels", "value": 500}),
    CommandPacket(11, CommandName.REBOOT_SERVO, {"servo_id": 2}),
    CommandPacket(12, CommandName.SEND_MASK, {"seq": 41}),
    AckPacket(8, "at pose"),
    NackPacket(9, Reason.OUT_OF_LIMITS, "elevation 95 beyond the arm's reach"),
    LogPacket(2, 3.5, LogLevel.WARNING, "tracker calibration low"),
], ids=lambda p: type(p).__name__)
def test_every_kind_round_trips(packet):
    assert decode(encode(packet)) == packet


def test_mask_mode_pools_to_64_and_round_trips():
    labels = np.zeros((480, 640), np.uint8)
    labels[100:300, 200:500] = 3
    labels[350:, :] = 7
    packet = decode(encode_mask(labels, robot_id=1, seq=5))
    assert isinstance(packet, MaskPacket)
    assert packet.frame_shape == (480, 640) and packet.shape == (48, 64)
    assert (packet.full_size() == labels).mean() > 0.99
    assert sum(packet.runs) == 48 * 64


def test_mode_pooling_keeps_the_majority_and_breaks_ties_low():
    labels = np.array([[1, 1, 2, 2], [1, 5, 2, 3], [4, 4, 6, 6], [4, 9, 7, 8]], np.uint8)
    assert downsample_labels(labels, 2).tolist() == [[1, 2], [4, 6]]
    tie = np.array([[5, 2], [2, 5]], np.uint8)
    assert downsample_labels(tie, 1).tolist() == [[2]]


@settings(max_examples=80, deadline=None)
@given(arrays(np.int64, st.tuples(st.integers(1, 90), st.integers(1, 90)), elements=st.integers(0, 7)),
       st.integers(1, 64))
def test_mode_pooling_gives_each_cell_the_mode_of_its_pixels(labels, side):
    small = downsample_labels(labels, side)
    (H, W), (h, w) = labels.shape, small.shape
    if max(H, W) <= side:
        assert np.array_equal(small, labels)
        return
    assert max(h, w) == side
    rows = np.linspace(0, H, h + 1).round().astype(int)  # cells: an even split, rounded
    cols = np.linspace(0, W, w + 1).round().astype(int)
    for i in range(h):
        for j in range(w):
            cell = labels[rows[i]:rows[i + 1], cols[j]:cols[j + 1]]
            assert small[i, j] == np.bincount(cell.ravel()).argmax()  # argmax: the lowest of equals


def test_small_masks_travel_exactly():
    labels = np.random.default_rng(2).integers(0, 4, (20, 30)).astype(np.uint8)
    packet = decode(encode_mask(labels, robot_id=1, seq=5))
    assert np.array_equal(packet.label_map(), labels)
    assert np.array_equal(packet.full_size(), labels)


def test_mask_refuses_labels_beyond_a_byte():
    with pytest.raises(ValueError, match="0..255"):
        encode_mask(np.full((4, 4), 300), robot_id=1, seq=1)


def test_command_arguments_are_checked_when_encoding():
    with pytest.raises(ValueError, match="takes arguments"):
        encode(CommandPacket(1, CommandName.GOTO, {"elevation": 10.0}))
    with pytest.raises(ValueError, match="servo id"):
        encode(CommandPacket(1, CommandName.REBOOT_SERVO, {"servo_id": 300}))


# -- strict decoding of hand-made bodies ---------------------------------------------------


def _raw(*items) -> bytes:
    return msgpack.packb(list(items), use_bin_type=True)


def _models_fields(records: bytes = b"") -> list:
    """A plain MODELS body's fields: labels 1 and 4, 3 bands, counts 500 and 1000, so the
    blob is: angles and levels (10 bytes), bitmap length and bitmap (2), two 2-byte varints,
    48 bytes of codes from offset 16; `records` appended."""
    recs = tuple(LabelModels(lab, count, 0, ((100, 200, 300, 400),) * 3) for lab, count in ((1, 500), (4, 1000)))
    items = msgpack.unpackb(encode(ModelsPacket(3, 41, 1.0, (45.0, 30.0), (44.9, 30.1), "rgb", ("R", "G", "B"),
                                                256, recs)))
    items[7] += records
    return items


def _with(index: int, value) -> bytes:
    items = _models_fields()
    items[index] = value
    return _raw(*items)


def _blob(edit, records: bytes = b"") -> bytes:
    items = _models_fields(records)
    blob = bytearray(items[7])
    edit(blob)
    items[7] = bytes(blob)
    return _raw(*items)


BAD = {
    "must be an array": msgpack.packb({"v": 1}),
    "schema version": _raw(99, 1),
    "kind": _raw(SCHEMA_VERSION, 42),
    "fields": _raw(SCHEMA_VERSION, int(Kind.ACK)),
    "integer": _raw(SCHEMA_VERSION, int(Kind.ACK), True, ""),  # a bool is not an id
    "finite": _with(4, float("nan")),
    "elevation": _blob(lambda b: b.__setitem__(slice(0, 2), struct.pack(">h", 9001))),
    "azimuth": _blob(lambda b: b.__setitem__(slice(6, 8), struct.pack(">H", 36000))),
    "band names repeat": _with(6, ["R", "R", "B"]),
    "levels": _blob(lambda b: b.__setitem__(slice(8, 10), b"\x00\x00")),
    "header": _with(7, b"\x00" * 10),
    "bitmap": _blob(lambda b: b.__setitem__(10, 33)),
    "not canonical": _blob(lambda b: b.__setitem__(slice(10, 12), b"\x01\x00")),
    "inside a varint": _blob(lambda b: b.__delitem__(slice(13, None))),
    "codes blob": _blob(lambda b: b.__delitem__(slice(20, None))),
    "decrease": _blob(lambda b: b.__setitem__(slice(16, 18), b"\xff\xff")),
    "z ladder": _blob(lambda b: b.__setitem__(12, b[12] | 0x0F)),
    "bad flags": _blob(lambda b: None, b"\x03\x00\x00"),
    "inside their bitmap": _blob(lambda b: None, b"\x01"),
    "end inside a record": _blob(lambda b: None, b"\x01\x00"),
    "record: z ladder": _blob(lambda b: None, b"\x03\x00\x10\x40"),  # flag Z, then z index 64
    "is not a read": _blob(lambda b: None, b"\x01\x00\x30"),  # shift slot 3
    "which no record uses": _blob(lambda b: None, b"\x02\x00\x00"),
    "after its records": _blob(lambda b: None, b"\x01\x00\x07\x07"),
    "extras": _raw(*_models_fields(), [1, 2]),
    "camera section ends inside its flags": _blob(lambda b: b.__setitem__(10, b[10] | 0x40)),
    "dependence section has 0 bytes": _blob(lambda b: b.__setitem__(10, b[10] | 0x80)),
    "no label has a measurement": _blob(lambda b: b.__setitem__(10, b[10] | 0x80), b"\x80" * 22),
    "dependence code -128": _blob(lambda b: b.__setitem__(10, b[10] | 0x80), b"\x00\x80" + b"\x00" * 20),
    "dependence section version 3": _blob(lambda b: b.__setitem__(10, b[10] | 0x80), b"\x80\x03\x06\x00"),
    "no label has a record": _blob(lambda b: b.__setitem__(10, b[10] | 0x80), b"\x80\x01\x06\x00"),
    "radius outside 1..8": _blob(lambda b: b.__setitem__(10, b[10] | 0x80), b"\x80\x01\x09\x01"),
    "observed levels": _blob(lambda b: b.__setitem__(10, b[10] | 0x80), b"\x80\x01\x06\x01" + bytes([9, 9, 9, 1, 1, 1])),
    "unknown command": _raw(SCHEMA_VERSION, int(Kind.COMMAND), 1, 99, {}),
    "takes arguments": _raw(SCHEMA_VERSION, int(Kind.COMMAND), 1, int(CommandName.PING), {"x": 1}),
    "empty run": _raw(SCHEMA_VERSION, int(Kind.MASK), 1, 1, 8, 8, 2, 2, b"\x01\x02", b"\x00\x04\x00\x00"),
    "cover": _raw(SCHEMA_VERSION, int(Kind.MASK), 1, 1, 8, 8, 2, 2, b"\x01\x02", b"\x00\x01\x00\x01"),
    "same label": _raw(SCHEMA_VERSION, int(Kind.MASK), 1, 1, 8, 8, 2, 2, b"\x01\x01", b"\x00\x02\x00\x02"),
    "mask height": _raw(SCHEMA_VERSION, int(Kind.MASK), 1, 1, 800, 800, 65, 1, b"\x01", b"\x00\x41"),
    "not before": _raw(SCHEMA_VERSION, int(Kind.UNCHANGED), 1, 5, 1.0, 0, 0, 0, 0, 5),
    "unprintable": _raw(SCHEMA_VERSION, int(Kind.LOG), 1, 1.0, 20, "bell\x07"),
    "msgpack": _raw(SCHEMA_VERSION, int(Kind.ACK), 1, "x") + b"\x00",
    "exceeds": b"\x00" * (MAX_BODY + 1),
}


@pytest.mark.parametrize("reason", sorted(BAD))
def test_malformed_bodies_raise_frame_error_naming_the_problem(reason):
    with pytest.raises(FrameError, match=reason):
        decode(BAD[reason])


def test_decoded_models_are_never_non_finite():
    # Extreme but legal codes: all at the bottom, all at the top, one giant gap.
    codec = PercentileCodec.for_levels(256)
    top = (1 << codec.bits) - 1
    for codes in [(0, 0, 0, 1), (0, 1, 1, top), (top - 1, top, top, top), (0, 0, top, top)]:
        rec = LabelModels(1, MAX_FRAME_PIXELS, len(Z_LADDER) - 1, (codes,))
        packet = decode(encode(ModelsPacket(1, 1, 1.0, (0.0, 0.0), (0.0, 0.0), "gray", ("Y",), 256, (rec,))))
        m = packet.models[(1, 0)]
        assert all(math.isfinite(v) for v in (m.gamma, m.delta, m.xi, m.lam))
