"""Correlated fields: the latent targets, the grain's spectrum and the fields drawn from it."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from threadpoolctl import threadpool_limits

from btf.dependence import Dependence, window
from btf.johnson import Family, Johnson
from tools.analysis.fields import blend, draw, grain_of
from tools.analysis.latent import GRID, curve, grain_curve, latent_acf, latent_bands
from tools.analysis.levelmap import level_map, pixel_corr
from tools.analysis.spectrum import RING, amplitude, full_window, ring_spectrum

NORMALS = tuple(level_map(Johnson.normal(128.0, 20.0), 256) for _ in range(3))


def _grain(decay, aspect: float = 1.0, shear: float = 0.0) -> tuple[float, ...]:
    """An exponential grain on the window: longer along x by `aspect`, sheared along a diagonal."""
    return tuple(float(decay ** np.hypot(dy, (dx - shear * dy) / aspect)) for dy, dx in window(6))


def _acf(x: np.ndarray, dy: int, dx: int) -> float:
    a = x[dy:, max(dx, 0):x.shape[1] + min(dx, 0)]
    b = x[:x.shape[0] - dy, max(-dx, 0):x.shape[1] - max(dx, 0)]
    return float(np.corrcoef(a.ravel(), b.ravel())[0, 1])


@pytest.mark.parametrize("inside", [None, "half"])
def test_fields_have_the_grain_and_exactly_the_band_correlation(inside):
    dep = Dependence((0.8, 0.3, -0.2), (_grain(0.8, aspect=2.0, shear=1.0),), 6)
    fields = draw(grain_of(dep, NORMALS), (240, 300), np.random.default_rng(1),
                  inside=None if inside is None else np.arange(300)[None, :].repeat(240, 0) < 180)
    assert len(fields) == 3 and all(f.shape == (240, 300) and f.dtype == np.float32 for f in fields)
    sel = slice(None) if inside is None else (slice(None), slice(0, 180))
    v = np.stack([f[sel].ravel() for f in fields]).astype(np.float64)
    assert np.allclose(v.mean(axis=1), 0, atol=1e-3) and np.allclose(v.std(axis=1), 1, atol=1e-3)
    assert np.corrcoef(v)[np.triu_indices(3, 1)] == pytest.approx([0.8, 0.3, -0.2], abs=0.005)
    for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1), (2, 2), (3, 0)):
        want = 0.8 ** np.hypot(dy, (dx - dy) / 2.0)  # a sheared, stretched grain: no product of axes
        assert _acf(fields[0], dy, dx) == pytest.approx(want, abs=0.04), (dy, dx)


def test_each_band_keeps_its_own_grain_and_the_bands_their_correlation():
    dep = Dependence((0.7, 0.0, 0.0), (_grain(0.9), _grain(0.5), _grain(0.7, aspect=3.0)), 6)
    fields = draw(grain_of(dep, NORMALS), (256, 256), np.random.default_rng(2))
    assert _acf(fields[0], 0, 2) == pytest.approx(0.81, abs=0.06)
    assert _acf(fields[1], 0, 2) == pytest.approx(0.25, abs=0.05)
    assert _acf(fields[2], 1, 0) == pytest.approx(0.7, abs=0.05)
    assert np.corrcoef(fields[0].ravel(), fields[1].ravel())[0, 1] == pytest.approx(0.7, abs=0.005)


def test_the_fields_are_the_target_in_table_units():
    dep = Dependence((0.5,), (_grain(0.6),), 6)
    maps = NORMALS[:2]
    z = [f.copy() for f in draw(grain_of(dep, maps), (128, 128), np.random.default_rng(3))]  # a workspace
    idx = draw(grain_of(dep, maps), (128, 128), np.random.default_rng(3), scale=1000.0, offset=8500.0)
    assert np.allclose(idx[0], 1000.0 * z[0] + 8500.0, atol=0.05)


@settings(max_examples=15, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=12, max_size=12))
def test_any_window_gives_a_finite_nonnegative_unit_variance_spectrum(values):
    with threadpool_limits(1, "blas"):  # as grain_of runs it
        s = ring_spectrum(2, tuple(values), grain_curve(list(NORMALS[:1])), 32, 32)
    assert np.all(np.isfinite(s)) and np.all(s >= 0)
    assert np.fft.ifft2(s).real[0, 0] == pytest.approx(1.0, abs=1e-9)


def test_a_reachable_window_is_met_by_the_spectrum_and_the_interpolated_grid_keeps_it():
    target = np.array(_grain(0.85, aspect=1.5, shear=0.5))
    s = ring_spectrum(6, tuple(target), grain_curve(list(NORMALS)), RING, RING)
    lags, _ = full_window(6, target)
    r = np.fft.ifft2(s).real[lags[1:85, 0] % RING, lags[1:85, 1] % RING]
    assert np.abs(r - target).max() < 0.02
    a = amplitude(s, 500, 300) ** 2
    full = np.concatenate([a, a[:, 1:150][:, ::-1]], axis=1)  # the mirrored half of the grid
    assert full.mean() == pytest.approx(1.0, rel=1e-3) and a.min() >= 0


def test_the_latent_band_matrix_reproduces_reachable_pixel_correlations():
    heavy = level_map(Johnson(Family.SU, -1.2, 0.9, 30.0, 6.0), 256, 12, 87)
    maps = [heavy, NORMALS[0], level_map(Johnson.normal(60.0, 8.0), 256)]
    want = np.array([[1.0, 0.6, 0.3], [0.6, 1.0, 0.5], [0.3, 0.5, 1.0]])
    latent, reached = latent_bands(want, maps)
    assert np.allclose(reached, want, atol=0.005)
    assert np.linalg.eigvalsh(latent).min() > 0
    assert reached[0, 1] == pytest.approx(float(pixel_corr(maps[0], maps[1], latent[0, 1])))


def test_a_correlation_beyond_the_marginals_is_reached_as_near_as_they_allow():
    skewed = level_map(Johnson(Family.SL, 0.0, 0.6, 0.0, 1.0), 256)  # piled near 0, a long tail
    maps = [NORMALS[0], skewed]
    bound = float(curve(maps[0], maps[1])[-1])  # the comonotone pixel correlation
    _, reached = latent_bands(np.array([[1.0, 0.99], [0.99, 1.0]]), maps)
    assert bound < 0.9 and reached[0, 1] == pytest.approx(bound, abs=0.01)


def test_the_grain_curve_inverts_to_the_latent_grain():
    assert latent_acf(np.array([0.0, 0.5, 1.0]), grain_curve(list(NORMALS))) == pytest.approx([0, 0.5, GRID[-1]], abs=0.01)


def test_blending_mixes_spectra_and_matrices_linearly():
    a = grain_of(Dependence((0.9, 0.9, 0.9), (_grain(0.9),), 6), NORMALS)
    b = grain_of(Dependence((-0.4, 0.4, -0.4), (_grain(0.3),), 6), NORMALS)
    m = blend(a, b, 0.25)
    assert np.allclose(m.latent, 0.75 * a.latent + 0.25 * b.latent)
    assert np.allclose(m.rings[0], 0.75 * a.rings[0] + 0.25 * b.rings[0])
    assert np.linalg.eigvalsh(m.latent).min() >= -1e-12
    with pytest.raises(ValueError, match="weight"):
        blend(a, b, 1.5)


def test_the_least_mixing_correction_meets_the_covariance_nearer_the_identity_than_a_triangular_one():
    from tools.analysis.fields import correction

    rng = np.random.default_rng(3)
    for _ in range(20):
        a = rng.standard_normal((3, 3))
        now = a @ a.T + 0.05 * np.eye(3)
        want = np.corrcoef(rng.standard_normal((3, 6)))  # nearly singular at times
        least, tri = correction(now, want, least_mixing=True), correction(now, want)
        assert least @ now @ least.T == pytest.approx(want, abs=1e-6)
        assert tri @ now @ tri.T == pytest.approx(want, abs=1e-6)
        # the optimal transport map moves a draw least: E|T z - z|^2 = tr((T - I) now (T - I)^T)
        cost = lambda t: float(np.trace((t - np.eye(3)) @ now @ (t - np.eye(3)).T))  # noqa: E731
        assert cost(least) <= cost(tri) + 1e-9


def test_bands_of_their_own_grain_keep_it_beside_a_correlation_one_constant_mixing_cannot_give():
    """A stained micrograph's make-up: red and blue uncorrelated, green following both. Bands
    whose spectra differ cannot all meet such a matrix by one mixing of their phases; the draw's
    correction then must not pour one band's grain into another."""
    dep = Dependence((0.7, 0.0, 0.7), (_grain(0.95), _grain(0.8), _grain(0.4)), 6)
    fields = draw(grain_of(dep, NORMALS), (256, 256), np.random.default_rng(2),
                  inside=np.arange(256)[:, None].repeat(256, 1) % 64 < 48)  # not the whole box
    for band, decay in enumerate((0.95, 0.8, 0.4)):  # a triangular correction took blue's lag 1 to 0.68
        f = fields[band].astype(np.float64)
        assert _acf(f, 0, 1) == pytest.approx(decay, abs=0.08)
        assert _acf(f, 2, 2) == pytest.approx(decay ** np.hypot(2, 2), abs=0.08)
    v = np.stack([f[np.arange(256)[:, None].repeat(256, 1) % 64 < 48] for f in fields])
    assert np.corrcoef(v)[np.triu_indices(3, 1)] == pytest.approx([0.7, 0.0, 0.7], abs=0.01)


def test_bands_with_near_rows_get_near_spectra_so_a_high_band_correlation_stays_reachable():
    noise = np.random.default_rng(4).normal(0, 0.01, (3, len(window(6))))
    rows = tuple(tuple(np.clip(np.array(_grain(0.8)) + n, -1, 1).tolist()) for n in noise)
    grain = grain_of(Dependence((0.97, 0.95, 0.97), rows, 6), NORMALS)
    s = np.stack([r.ravel() for r in grain.rings])
    overlap = np.sqrt(s[:, None] * s[None]).mean(axis=2)  # the most two bands can correlate
    assert overlap.min() > 0.98


def test_a_region_scattered_over_its_box_gets_the_grain_over_its_own_pairs():
    """One draw's autocorrelation over a fragmented region strays from the spectrum's at the
    longer lags; the draw imposes it there, which a whole-box draw cut to the region does not."""
    from tools.analysis.grain_metrics import acf2d

    rng = np.random.default_rng(5)
    inside = np.kron(rng.random((10, 10)) < 0.35, np.ones((40, 40), bool))  # blocks over a 400 x 400 box
    dep = Dependence((0.0,), (_grain(0.95),), 6)
    grain = grain_of(dep, NORMALS[:2])
    target = np.array(_grain(0.95))
    imposed, cut = [], []
    for seed in range(3):
        f = draw(grain, inside.shape, np.random.default_rng(seed), inside=inside)[0]
        imposed.append(np.abs(acf2d(f, inside, 6) - target).max())
        g = draw(grain, inside.shape, np.random.default_rng(seed))[0]
        cut.append(np.abs(acf2d(g, inside, 6) - target).max())
    assert np.mean(imposed) < 0.04 and np.mean(imposed) < 0.6 * np.mean(cut)


@settings(max_examples=6, deadline=None)
@given(st.integers(0, 2 ** 31 - 1), st.lists(st.floats(-0.99, 0.99), min_size=3, max_size=3),
       st.floats(0.05, 0.9))
def test_any_own_grain_band_matrix_and_splintered_region_draw_finite_fields_of_exact_moments(seed, corr, share):
    rng = np.random.default_rng(seed)
    rows = tuple(tuple(rng.uniform(-1, 1, len(window(2))).tolist()) for _ in range(3))
    inside = rng.random((60, 70)) < share  # specks: every region pixel apart from the next
    fields = draw(grain_of(Dependence(tuple(corr), rows, 2), NORMALS), inside.shape, rng, inside=inside)
    assert all(np.all(np.isfinite(f)) for f in fields)
    if inside.sum() >= 64:
        v = np.stack([f[inside] for f in fields]).astype(np.float64)
        assert np.allclose(v.mean(axis=1), 0, atol=1e-3) and np.allclose(v.std(axis=1), 1, atol=1e-3)
