"""A band's z -> level map, truncated to the region's observed levels, and its tables."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from btf.johnson import Family, Johnson
from tools.analysis.levelmap import (
    Z_SPAN,
    level_map,
    pixel_corr,
    quantile,
    uniform_table,
    z_scale,
    z_table,
)

HEAVY = Johnson(Family.SU, -1.2, 0.9, 30.0, 6.0)  # a dark region's model with a long bright tail


def test_without_observed_levels_the_map_is_the_models_level_probabilities():
    m = level_map(HEAVY, 256)
    assert (m.lo, m.hi) == (0, 255)
    assert np.abs(m.probs - HEAVY.level_probabilities(256)).max() < 1e-9


def test_a_truncated_map_keeps_the_curve_inside_and_renormalises_it():
    m = level_map(HEAVY, 256, 12, 87)
    want = HEAVY.level_probabilities(256)[12:88]
    assert m.probs.sum() == pytest.approx(1.0) and len(m.probs) == 76
    assert np.allclose(m.probs, want / want.sum(), atol=1e-9)
    assert set(np.unique(m.levels_of(np.linspace(-9, 9, 10001)))) <= set(range(12, 88))


def test_a_side_at_the_sensors_limit_keeps_its_pile():
    bright = Johnson.normal(250.0, 10.0)  # a third of it beyond 255: the sensor clipped it there
    m = level_map(bright, 256, 200, 255)
    p = bright.level_probabilities(256)
    assert m.probs[-1] == pytest.approx(p[255] / p[200:].sum(), rel=1e-6) and m.probs[-1] > 0.3


def test_a_curve_with_no_mass_in_the_observed_levels_is_drawn_clipped():
    m = level_map(Johnson.normal(20.0, 1.0), 256, 200, 210)
    assert (m.lo, m.hi) == (0, 255) and m.probs[20] > 0.3


def test_the_tables_draw_the_maps_probabilities():
    m = level_map(HEAVY, 256, 12, 87)
    u = np.bincount(uniform_table(m), minlength=256)[12:88] / 65536
    assert np.abs(u - m.probs).max() <= 2.0 ** -16 + 1e-12
    centres = (np.arange(1 << 16) + 0.5) / z_scale(16) - Z_SPAN
    from scipy.special import ndtr
    width = ndtr(centres + 0.5 / z_scale(16)) - ndtr(centres - 0.5 / z_scale(16))
    drawn = np.bincount(z_table(m, 16), weights=width, minlength=256)[12:88]
    assert np.abs(drawn - m.probs).max() < 1e-4  # the bin centre's level: off only at thresholds


def test_pixel_correlation_of_two_maps_matches_monte_carlo():
    a, b = level_map(HEAVY, 256, 12, 87), level_map(Johnson.normal(120.0, 30.0), 256, 40, 200)
    z = np.random.default_rng(1).standard_normal((2, 400_000))
    for rho in (0.3, 0.8, 0.97):
        z2 = rho * z[0] + np.sqrt(1 - rho ** 2) * z[1]
        want = np.corrcoef(a.levels_of(z[0]), b.levels_of(z2))[0, 1]
        assert float(pixel_corr(a, b, rho)) == pytest.approx(want, abs=0.01)
    assert float(pixel_corr(a, a, 1.0, same=True)) == pytest.approx(1.0)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 250), st.integers(1, 60), st.floats(-3, 3), st.floats(0.3, 3))
def test_the_truncated_quantile_function_never_rounds_outside(lo, span, gamma, delta):
    hi = min(lo + span, 255)
    model = Johnson(Family.SU, gamma, delta, 100.0, 20.0)
    x = np.clip(np.rint(quantile(model, 256, lo, hi, np.linspace(-8, 8, 2001))), 0, 255)  # as synthesis rounds
    m = level_map(model, 256, lo, hi)
    assert x.min() >= m.lo and x.max() <= m.hi
