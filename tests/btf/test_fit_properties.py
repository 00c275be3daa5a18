"""Property-based checks: any histogram and any finite parameters give finite, in-range results."""
import math

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from btf.codec import PercentileCodec
from btf.fit.fitter import fit_histogram
from btf.johnson import Family, Johnson, normal_ppf
from btf.record import rebuild

SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@st.composite
def histograms(draw):
    kind = draw(st.sampled_from(["random", "sparse", "one", "two", "saturated", "huge32", "huge53"]))
    h = np.zeros(256, dtype=np.int64)
    if kind == "random":
        h[:] = draw(st.lists(st.integers(0, 1000), min_size=256, max_size=256))
        h[draw(st.integers(0, 255))] += 1  # never empty: empty labels are skipped, not fitted
    elif kind == "sparse":
        for k in draw(st.lists(st.integers(0, 255), min_size=1, max_size=6)):
            h[k] += draw(st.integers(1, 50))
    elif kind == "one":
        h[draw(st.integers(0, 255))] = draw(st.integers(1, 2**40))
    elif kind == "two":
        a, b = draw(st.lists(st.integers(0, 255), min_size=2, max_size=2, unique=True))
        h[a], h[b] = draw(st.integers(1, 10**6)), draw(st.integers(1, 10**6))
    elif kind == "saturated":
        end = draw(st.sampled_from([0, 255]))
        lo = draw(st.integers(0, 200))
        h[lo:lo + 50] = draw(st.integers(1, 100))
        h[end] += int(h.sum() * draw(st.floats(0.4, 5.0)))
    else:
        top = 2**32 - 1 if kind == "huge32" else 2**53
        for k in draw(st.lists(st.integers(0, 255), min_size=1, max_size=4, unique=True)):
            h[k] = draw(st.integers(top // 2, top))
    return h


@SETTINGS
@given(histograms())
def test_any_histogram_gives_a_finite_model_and_in_range_pixels(h):
    r = fit_histogram(h)
    m = r.model
    assert all(math.isfinite(v) for v in (m.gamma, m.delta, m.xi, m.lam, r.beta1, r.beta2))
    assert all(-0.5 <= p <= 255.5 for p in r.percentiles)
    codec = PercentileCodec.for_levels(256)
    assert rebuild(r, codec.decode(codec.encode(r.percentiles))) == m
    px = m.sample_pixels(500, np.random.default_rng(0))
    assert px.dtype == np.uint8
    x = m.sample(500, np.random.default_rng(1))
    assert np.all(np.isfinite(x))


finite = st.floats(-1e12, 1e12, allow_nan=False, allow_infinity=False)
positive = st.floats(1e-6, 1e6, allow_nan=False, allow_infinity=False)


@st.composite
def models(draw):
    family = draw(st.sampled_from([Family.SU, Family.SB, Family.SL, Family.SN]))
    lam = draw(positive)
    if family is Family.SL and draw(st.booleans()):
        lam = -lam
    return Johnson(family, draw(st.floats(-50, 50)), draw(positive), draw(finite), lam)


@SETTINGS
@given(models(), st.floats(0.001, 0.999))
def test_any_finite_parameters_give_finite_samples_and_consistent_cdf(m, u):
    rng = np.random.default_rng(2)
    for dtype in (np.float32, np.float64):
        assert np.all(np.isfinite(m.sample(200, rng, dtype=dtype)))
    px = m.sample_pixels(200, rng)
    assert px.min() >= 0 and px.max() <= 255
    deep = m.sample_pixels(50, rng, levels=4096)
    assert deep.dtype == np.uint16 and deep.max() <= 4095
    x = m.ppf(u)
    assert np.isfinite(x)
    w = (float(normal_ppf(u)) - m.gamma) / m.delta
    if abs(w) < 600 and abs(x) < 1e300:  # beyond, the quantile is clipped to the finite range
        back = float(m.cdf(x))
        if abs(back - u) > 1e-6:
            # x is rounded to a float64: then u must lie between the cdf of its neighbours
            below, above = m.cdf(np.nextafter(x, -np.inf)), m.cdf(np.nextafter(x, np.inf))
            assert below - 1e-6 <= u <= above + 1e-6
    assert np.all(np.isfinite(m.pdf(np.array([x, x + 1.0, -1e300, 1e300]))))
