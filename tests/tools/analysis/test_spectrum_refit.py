"""The spectrum's refit tilts a base spectrum by the window's cosines: it meets a window a
spectrum can meet, keeps a base that already meets it, and stays finite where none can."""
from __future__ import annotations

import numpy as np
import pytest

from tools.analysis import spectrum
from tools.analysis.latent import GRID

RADIUS = 6


def _acf(s: np.ndarray) -> np.ndarray:
    return np.fft.ifft2(s / s.mean()).real


def _window_miss(s: np.ndarray, target: np.ndarray) -> float:
    lags, vals = spectrum.full_window(RADIUS, target)
    return float(np.abs(_acf(s)[lags[:, 0] % s.shape[0], lags[:, 1] % s.shape[1]] - vals).max())


def _is_even(s: np.ndarray) -> bool:
    ny, nx = s.shape
    return bool(np.allclose(s, s[(-np.arange(ny)) % ny][:, (-np.arange(nx)) % nx]))


def _diagonal_target() -> np.ndarray:
    """A grain longer along the diagonal y = x than across it."""
    lags = np.array(spectrum.window(RADIUS), dtype=float)
    return 0.8 * np.exp(-np.hypot((lags[:, 0] + lags[:, 1]) / 6.0, (lags[:, 0] - lags[:, 1]) / 2.0))


@pytest.mark.parametrize("shape", [(32, 32), (31, 33), (30, 27)])
def test_an_anisotropic_diagonal_window_is_met_and_the_spectrum_is_even_and_non_negative(shape):
    target = _diagonal_target()
    curve = GRID.copy()  # the identity: pixel and latent correlation alike
    flat = np.ones(shape)  # a start that knows nothing of the grain: the tilt must find it all
    s = spectrum._refit(RADIUS, target, flat, curve)
    assert s.min() >= 0 and np.isfinite(s).all() and s.mean() == pytest.approx(1.0)
    assert _is_even(s)
    assert _window_miss(flat, target) > 0.5 and _window_miss(s, target) < 0.02
    r = _acf(s)
    assert r[3, 3] > r[3, -3] + 0.2  # the diagonal kept: (3, 3) along the grain, (3, -3) across it


def test_a_reference_that_meets_the_window_comes_back_as_it_was():
    ny = nx = 64
    ky, kx = np.meshgrid(np.fft.fftfreq(ny), np.fft.fftfreq(nx), indexing="ij")
    reference = np.exp(-((ky / 0.05) ** 2 + (kx / 0.15) ** 2)) + 0.2  # anisotropic, nowhere zero
    reference /= reference.mean()
    lags = np.array(spectrum.window(RADIUS))
    target = _acf(reference)[lags[:, 0] % ny, lags[:, 1] % nx]
    s = spectrum._refit(RADIUS, target, np.ones((ny, nx)), GRID.copy(), reference=reference)
    # only the floor under every frequency (1e-3 of the mean) separates them
    assert np.abs(s - reference).max() < 5e-3 * reference.max()


def test_a_window_no_spectrum_can_meet_gives_a_finite_spectrum_nearest_it():
    target = np.zeros(len(spectrum.window(RADIUS)))
    target[0], target[1] = 0.99, -0.99  # lag 1 nearly one, lag 2 nearly minus one: not positive definite
    s = spectrum._refit(RADIUS, target, np.ones((32, 32)), GRID.copy())
    assert np.isfinite(s).all() and s.min() >= 0 and s.mean() == pytest.approx(1.0)
    r = _acf(s)
    assert r[0, 1] > 0.2 and r[0, 2] < -0.3  # pulled both ways, as far as a spectrum goes


def test_noisy_windows_reachable_or_not_refit_without_a_floating_point_fault():
    lags = np.array(spectrum.window(RADIUS), dtype=float)
    distance = np.hypot(lags[:, 0], lags[:, 1])
    rng = np.random.default_rng(5)
    for _ in range(12):
        target = np.clip(rng.uniform(0.3, 0.99) * rng.uniform(0.5, 0.99) ** distance
                         + rng.normal(0.0, rng.choice([0.01, 0.2]), len(lags)), -1.0, 1.0)
        with np.errstate(over="raise", invalid="raise", divide="raise"):
            s = spectrum._refit(RADIUS, target, np.ones((32, 32)), GRID.copy())
        assert np.isfinite(s).all() and s.min() >= 0 and s.mean() == pytest.approx(1.0)
