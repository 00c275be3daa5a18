"""The spectrum's refit holds a real, even spectrum once per pair of frequencies k, -k: each
frequency of the ring is one entry or the mirror of one, and the refit on the half meets a
window as the refit on the whole ring did."""
from __future__ import annotations

import numpy as np
import pytest

from tools.analysis import spectrum
from tools.analysis.latent import GRID

RADIUS = 6


@pytest.mark.parametrize("shape", [(8, 8), (7, 9), (9, 6), (128, 128)])
def test_every_frequency_of_the_ring_is_one_entry_or_its_mirror(shape):
    ny, nx = shape
    plane = spectrum._half_plane(ny, nx)
    twice = plane.count == 2
    covered = np.bincount(np.concatenate([plane.full, plane.full_mirror[twice]]), minlength=ny * nx)
    assert covered.tolist() == [1] * (ny * nx)
    assert np.array_equal(plane.full[~twice], plane.full_mirror[~twice])  # self-mirrored: k = -k


@pytest.mark.parametrize("shape", [(8, 8), (7, 9), (9, 6)])
def test_the_half_gives_the_autocorrelation_of_the_whole_even_spectrum(shape):
    ny, nx = shape
    rng = np.random.default_rng(1)
    s = rng.random(shape)
    s = s + s[(-np.arange(ny)) % ny][:, (-np.arange(nx)) % nx]  # even: S(k) = S(-k)
    plane = spectrum._half_plane(ny, nx)
    half = np.zeros((ny, nx // 2 + 1))
    half.flat[plane.entries] = s.ravel()[plane.full]
    half.flat[plane.mirror_to] = half.flat[plane.mirror_from]
    assert np.allclose(np.fft.irfft2(half, s=shape), np.fft.ifft2(s).real, atol=1e-12)


def _window_miss(s: np.ndarray, target: np.ndarray) -> float:
    lags, vals = spectrum.full_window(RADIUS, target)
    r = np.fft.ifft2(s / s.mean()).real
    return float(np.abs(r[lags[:, 0] % s.shape[0], lags[:, 1] % s.shape[1]] - vals).max())


def test_an_anisotropic_diagonal_window_is_met_and_the_spectrum_is_even_and_non_negative():
    lags = np.array(spectrum.window(RADIUS), dtype=float)
    # a grain longer along the diagonal y = x than across it
    target = 0.8 * np.exp(-np.hypot((lags[:, 0] + lags[:, 1]) / 6.0, (lags[:, 0] - lags[:, 1]) / 2.0))
    curve = GRID.copy()  # the identity: pixel and latent correlation alike
    start = spectrum._projected(RADIUS, target, 32, 32)
    s = spectrum._refit(RADIUS, target, start, curve)
    assert s.min() >= 0 and np.isfinite(s).all()
    assert np.allclose(s, s[(-np.arange(32)) % 32][:, (-np.arange(32)) % 32])
    assert _window_miss(s, target) < 0.02
    r = np.fft.ifft2(s / s.mean()).real
    assert r[3, 3] > r[3, -3] + 0.2  # the diagonal kept: (3, 3) along the grain, (3, -3) across it
