"""One histogram (fit_histogram, fit_values) is read by scalar steps, a frame's histograms in a
batch (FrameFitter.fit): both must give the same numbers, bit for bit."""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from benchmarks.model_histograms import histogram_l1
from btf.fit.censor import _censored_end, censored_end_one
from btf.fit.fitter import FrameFitter, fit_histogram, fit_values
from btf.fit.histogram_fit import _percentile_rows, _percentiles_one
from btf.johnson import Family, Johnson, normal_cdf


def _histograms(rng):
    su = Johnson(Family.SU, -0.6, 1.6, 110.0, 22.0)
    out = [np.bincount(su.sample_pixels(n, rng), minlength=256) for n in (10, 300, 100_000)]
    sat = np.clip(np.rint(su.sample(50_000, rng, np.float64) + 254.5 - float(su.ppf(0.6))), 0, 255)
    out.append(np.bincount(sat.astype(np.int64), minlength=256))  # 40% censored at 255
    pole = np.zeros(256, np.int64)
    pole[40:200] = np.bincount(rng.integers(0, 160, 5000), minlength=160)
    pole[40] += 3000  # a pile at an interior bound
    out.append(pole)
    both = rng.integers(0, 5, 256)
    both[0] += 40_000
    both[-1] += 45_000  # the fallback
    out += [both, np.eye(1, 256, 77, dtype=np.int64)[0], np.eye(1, 256, 3, dtype=np.int64)[0] * 2**60]
    two = np.zeros(256, np.int64)
    two[[100, 101]] = [5, 9]
    out.append(two)
    out.append(rng.integers(0, 2**52, 256) * (rng.random(256) < 0.2))
    return [np.asarray(h, np.int64) for h in out]


@pytest.mark.parametrize("censor", [True, False])
def test_fit_histogram_equals_the_frame_fitters_batch(censor):
    hists = _histograms(np.random.default_rng(5))
    f = FrameFitter(len(hists), 1)
    f.counts[:, 0, :] = np.stack(hists)
    batch = f.fit(censor=censor)
    kinds = set()
    for label, h in enumerate(hists):
        one = fit_histogram(h, censor=censor)
        assert one == batch[(label, 0)]
        kinds.add((one.model.family, one.shift != 0.0, one.fallback))
    if censor:  # the cases above reach the shifted read and the fallback
        assert any(shifted for _, shifted, _ in kinds) and any(fb for _, _, fb in kinds)


def test_fit_values_equals_the_frame_fitter_on_the_same_pixels():
    rng = np.random.default_rng(8)
    su = Johnson(Family.SU, -0.6, 1.6, 110.0, 22.0)
    frame = np.stack([su.sample_pixels(40_000, rng),
                      np.clip(su.sample_pixels(40_000, rng).astype(int) + 150, 0, 255)], axis=1)
    frame = frame.reshape(200, 200, 2).astype(np.uint8)
    labels = np.zeros((200, 200), np.uint8)
    f = FrameFitter(1, 2)
    f.add(frame, labels)
    fits = f.fit()
    for band in range(2):
        assert fit_values(frame[..., band]) == fits[(0, band)]
        assert fit_values(frame[..., band]) == fit_histogram(f.counts[0, band])


counts_rows = st.lists(st.one_of(st.integers(0, 20), st.integers(0, 2**53 + 7), st.just(0)),
                       min_size=4, max_size=40)


@settings(max_examples=150, deadline=None)
@given(counts_rows, st.lists(st.floats(0.0, 1.0), min_size=1, max_size=6),
       st.floats(-1e3, 1e3), st.floats(1e-3, 10.0))
def test_scalar_percentiles_equal_the_batch(row, probs, lo, width):
    c = np.array(row, dtype=np.int64)
    if not c.any():
        c[0] = 1
    cum = np.cumsum(c, dtype=np.float64)
    want = _percentile_rows(c[None], cum[None], np.array([probs]), lo, width)[0]
    got = _percentiles_one(c, cum, probs, lo, width)
    assert np.array_equal(np.array(got), want)


@settings(max_examples=300, deadline=None)
@given(st.integers(0, 2**62), st.integers(0, 2**62), st.integers(0, 2**62))
def test_scalar_censor_test_equals_the_array_one(end, n1, n2):
    want = _censored_end(np.array([end]), np.array([n1]), np.array([n2]))[0]
    assert censored_end_one(end, n1, n2) == want
    want_f = _censored_end(np.array([float(end)]), np.array([float(n1)]), np.array([float(n2)]))[0]
    assert censored_end_one(float(end), float(n1), float(n2)) == want_f


@pytest.mark.parametrize("model", [Johnson(Family.SU, -0.7, 1.5, 240.0, 20.0), Johnson.normal(10.0, 3.0),
                                   Johnson(Family.SB, -1.0, 0.4, 0.0, 255.0),
                                   Johnson(Family.SL, 0.5, 1.2, 240.0, -30.0)])
def test_interval_probabilities_are_phi_differences_from_the_nearer_tail(model):
    edges = np.linspace(-20.0, 280.0, 301)
    z = model.z_of_x(edges)
    t = np.concatenate(([-np.inf], z, [np.inf]))
    phi = np.array([0.5 * math.erfc(-v / math.sqrt(2.0)) for v in t])
    tail = np.array([0.5 * math.erfc(v / math.sqrt(2.0)) for v in t])
    want = np.where(t[:-1] >= 0.0, tail[:-1] - tail[1:], phi[1:] - phi[:-1])
    got = model.interval_probabilities(edges)
    assert np.array_equal(got, want)
    assert np.array_equal(normal_cdf(z), phi[1:-1])
    assert got.sum() == pytest.approx(1.0, abs=1e-12) and np.all(got >= 0.0)


def test_histogram_l1_equals_the_sum_over_every_level():
    rng = np.random.default_rng(4)
    model = Johnson(Family.SU, -0.6, 1.6, 110.0, 22.0)
    h = np.zeros(256, np.int64)
    h[[3, 90, 91, 92, 150, 255]] = rng.integers(1, 500, 6)
    every = float(np.abs(model.level_probabilities() - h / h.sum()).sum())
    assert histogram_l1(model, h) == pytest.approx(every, abs=1e-12)
