"""The percentile fitter: closed forms, recovery, degenerate regions, the codec contract."""
import math

import numpy as np
import pytest

from btf.codec import COUNT_LADDER, Z_LADDER, PercentileCodec, z_for_count
from btf.fit.fitter import FrameFitter, fit_histogram, fit_values
from btf.fit.reads import GRID
from btf.johnson import Family, Johnson
from btf.percentile import model_from_percentiles
from btf.record import FittedModel, rebuild

HUGE = 2**53


def exact_percentiles(model, z):
    return tuple(model.x_of_z(np.array([-3 * z, -z, z, 3 * z])))


def sl_intercept(m):
    # gamma + delta f((x - xi)/lam), f = sign(lam) ln: only this intercept is identifiable.
    return m.gamma - math.copysign(1.0, m.lam) * m.delta * math.log(abs(m.lam))


ROUND_TRIP = [
    Johnson(Family.SU, 0.7, 1.3, 10.0, 4.0),
    Johnson(Family.SU, -1.2, 2.5, -3.0, 0.5),
    Johnson(Family.SU, 0.0, 0.8, 100.0, 20.0),
    Johnson(Family.SB, 0.5, 0.8, 2.0, 100.0),
    Johnson(Family.SB, -1.5, 1.7, 2.0, 100.0),
    Johnson(Family.SB, 0.0, 0.6, 0.0, 1.0),
    Johnson(Family.SL, 0.3, 1.1, 5.0, 1.0),
    Johnson(Family.SL, -0.8, 2.0, 5.0, -2.0),
    Johnson.normal(128.0, 3.0),
]


@pytest.mark.parametrize("truth", ROUND_TRIP, ids=lambda m: f"{m.family}{m.gamma:+}")
@pytest.mark.parametrize("z", [Z_LADDER[0], 0.3])
def test_closed_forms_recover_parameters_from_exact_quantiles(truth, z):
    got = model_from_percentiles(exact_percentiles(truth, z), z, HUGE)
    assert got.family is truth.family
    if truth.family is Family.SL:
        assert math.copysign(1, got.lam) == math.copysign(1, truth.lam)
        pairs = [(sl_intercept(got), sl_intercept(truth)), (got.delta, truth.delta), (got.xi, truth.xi)]
    else:
        pairs = [(got.gamma, truth.gamma), (got.delta, truth.delta), (got.xi, truth.xi), (got.lam, truth.lam)]
    for a, b in pairs:
        assert a == pytest.approx(b, rel=1e-9, abs=1e-9)


def test_near_the_lognormal_boundary_the_band_catches_it_and_nothing_blows_up():
    ln = Johnson(Family.SL, 0.3, 1.1, 5.0, 1.0)
    base = exact_percentiles(ln, 0.524)
    for eps in (0.0, 1e-15, 1e-12, 1e-9, 1e-7, -1e-7, -1e-12):
        pct = (base[0], base[1], base[2], base[3] * (1 + eps))
        for count in (50, 10_000, HUGE):
            m = model_from_percentiles(pct, 0.524, count)
            assert all(math.isfinite(v) for v in (m.gamma, m.delta, m.xi, m.lam))
            np.testing.assert_allclose(m.x_of_z([-1.572, -0.524, 0.524, 1.572]), pct, atol=1e-5 * abs(pct[3]))


def test_near_normal_percentiles_give_sn():
    pct = exact_percentiles(Johnson.normal(128.0, 3.0), 0.524)
    wobble = (pct[0] - 1e-4, pct[1], pct[2] + 1e-4, pct[3])
    assert model_from_percentiles(wobble, 0.524, 100_000).family is Family.SN


def test_decreasing_or_non_finite_percentiles_are_rejected():
    with pytest.raises(ValueError, match="non-decreasing"):
        model_from_percentiles((1.0, 3.0, 2.0, 4.0), 0.524, 100)
    with pytest.raises(ValueError, match="finite"):
        model_from_percentiles((1.0, 2.0, 3.0, float("inf")), 0.524, 100)


def test_z_ladder_steps_down_for_small_regions():
    assert Z_LADDER[0] == 0.524
    assert z_for_count(10**6) == 0.524
    assert z_for_count(10) < z_for_count(100) <= z_for_count(1000) == 0.524
    assert all(a > b for a, b in zip(COUNT_LADDER, COUNT_LADDER[1:])) and COUNT_LADDER == Z_LADDER[:10]
    # every read the fitter tries is on the ladder, whose index travels in 4 bits
    assert len(Z_LADDER) <= 16 and {z for z, _ in GRID} <= set(Z_LADDER)


def test_codec_round_trip_reproduces_the_model_bit_for_bit():
    rng = np.random.default_rng(0)
    codec = PercentileCodec.for_levels(256)
    assert codec.step == 2.0**-8
    for loc, scale in [(128, 3), (240, 30), (20, 50), (128, 60)]:
        x = np.clip(np.rint(rng.normal(loc, scale, 5000)), 0, 255).astype(np.uint8)
        r = fit_values(x)
        assert rebuild(r, codec.decode(codec.encode(r.percentiles))) == r.model


def test_codec_for_deep_sensors_uses_32_bits():
    codec = PercentileCodec.for_levels(65536)
    assert codec.bits == 32 and codec.step == 2.0**-16
    with pytest.raises(ValueError, match="code"):
        codec.decode((0, 1, 2, 2**32))


def test_rounded_narrow_normal_is_not_mistaken_for_bounded():
    x = np.clip(np.rint(np.random.default_rng(1).normal(128, 3, 100_000)), 0, 255).astype(np.uint8)
    r = fit_values(x)
    assert r.model.family is not Family.SB
    u = np.linspace(0.01, 0.99, 99)
    truth = 128 + 3 * np.asarray(Johnson.normal(0, 1).ppf(u))
    assert np.max(np.abs(r.model.ppf(u) - truth)) < 0.3


def recovery_grid():
    cells = []
    for gamma in (-1.0, -0.5, 0.0, 0.5, 1.0):
        for delta in (0.8, 1.2, 2.0, 4.0):
            cells.append((Family.SU, gamma, delta))
    for gamma in (-1.0, 0.0, 1.0):
        for delta in (0.6, 1.0, 2.0):
            cells.append((Family.SB, gamma, delta))
    for gamma in (0.0,):
        for delta in (1.5, 3.0):
            cells.append((Family.SL, gamma, delta))
    return cells


def scaled(family, gamma, delta):
    """The shape placed so its 0.1%..99.9% range spans gray levels 78..178 (a normal of
    sd 16). Wider spreads extrapolate sampling noise at the 3z percentiles further into
    the 1% tails: at 195 levels about 80% of cells stay within one level."""
    unit = Johnson(family, gamma, delta, 0.0, 1.0)
    lo, hi = unit.ppf([0.001, 0.999])
    lam = 100.0 / (hi - lo)
    return Johnson(family, gamma, delta, 78.0 - lo * lam, lam)


def test_recovery_across_the_beta_plane():
    rng = np.random.default_rng(7)
    u = np.linspace(0.01, 0.99, 99)
    worst = []
    for cell in recovery_grid():
        truth = scaled(*cell)
        px = np.clip(np.rint(truth.sample(100_000, rng, dtype=np.float64)), 0, 255).astype(np.uint8)
        fitted = fit_values(px).model
        worst.append(np.max(np.abs(fitted.ppf(u) - truth.ppf(u))))
    worst = np.array(worst)
    assert np.mean(worst <= 1.0) >= 0.95, worst
    assert np.all(worst <= 3.0), worst


@pytest.mark.parametrize("name,counts", [
    ("constant", {77: 1000}),
    ("two levels", {10: 500, 11: 300}),
    ("saturated high", {255: 4000, **{v: 60 for v in range(150, 255)}}),
    ("saturated low", {0: 4000, **{v: 60 for v in range(1, 100)}}),
    ("ten pixels", {3: 2, 9: 5, 200: 3}),
    ("one pixel", {5: 1}),
    ("near 2**32", {100: 2**32 - 1, 101: 2**32 - 1, 140: 2**31}),
    ("near 2**53", {0: 2**53, 255: 2**53, 128: 1}),
])
def test_degenerate_histograms_get_a_finite_model(name, counts):
    h = np.zeros(256, dtype=np.int64)
    for k, v in counts.items():
        h[k] = v
    r = fit_histogram(h)
    m = r.model
    assert all(math.isfinite(v) for v in (m.gamma, m.delta, m.xi, m.lam, r.beta1, r.beta2))
    assert r.count == int(h.sum())
    px = m.sample_pixels(10_000, np.random.default_rng(0))
    occupied = [k for k, v in counts.items() if v]
    assert px.min() >= 0 and px.max() <= 255
    # The synthesized pixels stay near the data they came from.
    assert min(occupied) - 20 <= np.median(px) <= max(occupied) + 20


def test_constant_region_is_const():
    h = np.zeros(256, dtype=np.int64)
    h[77] = 1000
    r = fit_histogram(h)
    assert r.model == Johnson.constant(77.0)
    assert r.percentiles == (77.0,) * 4


def test_percentiles_spread_ties_over_the_level():
    h = np.zeros(256, dtype=np.int64)
    h[10], h[11] = 500, 500
    r = fit_histogram(h, z=0.524)
    a, b, c, d = r.percentiles
    assert 9.5 < a < b < 10.5 < c < d < 11.5  # distinct even though only two levels exist


def test_bad_histograms_are_rejected():
    with pytest.raises(ValueError, match="empty"):
        fit_histogram(np.zeros(256))
    with pytest.raises(ValueError, match="non-negative"):
        fit_histogram(np.array([1, -1, 3]))
    with pytest.raises(ValueError, match="finite"):
        fit_histogram(np.array([1.0, np.nan]))


def test_fit_values_checks_its_input():
    with pytest.raises(ValueError, match="NaN"):
        fit_values(np.array([1.0, np.nan]))
    with pytest.raises(ValueError, match="outside"):
        fit_values(np.array([0.5, 2.0]), value_range=(0.0, 1.0))
    with pytest.raises(ValueError, match="numeric"):
        fit_values(np.array(["a", "b"]))


def two_region_frame(h=120, w=90, rng=None):
    rng = rng or np.random.default_rng(2)
    labels = np.zeros((h, w), dtype=np.int32)
    labels[:, w // 2:] = 2  # label 1 left empty on purpose
    frame = np.empty((h, w, 3), dtype=np.uint8)
    frame[labels == 0] = np.clip(rng.normal(80, 10, ((labels == 0).sum(), 3)), 0, 255).astype(np.uint8)
    frame[labels == 2] = np.clip(rng.gamma(2.0, 15.0, ((labels == 2).sum(), 3)) + 100, 0, 255).astype(np.uint8)
    return frame, labels


def test_frame_fitter_matches_fitting_each_region_directly():
    frame, labels = two_region_frame()
    f = FrameFitter(n_labels=3, n_bands=3, chunk_rows=7)
    f.add(frame, labels)
    results = f.fit()
    assert f.empty_labels == (1,)
    assert set(results) == {(0, b) for b in range(3)} | {(2, b) for b in range(3)}
    for (label, band), r in results.items():
        assert isinstance(r, FittedModel)
        assert r == fit_values(frame[..., band][labels == label])
        assert np.array_equal(f.counts[label, band], np.bincount(frame[..., band][labels == label], minlength=256))


@pytest.mark.parametrize("label_dtype", [np.uint8, np.int32, np.int64])
def test_eight_bit_counting_agrees_with_the_general_path(label_dtype):
    # uint8 frames take the per-band 16-bit path; the same values as uint16 the general one.
    rng = np.random.default_rng(3)
    frame = rng.integers(0, 256, (37, 53, 4), dtype=np.uint8)
    labels = rng.integers(0, 5, (37, 53)).astype(label_dtype)
    fast, general = FrameFitter(5, 4, chunk_rows=1), FrameFitter(5, 4, chunk_rows=1)
    fast.add(frame, labels)
    fast.add(frame[:, ::-1], labels[::-1])  # strided views too
    general.add(frame.astype(np.uint16), labels)
    general.add(frame[:, ::-1].astype(np.uint16), labels[::-1])
    assert np.array_equal(fast.counts, general.counts)
    for lab in range(5):
        for band in range(4):
            want = np.bincount(frame[..., band][labels == lab], minlength=256)
            want += np.bincount(frame[:, ::-1, band][labels[::-1] == lab], minlength=256)
            assert np.array_equal(fast.counts[lab, band], want)
    with pytest.raises(ValueError, match="label 5"):
        fast.add(frame, np.full((37, 53), 5, dtype=label_dtype))


def test_sixteen_bit_constant_and_sparse_regions_fit():
    # found by make stress: a frame of only constant regions leaves the percentile batch empty
    h = np.zeros(65536, np.int64)
    h[0] = 1
    assert fit_histogram(h).model.family is Family.CONST
    h[[17, 40000]] = 5
    r = fit_histogram(h)
    assert all(-0.5 <= p <= 65535.5 for p in r.percentiles) and r.model.family is not Family.CONST


def test_frame_fitter_accumulates_frames_and_resets():
    frame, labels = two_region_frame()
    f = FrameFitter(3, 3)
    f.add(frame, labels)
    f.add(frame, labels)
    assert f.counts.sum() == 2 * frame.size
    f.reset()
    assert f.counts.sum() == 0


def test_frame_fitter_subsample_and_min_count():
    frame, labels = two_region_frame()
    f = FrameFitter(3, 3, subsample=2)
    f.add(frame, labels)
    assert f.counts[:, 0].sum() == labels[::2, ::2].size
    f.fit(min_count=10**9)
    assert f.empty_labels == (0, 1, 2)


def test_frame_fitter_single_band_and_sixteen_bit_and_float():
    rng = np.random.default_rng(3)
    labels = np.zeros((40, 50), dtype=np.uint8)
    deep = rng.integers(1000, 60000, (40, 50)).astype(np.uint16)
    f16 = FrameFitter(1, 1, bins=65536)
    f16.add(deep, labels)
    r = f16.fit()[(0, 0)]
    assert f16.codec.bits == 32
    assert 1000 < r.model.ppf(0.5) < 60000
    flt = rng.uniform(0.2, 0.8, (40, 50, 2))
    ff = FrameFitter(1, 2, value_range=(0.0, 1.0))
    ff.add(flt, labels)
    med = ff.fit()[(0, 1)].model.ppf(0.5)
    assert med == pytest.approx(0.5, abs=0.05)


@pytest.mark.parametrize("frame,labels,match", [
    (np.zeros((4, 4, 3), np.uint8), np.zeros((4, 5), np.int32), "does not match"),
    (np.zeros((4, 4, 2), np.uint8), np.zeros((4, 4), np.int32), "HxWx3"),
    (np.zeros((4, 4, 3), np.uint8), np.full((4, 4), 3, np.int32), "label 3"),
    (np.zeros((4, 4, 3), np.uint8), np.full((4, 4), -1, np.int32), "label -1"),
    (np.zeros((4, 4, 3), np.uint8), np.zeros((4, 4), np.float32), "labels must be integers"),
    (np.zeros((4, 4, 3), np.complex64), np.zeros((4, 4), np.int32), "dtype"),
    (np.full((4, 4, 3), np.nan), np.zeros((4, 4), np.int32), "NaN"),
    (np.full((4, 4, 3), 300.0), np.zeros((4, 4), np.int32), "outside"),
    (np.full((4, 4, 3), 300, np.uint16), np.zeros((4, 4), np.int32), "outside"),
])
def test_frame_fitter_rejects_bad_input_with_a_reason(frame, labels, match):
    f = FrameFitter(3, 3)
    with pytest.raises(ValueError, match=match):
        f.add(frame, labels)
    assert f.counts.sum() == 0
