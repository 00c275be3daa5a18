"""Correlated Gaussian fields: valid spectra, the asked-for lags and copula, nearest correlation."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from btf.dependence import LAGS, Dependence
from btf.johnson import Family, Johnson
from tools.analysis.fields import (
    blend,
    empirical_autocorrelation,
    gaussian_fields,
    latent,
    latent_rho,
    nearest_correlation,
    spectrum,
)


def test_fields_reproduce_lags_and_copula():
    dep = Dependence((0.8, 0.3, -0.2), (0.7, 0.45, 0.2, 0.05), (0.5, 0.2, 0.05, 0.0))
    f = gaussian_fields((300, 360), dep, np.random.default_rng(1))
    assert f.shape == (3, 300, 360) and f.dtype == np.float32
    assert np.all(np.abs(f.std(axis=(1, 2)) - 1.0) < 0.05)
    inside = np.ones((300, 360), dtype=bool)
    for k, lag in enumerate(LAGS):
        assert empirical_autocorrelation(f[0], inside, lag, 1) == pytest.approx(dep.dx[k], abs=0.05)
        assert empirical_autocorrelation(f[2], inside, lag, 0) == pytest.approx(dep.dy[k], abs=0.05)
    c = np.corrcoef(f.reshape(3, -1))
    assert c[np.triu_indices(3, 1)] == pytest.approx(dep.corr, abs=0.03)


lag_values = st.lists(st.floats(-1.0, 1.0), min_size=4, max_size=4).map(tuple)


@settings(max_examples=40, deadline=None)
@given(lag_values, st.integers(18, 300))
def test_any_lags_give_a_finite_nonnegative_unit_variance_spectrum(lags, n):
    s = spectrum(lags, n)
    assert np.all(np.isfinite(s)) and np.all(s >= 0)
    r = np.fft.irfft(s, n)
    assert r[0] == pytest.approx(1.0, abs=1e-9)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=6, max_size=6))
def test_nearest_correlation_is_valid_for_any_triangle(tri):
    m = np.eye(4)
    iu = np.triu_indices(4, 1)
    m[iu] = tri
    m[(iu[1], iu[0])] = tri
    c = nearest_correlation(m)
    assert np.allclose(np.diag(c), 1.0) and np.allclose(c, c.T)
    assert np.linalg.eigvalsh(c).min() > 0
    np.linalg.cholesky(c)


def test_nearest_correlation_keeps_a_valid_matrix():
    m = np.array([[1.0, 0.5], [0.5, 1.0]])
    assert np.allclose(nearest_correlation(m), m)


def test_blend_is_linear_and_stays_a_correlation_matrix():
    a = Dependence((0.9, 0.9, 0.9), (0.8,) * 4, (0.6,) * 4)
    b = Dependence((-0.4, 0.4, -0.4), (0.0,) * 4, (0.2,) * 4)
    m = blend(a, b, 0.25)
    assert m.dx == pytest.approx((0.6,) * 4) and m.dy == pytest.approx((0.5,) * 4)
    assert np.linalg.eigvalsh(m.matrix()).min() >= -1e-12
    with pytest.raises(ValueError, match="weight"):
        blend(a, b, 1.5)


def test_latent_inverts_the_pixel_correlation_through_the_models():
    normal = Johnson.normal(128.0, 20.0)
    assert latent_rho(normal, normal, 0.5) == pytest.approx(0.5, abs=0.01)
    heavy = Johnson(Family.SU, -0.7, 0.8, 10.0, 2.5)  # a dark plate: heavy bright tail
    rho = latent_rho(heavy, heavy, 0.3)
    z = np.random.default_rng(2).standard_normal((2, 200_000))
    z2 = rho * z[0] + np.sqrt(1 - rho**2) * z[1]
    x1, x2 = (np.clip(np.rint(heavy.x_of_z(v)), 0, 255) for v in (z[0], z2))
    assert np.corrcoef(x1, x2)[0, 1] == pytest.approx(0.3, abs=0.02)
    assert latent_rho(Johnson.constant(4.0), normal, 0.9) == 0.0


def test_latent_needs_one_model_per_band():
    with pytest.raises(ValueError, match="bands"):
        latent(Dependence.independent(3), (Johnson.normal(0, 1),))
