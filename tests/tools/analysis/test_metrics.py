"""The host's image metrics against small cases worked by hand, and against scipy.stats."""
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from tools.analysis import metrics


def h(*p):
    return np.array(p, dtype=np.float64)


def test_opposite_point_masses_hit_every_metric_maximum():
    a, b = h(1, 0, 0, 0), h(0, 0, 0, 1)
    assert metrics.hist_diff(a, b) == 2.0
    assert metrics.chi2(a, b) == 2.0
    assert metrics.ks(a, b) == 1.0
    assert metrics.w1(a, b) == pytest.approx(3.0)


def test_two_level_case_worked_by_hand():
    a = metrics.histogram(np.array([0, 0, 1, 1]), 2)
    b = metrics.histogram(np.array([0, 1, 1, 1]), 2)
    assert a.tolist() == [0.5, 0.5] and b.tolist() == [0.25, 0.75]
    assert metrics.hist_diff(a, b) == pytest.approx(0.5)
    assert metrics.chi2(a, b) == pytest.approx(0.0625 / 0.75 + 0.0625 / 1.25)
    assert metrics.ks(a, b) == pytest.approx(0.25)
    assert metrics.w1(a, b) == pytest.approx(0.25)


def test_circular_distances_go_the_short_way_round():
    a, b = h(1, 0, 0, 0), h(0, 0, 0, 1)  # neighbours across the wrap
    assert metrics.w1(a, b, circular=True) == pytest.approx(1.0)
    assert metrics.w1(a, b) == pytest.approx(3.0)
    c = h(0, 0, 1, 0)  # half way round: the long and short ways are equal
    assert metrics.w1(a, c, circular=True) == pytest.approx(2.0)
    # Two half-masses shifted by one level across the wrap move half a unit each.
    d, e = h(0.5, 0, 0, 0.5), h(0.5, 0.5, 0, 0)
    assert metrics.w1(d, e, circular=True) == pytest.approx(1.0)
    assert metrics.ks(d, e, circular=True) == pytest.approx(0.5)
    assert metrics.ks(d, e) == pytest.approx(0.5)


def test_pearson_correlation_signs_and_constant_bands():
    x = np.array([1, 2, 3, 4])
    assert metrics.correlation(x, 2 * x + 1) == pytest.approx(1.0)
    assert metrics.correlation(x, -x) == pytest.approx(-1.0)
    assert metrics.correlation(x, np.array([1, 3, 2, 4])) == pytest.approx(0.8)
    assert metrics.correlation(np.full(4, 7), x) == 0.0
    assert metrics.correlation(np.full(4, 7), np.full(4, 7)) == 1.0


def test_hue_correlation_is_circular():
    rng = np.random.default_rng(1)
    a = rng.integers(170, 190, 500) % 180  # straddles the wrap at 180
    b = (a + 1) % 180
    assert metrics.circular_correlation(a, b, 180) > 0.99
    assert metrics.correlation(a, b) < 0.9


def test_compare_bands_per_region_and_totals():
    ref = np.zeros((2, 4, 1), np.uint8)
    ref[:, :2, 0] = 10
    test = ref.copy()
    test[:, 2:, 0] = 1  # region 1 moves from level 0 to 1; region 0 identical
    mask = np.zeros((2, 4), np.uint8)
    mask[:, 2:] = 1
    out = metrics.compare_bands(ref, test, ("Y",), mask=mask)
    r0, r1 = out.regions
    assert (r0.label, r0.hist_diff, r0.w1) == (0, 0.0, 0.0)
    assert (r1.label, r1.hist_diff, r1.ks, r1.w1, r1.count_ref) == (1, 2.0, 1.0, 1.0, 4)
    assert out.total["hist_diff"] == 2.0
    doc = out.to_json()
    assert set(doc) == {"bands", "correlation", "regions", "total"}
    assert doc["regions"][1]["label"] == 1


def test_compare_rejects_size_mismatch():
    with pytest.raises(ValueError, match="differ in size"):
        metrics.compare_bands(np.zeros((2, 2, 1)), np.zeros((2, 3, 1)), ("Y",))


@settings(max_examples=60, deadline=None)
@given(st.integers(2, 300), st.integers(0, 2**32 - 1))
def test_w1_is_scipys_wasserstein_distance_over_the_levels(levels, seed):
    rng = np.random.default_rng(seed)
    a, b = (metrics.normalized(rng.integers(0, 50, levels) * (rng.random(levels) < 0.6)) for _ in range(2))
    if a.sum() == 0 or b.sum() == 0:
        assert metrics.w1(a, b) == 0.0
        return
    grid = np.arange(levels, dtype=np.float64)
    assert metrics.w1(a, b) == pytest.approx(stats.wasserstein_distance(grid, grid, a, b), rel=1e-9, abs=1e-12)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(0.0, 2 * np.pi, exclude_max=True), min_size=1, max_size=50))
def test_circular_mean_is_scipys_circmean_up_to_a_turn(angles):
    theta = np.array(angles)
    if np.hypot(np.sin(theta).mean(), np.cos(theta).mean()) < 1e-6:
        return  # no mean direction: both answer rounding noise
    gap = metrics.circular_mean(theta) - stats.circmean(theta)
    assert abs(np.angle(np.exp(1j * gap))) < 1e-9


def test_metrics_loads_without_scipy_stats():
    # `compare` imports it: scipy.stats alone took 1.5 s of each call
    code = "import sys, tools.analysis.metrics; print('scipy.stats' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
