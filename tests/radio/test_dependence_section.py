"""The MODELS blob's dependence section: observed levels, grain and band correlation in int8,
versioned, and the older layout still read."""
from __future__ import annotations

import dataclasses
from functools import lru_cache

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from btf.codec import z_for_count
from btf.dependence import MAX_RADIUS, Dependence, window_size
from btf.fit.dependence import measure, observed
from btf.fit.fitter import FrameFitter
from radio import FrameError
from radio import packets as pk
from radio.packets.dependence import decode_dependence, encode_dependence, encode_lags, record_size

HEADER = dict(robot_id=1, seq=5, time=10.0, commanded=(60.0, 0.0), measured=(60.0, 0.0), feature_space="rgb")
RGB = ("R", "G", "B")


def _grain(seed: int, lo=(3, 4, 5), hi=(200, 210, 220), rows: int = 1) -> Dependence:
    rng = np.random.default_rng(seed)
    return Dependence(tuple(rng.uniform(-1, 1, 3)), tuple(tuple(rng.uniform(-1, 1, 84)) for _ in range(rows)),
                      6, lo, hi)


def _close(a: Dependence, b: Dependence) -> bool:
    values = lambda d: np.array([*d.corr, *(v for row in d.acf for v in row)])  # noqa: E731
    return (a.lo, a.hi, a.radius) == (b.lo, b.hi, b.radius) and np.abs(values(a) - values(b)).max() <= 0.5 / 127 + 1e-12


def test_records_round_trip_within_half_a_step_with_levels_and_absent_labels():
    deps = {2: _grain(1), 5: Dependence.observed((1, 2, 3), (9, 9, 9)), 7: _grain(2, lo=(), hi=())}
    blob = encode_dependence(deps, [2, 3, 5, 7], 3)
    back, end = decode_dependence(blob, [2, 3, 5, 7], 3)
    assert end == len(blob) and set(back) == {2, 5, 7}
    assert _close(back[2], deps[2]) and _close(back[7], deps[7]) and back[5] == deps[5]


def test_an_rgb_region_costs_93_bytes_and_a_16_bit_gray_one_88():
    assert record_size(3, 6) == 6 + 3 + 84 == 93
    assert record_size(1, 6) == 2 + 84 and record_size(1, 6, 65536) == 4 + 84 == 88
    assert record_size(3, 6, grain=False) == 6  # the levels alone
    blob = encode_dependence({0: _grain(3)}, [0], 3)
    assert len(blob) == 3 + 1 + 93


def test_per_band_rows_and_deep_levels_travel():
    dep = _grain(4, lo=(300, 40000, 7), hi=(65535, 65000, 70), rows=3)
    back, _ = decode_dependence(encode_dependence({1: dep}, [1], 3, 65536), [1], 3, 65536)
    assert _close(back[1], dep) and len(back[1].acf) == 3


def test_the_older_layout_still_decodes_to_its_separable_window():
    blob = encode_lags({0: ((0.5, 0.2, 0.1), (0.9, 0.7, 0.5, 0.2), (0.8, 0.6, 0.4, 0.1))}, [0, 1], 3)
    assert len(blob) == 2 * record_size(3)  # 11 bytes a label
    back, end = decode_dependence(blob, [0, 1], 3)
    assert end == 22 and set(back) == {0}
    want = Dependence.from_lags((0.5, 0.2, 0.1), (0.9, 0.7, 0.5, 0.2), (0.8, 0.6, 0.4, 0.1))
    assert back[0].radius == MAX_RADIUS and np.allclose(back[0].acf, want.acf, atol=0.01)


@pytest.mark.parametrize("blob, reason", [
    (b"\x00" * 10, "expected"),
    (b"\x00\x80" + b"\x00" * 31, "-128"),
    (b"\x80" * 33, "no label has a measurement"),
    (b"\x80\x01\x06", "cut short"),
    (b"\x80\x01\x06\x02" + b"\x00" * 10, "needs 87 bytes"),
    (b"\x80\x01\x26\x02", "shape byte"),
    (b"\x80\x01\x06\x40", "labels the packet does not carry"),
    ("text", "binary"),
])
def test_bad_sections_are_refused_with_a_reason(blob, reason):
    with pytest.raises(FrameError, match=reason):
        decode_dependence(blob, [0, 1, 2], 3)


@lru_cache(maxsize=8)
def _fits(n_labels: int, plain: bool = False):
    rng = np.random.default_rng(6)
    img = rng.integers(60, 200, (64, 64, 3), dtype=np.uint8)
    labels = (np.arange(64)[None, :] * n_labels // 64).repeat(64, axis=0).astype(np.uint8)
    f = FrameFitter(n_labels, 3, bins=256)
    f.add(img, labels)
    fits = f.fit(min_count=64)
    if plain:  # each re-read at its label's z, unshifted: the blob then carries no records
        fits = {k: dataclasses.replace(r, z=z_for_count(r.count), shift=0.0, exact_family=False)
                for k, r in fits.items()}
    return fits, measure(img, labels, {k: r.model for k, r in fits.items()},
                         levels_seen=observed(f.counts, f.centre0, f.bin_width))


@pytest.mark.parametrize("n_labels", [1, 4, 16])
def test_a_packet_grows_by_the_section_and_keeps_its_models(n_labels):
    fits, deps = _fits(n_labels)
    plain = pk.encode_models(fits, bands=RGB, **HEADER)
    rich = pk.encode_models(fits, bands=RGB, dependence=deps, **HEADER)
    section = 3 + (n_labels + 3) // 4 + n_labels * record_size(3, 6)
    assert section <= len(rich) - len(plain) <= section + 2  # the blob's msgpack header may grow
    packet = pk.decode(rich)
    assert set(packet.dependence) == set(deps)
    assert all(_close(packet.dependence[k], d) for k, d in deps.items())
    assert packet.models == pk.decode(plain).models


def test_a_packet_keeps_records_for_some_labels_and_equals_its_decoded_self():
    fits, deps = _fits(4)
    some = {0: deps[0], 2: Dependence.observed(deps[2].lo, deps[2].hi)}
    packet = pk.models_packet(fits, bands=RGB, dependence=some, **HEADER)
    back = pk.decode(pk.encode(packet))
    assert set(back.dependence) == {0, 2} and not back.dependence[2].measured
    assert back == packet


def test_a_packet_without_records_has_no_section():
    fits, _ = _fits(2)
    body = pk.encode_models(fits, bands=RGB, **HEADER)
    assert pk.decode(body).dependence == {} and not msgpack.unpackb(body)[7][10] & 0x80


def test_records_for_labels_the_packet_lacks_or_of_other_bands_are_refused():
    fits, _ = _fits(1)
    with pytest.raises(ValueError, match="does not carry"):
        pk.models_packet(fits, bands=RGB, dependence={7: Dependence.independent(3)}, **HEADER)
    with pytest.raises(ValueError, match="bands"):
        pk.models_packet(fits, bands=RGB, dependence={0: Dependence.independent(2)}, **HEADER)


@settings(max_examples=300, deadline=None)
@given(st.sampled_from([1, 2]), st.binary(min_size=0, max_size=200))
def test_any_section_bytes_decode_to_valid_records_or_a_frame_error(version, section):
    fits, _ = _fits(2, plain=True)
    plain = pk.encode_models(fits, bands=RGB, **HEADER)
    items = msgpack.unpackb(plain)
    blob = bytearray(items[7])
    blob[10] |= 0x80
    items[7] = bytes(blob) + bytes([0x80, version]) + section
    try:
        got = pk.decode(msgpack.packb(items, use_bin_type=True)).dependence
    except FrameError:
        return
    assert got and set(got) <= {0, 1}
    for d in got.values():
        assert all(0 <= a <= b < 256 for a, b in zip(d.lo, d.hi))
        if d.measured:
            codes = np.rint(np.array([*d.corr, *(v for r in d.acf for v in r)]) * 127)
            assert np.all(np.abs(codes) <= 127) and len(d.acf[0]) == window_size(d.radius)
            assert version == 2 or not d.unmeasured
            assert all(d.acf[r][k] == 0.0 for r, gap in enumerate(d.unmeasured) for k in gap)


def _gaps(seed: int, gap: tuple[int, ...], rows: int = 1) -> Dependence:
    d = _grain(seed, rows=rows)
    acf = tuple(tuple(0.0 if k in gap else v for k, v in enumerate(row)) for row in d.acf)
    return Dependence(d.corr, acf, 6, d.lo, d.hi, (gap,) * rows)


def test_unmeasured_lags_travel_as_minus_128_in_version_2():
    deps = {0: _gaps(5, (0, 7, 83)), 1: _grain(6), 2: Dependence.observed((1, 1, 1), (5, 5, 5))}
    blob = encode_dependence(deps, [0, 1, 2], 3)
    assert blob[:2] == bytes([0x80, 2]) and len(blob) == 3 + 1 + 2 * 93 + 6  # no byte more than version 1
    codes = np.frombuffer(blob, np.int8, 3 + 84, 4 + 6)  # label 0's grain: its 3 correlations, then its lags
    assert set(np.flatnonzero(codes[3:] == -128)) == {0, 7, 83}
    back, _ = decode_dependence(blob, [0, 1, 2], 3)
    assert back[0].unmeasured == ((0, 7, 83),) and back[1].unmeasured == () and _close(back[0], deps[0])
    assert back[2] == deps[2]
    per_band = _gaps(7, (1, 2), rows=3)
    got = decode_dependence(encode_dependence({4: per_band}, [4], 3), [4], 3)[0][4]
    assert got.unmeasured == ((1, 2),) * 3 and _close(got, per_band)


def test_a_record_with_every_lag_measured_keeps_version_1_byte_for_byte():
    codes = np.array([100, -5, 0, *((np.arange(84) * 3) % 255 - 127)], dtype=np.int8)
    assert not (codes == -128).any()
    old = bytes([0x80, 1, 6, 0b10]) + codes.tobytes()  # one label, grain only: what robots have sent
    dep = decode_dependence(old, [3], 3)[0][3]
    assert dep == Dependence(tuple(codes[:3] / 127), (tuple(codes[3:] / 127),), 6)
    assert dep.unmeasured == () and encode_dependence({3: dep}, [3], 3) == old


@pytest.mark.parametrize("version, at, reason", [(1, 10, "-128"), (2, 0, "-128"), (3, 10, "version 3")])
def test_minus_128_is_refused_in_version_1_and_in_band_correlations(version, at, reason):
    codes = np.zeros(3 + 84, np.int8)
    codes[at] = -128
    with pytest.raises(FrameError, match=reason):
        decode_dependence(bytes([0x80, version, 6, 0b10]) + codes.tobytes(), [3], 3)
