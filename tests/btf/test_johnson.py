"""The Johnson model: transforms, distribution functions and samplers."""
import math

import numpy as np
import pytest

from btf.johnson import Family, Johnson, normal_cdf

MODELS = [
    Johnson(Family.SU, 0.7, 1.3, 120.0, 14.0),
    Johnson(Family.SU, -2.0, 0.6, 60.0, 3.0),
    Johnson(Family.SB, 0.4, 0.9, 20.0, 220.0),
    Johnson(Family.SB, -1.6, 1.2, 0.0, 255.0),
    Johnson(Family.SL, 0.2, 1.5, 40.0, 30.0),
    Johnson(Family.SL, 0.2, 1.5, 230.0, -30.0),
    Johnson.normal(128.0, 20.0),
]


@pytest.mark.parametrize("model", MODELS, ids=lambda m: f"{m.family}{m.lam:+}")
def test_x_of_z_inverts_z_of_x_and_is_increasing(model):
    z = np.linspace(-5, 5, 201)
    x = model.x_of_z(z)
    assert np.all(np.diff(x) > 0)
    np.testing.assert_allclose(model.z_of_x(x), z, atol=1e-8)


@pytest.mark.parametrize("model", MODELS, ids=lambda m: f"{m.family}{m.lam:+}")
def test_cdf_of_ppf_is_identity_and_pdf_integrates_to_cdf(model):
    u = np.linspace(0.001, 0.999, 99)
    np.testing.assert_allclose(model.cdf(model.ppf(u)), u, atol=1e-12)
    a, b = model.ppf([0.1, 0.9])
    grid = np.linspace(a, b, 20001)
    integral = np.trapezoid(model.pdf(grid), grid)
    assert integral == pytest.approx(0.8, abs=1e-6)


def test_reflected_sl_mirrors_the_positive_one():
    pos = Johnson(Family.SL, 0.3, 1.2, -10.0, 4.0)
    neg = Johnson(Family.SL, -0.3, 1.2, 10.0, -4.0)
    x = np.linspace(-5, 60, 50)
    np.testing.assert_allclose(neg.cdf(-x), 1.0 - pos.cdf(x), atol=1e-12)
    assert neg.cdf(10.5) == 1.0 and neg.pdf(11.0) == 0.0


def test_sb_keeps_precision_near_its_upper_bound():
    m = Johnson(Family.SB, -6.0, 1.0, 0.0, 1.0)  # mass piled against the upper bound
    x = m.x_of_z(np.array([3.0]))[0]
    gap = 1.0 - x
    # 1 - expit(w) computed directly: the gap is exact, not rounded to 0.
    assert gap == pytest.approx(1.0 / (1.0 + math.exp(9.0)), rel=1e-12)


def test_pixels_of_z_equals_clip_round_of_the_continuous_value():
    rng = np.random.default_rng(3)
    z = rng.standard_normal(20000)
    for model in MODELS:
        want = np.clip(np.rint(model.x_of_z(z)), 0, 255).astype(np.uint8)
        got = model.pixels_of_z(z)
        assert got.dtype == np.uint8
        assert np.mean(got != want) < 1e-3  # only exact half-way ties may differ
        assert np.all(np.abs(got.astype(int) - want) <= 1)


def test_sample_pixels_matches_level_probabilities():
    rng = np.random.default_rng(4)
    n = 400_000
    for model in MODELS:
        px = model.sample_pixels(n, rng)
        assert px.dtype == np.uint8
        freq = np.bincount(px, minlength=256) / n
        p = model.level_probabilities()
        # binomial noise plus the 2**-16 table resolution
        assert np.all(np.abs(freq - p) <= 5 * np.sqrt(p * (1 - p) / n) + 2.0**-15)


def test_lookup_table_cells_are_within_one_table_step():
    for model in MODELS:
        table = model.pixel_table()
        assert table.shape == (65536,)
        share = np.bincount(table, minlength=256) / 65536
        assert np.all(np.abs(share - model.level_probabilities()) <= 2.0**-16 + 1e-15)


def test_a_constant_lookup_table_holds_its_level_at_any_depth():
    table = Johnson.constant(300.2).pixel_table(levels=1024)
    assert table.dtype == np.uint16 and (table == 300).all()
    assert (Johnson.constant(300.2).pixel_table() == 255).all()  # clipped to the 8-bit range
    with pytest.raises(ValueError, match="levels"):
        Johnson.constant(3.0).pixel_table(levels=1)


def test_sixteen_bit_pixels_are_uint16_in_range():
    m = Johnson(Family.SU, 0.0, 0.3, 30000.0, 500.0)
    px = m.sample_pixels(10000, np.random.default_rng(0), levels=65536)
    assert px.dtype == np.uint16
    assert px.min() == 0 and px.max() == 65535  # heavy tails saturate both ends


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_float_sampling_follows_the_model(dtype):
    rng = np.random.default_rng(5)
    for model in MODELS:
        x = model.sample(200_000, rng, dtype=dtype)
        assert x.dtype == dtype and np.all(np.isfinite(x))
        q = np.quantile(x.astype(np.float64), [0.1, 0.5, 0.9])
        np.testing.assert_allclose(model.cdf(q), [0.1, 0.5, 0.9], atol=0.01)


@pytest.mark.parametrize("family", [Family.SU, Family.SL, Family.SB])
def test_extreme_parameters_never_overflow(family):
    rng = np.random.default_rng(6)
    lam = -1e30 if family is Family.SL else 1e30
    m = Johnson(family, 50.0, 1e-3, 1e300, lam)
    for dtype in (np.float32, np.float64):
        assert np.all(np.isfinite(m.sample(1000, rng, dtype=dtype)))
    assert np.all(np.isfinite(m.x_of_z(np.linspace(-40, 40, 9))))
    assert np.all(np.isfinite(m.z_of_x(np.linspace(-1e307, 1e307, 9))))
    assert np.all(np.isfinite(m.pdf(np.linspace(-1e307, 1e307, 9))))
    px = m.sample_pixels(1000, rng)
    assert px.dtype == np.uint8


@pytest.mark.parametrize("model", [Johnson(Family.SU, 0.0, 0.01, 5.0, 20.0),
                                   Johnson(Family.SL, 0.0, 0.01, 5.0, -20.0),
                                   Johnson(Family.SU, 0.0, 0.01, 5.0, 0.5)])
def test_float32_tails_run_on_towards_the_float32_maximum_without_overflow(model):
    # |w| = |z| / delta reaches ~400: float32 exp overflows near 88.7 and once stopped at 80,
    # saturating at 2.8e34 * lam; the tails now reach e^88.5 ~ 2.7e38 (or lam/2 of it below 2).
    z = np.random.default_rng(8).standard_normal(2000).astype(np.float32)
    x = model._x_of_z_inplace(z.copy())
    assert np.all(np.isfinite(x))
    reach = min(2.7e38, 0.5 * abs(model.lam) * math.exp(88.5))
    assert np.max(np.abs(x)) >= 0.99 * reach
    # below where the float32 path saturates, the two agree to float32 precision
    x64 = model.x_of_z(z.astype(np.float64))
    inside = np.abs(x64) < 0.99 * reach
    np.testing.assert_allclose(x[inside], x64[inside], rtol=1e-4)


def test_constant_model_is_a_point_mass():
    c = Johnson.constant(42.0)
    rng = np.random.default_rng(0)
    assert np.all(c.sample_pixels(100, rng) == 42)
    assert np.all(c.sample(10, rng) == 42.0)
    assert list(c.cdf([41.9, 42.0])) == [0.0, 1.0]


def test_invalid_parameters_are_rejected_with_a_reason():
    with pytest.raises(ValueError, match="finite"):
        Johnson(Family.SU, float("nan"), 1.0, 0.0, 1.0)
    with pytest.raises(ValueError, match="delta"):
        Johnson(Family.SU, 0.0, -1.0, 0.0, 1.0)
    with pytest.raises(ValueError, match="lam"):
        Johnson(Family.SB, 0.0, 1.0, 0.0, -1.0)
    with pytest.raises(ValueError, match="probabilities"):
        Johnson.normal(0, 1).ppf([0.5, 1.5])
    with pytest.raises(ValueError, match="levels"):
        Johnson.normal(0, 1).sample_pixels(10, np.random.default_rng(0), levels=1)


def test_normal_cdf_is_accurate_in_the_far_tail():
    assert float(normal_cdf(-30.0)) == pytest.approx(4.906713927148187e-198, rel=1e-12)
