"""On-board dependence measurement and its packet entry."""
from __future__ import annotations

import dataclasses

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from btf.codec import z_for_count
from btf.dependence import LAGS, Dependence
from btf.fit.dependence import measure
from btf.fit.fitter import FrameFitter
from btf.johnson import Johnson
from radio import FrameError
from radio import packets as pk
from radio.packets.dependence import decode_dependence, encode_dependence, record_size
from tests.support.robots import robot_toml

HEADER = dict(robot_id=1, seq=5, time=10.0, commanded=(60.0, 0.0), measured=(60.0, 0.0),
              feature_space="rgb")


def _fits(image: np.ndarray, labels: np.ndarray):
    f = FrameFitter(int(labels.max()) + 1, image.shape[2], bins=256)
    f.add(image, labels)
    return f.fit(min_count=64)


def _ar_image(h: int, w: int, phi: float, mix: float, seed: int) -> np.ndarray:
    """Three bands sharing an AR(1) field along rows (lag-k correlation phi**k), mixed across bands."""
    rng = np.random.default_rng(seed)
    e = rng.standard_normal((3, h, w))
    f = np.empty_like(e)
    f[:, :, 0] = e[:, :, 0]
    for c in range(1, w):
        f[:, :, c] = phi * f[:, :, c - 1] + np.sqrt(1 - phi**2) * e[:, :, c]
    z = np.stack([f[0], mix * f[0] + np.sqrt(1 - mix**2) * f[1], f[2]], axis=-1)
    return np.clip(np.rint(120 + 25 * z), 0, 255).astype(np.uint8)


def test_measures_row_autocorrelation_and_band_correlation_of_a_known_field():
    img = _ar_image(200, 240, phi=0.8, mix=0.7, seed=1)
    labels = np.zeros(img.shape[:2], dtype=np.int64)
    models = {k: r.model for k, r in _fits(img, labels).items()}
    dep = measure(img, labels, models)[0]
    assert dep.dx == pytest.approx([0.8**k for k in LAGS], abs=0.05)
    assert dep.dy == pytest.approx([0.0] * len(LAGS), abs=0.05)
    assert dep.corr == pytest.approx([0.7, 0.0, 0.0], abs=0.05)


def test_regions_are_measured_apart_and_pairs_never_cross_a_border():
    img = _ar_image(120, 160, phi=0.9, mix=0.0, seed=2)
    noise = np.random.default_rng(3).integers(90, 160, size=img.shape, dtype=np.uint8)
    labels = np.zeros(img.shape[:2], dtype=np.int64)
    labels[:, 80:] = 1
    img[:, 80:] = noise[:, 80:]
    models = {k: r.model for k, r in _fits(img, labels).items()}
    deps = measure(img, labels, models)
    assert deps[0].dx[0] > 0.8
    assert abs(deps[1].dx[0]) < 0.06  # white noise region: no grain borrowed from its neighbour


def test_constant_band_and_tiny_region_report_independence_not_nan():
    img = np.full((40, 40, 2), 7, dtype=np.uint8)
    img[..., 1] = np.random.default_rng(4).integers(0, 255, size=(40, 40))
    labels = np.zeros((40, 40), dtype=np.int64)
    models = {k: r.model for k, r in _fits(img, labels).items()}
    dep = measure(img, labels, models)[0]
    assert dep.corr == (0.0,)
    assert all(np.isfinite(dep.dx)) and all(np.isfinite(dep.dy))


def test_anchor_budget_bounds_the_work_but_keeps_the_estimate():
    img = _ar_image(200, 240, phi=0.8, mix=0.5, seed=5)
    labels = np.zeros(img.shape[:2], dtype=np.int64)
    models = {k: r.model for k, r in _fits(img, labels).items()}
    dep = measure(img, labels, models, max_anchors=4096, chunk=512)[0]
    assert dep.dx[0] == pytest.approx(0.8, abs=0.06)


def test_blob_round_trips_within_one_step_and_marks_absent_labels():
    deps = {2: Dependence((0.5, -0.25, 1.0), (0.9, 0.7, 0.3, 0.0), (0.8, -0.1, 0.0, 0.05))}
    blob = encode_dependence(deps, [2, 5], 3)
    back = decode_dependence(blob, [2, 5], 3)
    assert set(back) == {2}
    for a, b in zip((*deps[2].corr, *deps[2].dx, *deps[2].dy), (*back[2].corr, *back[2].dx, *back[2].dy)):
        assert abs(a - b) <= 0.5 / 127 + 1e-12


@pytest.mark.parametrize("blob, reason", [
    (b"\x00" * 10, "expected"),
    (b"\x80" + b"\x00" * 10, "-128"),
    ("text", "binary"),
])
def test_bad_blobs_are_refused_with_a_reason(blob, reason):
    with pytest.raises(FrameError, match=reason):
        decode_dependence(blob, [0], 3)


def _fit_stub(n_labels: int, plain: bool = False):
    """Fits of an AR texture; `plain`: each re-read at its label's z, unshifted, so the blob
    carries no records (the dependence section is then its end)."""
    img = _ar_image(64, 64, 0.5, 0.5, seed=6)
    labels = (np.arange(64)[None, :] * n_labels // 64).repeat(64, axis=0)
    fits = _fits(img, labels)
    if plain:
        fits = {k: dataclasses.replace(f, z=z_for_count(f.count), shift=0.0, exact_family=False)
                for k, f in fits.items()}
    return fits, labels, img


@pytest.mark.parametrize("n_labels", [1, 2, 4, 8, 16])
def test_packet_grows_at_most_16_bytes_per_rgb_region_even_for_one_region(n_labels):
    fits, labels, img = _fit_stub(n_labels)
    models = {k: r.model for k, r in fits.items()}
    deps = measure(img, labels, models)
    regions = sorted({lab for lab, _ in fits})
    assert len(regions) == n_labels and set(deps) == set(regions)
    plain = pk.encode_models(fits, bands=("R", "G", "B"), **HEADER)
    rich = pk.encode_models(fits, bands=("R", "G", "B"), dependence=deps, **HEADER)
    growth = len(rich) - len(plain)
    # 11 bytes a region inside the blob; one more only if the blob's msgpack header grows.
    assert record_size(3) == 11
    assert 11 * n_labels <= growth <= 11 * n_labels + 1
    assert growth <= 16 * n_labels
    packet = pk.decode(rich)
    assert set(packet.dependence) == set(deps)
    for lab, d in deps.items():
        got = packet.dependence[lab]
        for a, b in zip((*d.corr, *d.dx, *d.dy), (*got.corr, *got.dx, *got.dy)):
            assert abs(a - b) <= 0.5 / 127 + 1e-12
    assert packet.models == pk.decode(plain).models  # the models themselves are untouched


def test_a_packet_keeps_dependence_for_some_labels_only():
    fits, labels, img = _fit_stub(4)
    deps = measure(img, labels, {k: r.model for k, r in fits.items()})
    some = {lab: deps[lab] for lab in (0, 2)}
    packet = pk.models_packet(fits, bands=("R", "G", "B"), dependence=some, **HEADER)
    back = pk.decode(pk.encode(packet))
    assert set(back.dependence) == {0, 2}
    assert back == packet  # the packet holds its dependence already quantized as sent


def test_a_packet_without_dependence_has_none_and_no_section():
    fits, _, _ = _fit_stub(2)
    body = pk.encode_models(fits, bands=("R", "G", "B"), **HEADER)
    assert pk.decode(body).dependence == {}
    assert not msgpack.unpackb(body)[7][10] & 0x80


def test_dependence_for_a_label_the_packet_lacks_or_of_other_bands_is_refused():
    fits, _, _ = _fit_stub(1)
    with pytest.raises(ValueError, match="does not carry"):
        pk.models_packet(fits, bands=("R", "G", "B"), dependence={7: Dependence.independent(3)}, **HEADER)
    with pytest.raises(ValueError, match="bands"):
        pk.models_packet(fits, bands=("R", "G", "B"), dependence={0: Dependence.independent(2)}, **HEADER)


@settings(max_examples=200, deadline=None)
@given(st.binary(min_size=22, max_size=22))
def test_any_section_bytes_decode_to_steps_of_1_127_or_a_frame_error(section):
    fits, _, _ = _fit_stub(2, plain=True)
    plain = pk.encode_models(fits, bands=("R", "G", "B"), **HEADER)
    assert not any(t for lab in pk.decode(plain).labels for t in lab.tails)  # the blob ends with its codes
    items = msgpack.unpackb(plain)
    blob = bytearray(items[7])
    blob[10] |= 0x80
    items[7] = bytes(blob) + section
    codes = np.frombuffer(section, np.int8).reshape(2, 11)
    try:
        got = pk.decode(msgpack.packb(items, use_bin_type=True)).dependence
    except FrameError:
        assert (codes == -128).any(axis=1).any()
        return
    for row, lab in zip(codes, (0, 1)):
        if (row == -128).all():
            assert lab not in got
        else:
            d = got[lab]
            assert np.array_equal(np.rint(np.array((*d.corr, *d.dx, *d.dy)) * 127), row)


def test_dependence_is_not_carried_in_the_extras_map():
    fits, _, _ = _fit_stub(1)
    body = msgpack.unpackb(pk.encode_models(fits, bands=("R", "G", "B"), **HEADER))
    body.append({"d": b"\x00" * 600})
    with pytest.raises(FrameError, match="longer"):
        pk.decode(msgpack.packb(body, use_bin_type=True))


def _pipeline(tmp_path, on: bool):
    from onboard import config
    from onboard.capture.pipeline import Pipeline

    path = tmp_path / "robot.toml"
    path.write_text(robot_toml({"features": {"dependence": on}}))
    cfg = config.load(path)
    return lambda labels: Pipeline(cfg, None, lambda f, fr, m: (labels, False))


@pytest.mark.parametrize("on", [True, False])
def test_capture_sends_dependence_only_when_configured(tmp_path, on):
    from hal.interfaces import ViewAngles
    from onboard.link.bodies import models_body

    img = _ar_image(96, 128, phi=0.8, mix=0.6, seed=8)
    labels = np.zeros(img.shape[:2], dtype=np.uint8)
    labels[:, 64:] = 1
    cap = _pipeline(tmp_path, on)(labels).process(img, ViewAngles(90), ViewAngles(90))
    _, body = models_body(1, 1, 0.0, "rgb", cap)
    got = pk.decode(body).dependence
    if on:
        assert set(got) == {0, 1} and got[0].dx[0] == pytest.approx(0.8, abs=0.08)
    else:
        assert got == {}


def test_dependence_memory_does_not_grow_with_the_frame():
    import tracemalloc

    def peak(n):
        rng = np.random.default_rng(0)
        img = rng.integers(0, 256, (n, n, 3), dtype=np.uint8)
        labels = np.zeros((n, n), np.int64)
        models = {(0, b): Johnson.normal(128.0, 70.0) for b in range(3)}
        measure(img[:16, :16], labels[:16, :16], models)
        tracemalloc.start()
        measure(img, labels, models)
        _, top = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        return top

    assert peak(1500) <= 1.2 * peak(400) + 200_000
