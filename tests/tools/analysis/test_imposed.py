"""A draw's grain as the record reads it: each lag's Pearson correlation over a region's own
pairs, and a long grain kept on a box no larger than the spectrum's ring."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.fft as sfft
from hypothesis import given, settings
from hypothesis import strategies as st

from btf.dependence import Dependence, window
from btf.johnson import Johnson
from tools.analysis import spectrum
from tools.analysis.fields import _shaping, _targets, draw, grain_of
from tools.analysis.grain_metrics import acf2d, pair_pearson, region_pairs
from tools.analysis.levelmap import level_map

NORMAL = level_map(Johnson.normal(128.0, 20.0), 256)


def _exponential(decay: float, radius: int) -> tuple[float, ...]:
    return tuple(float(decay ** np.hypot(dy, dx)) for dy, dx in window(radius))


def _pearson(values: np.ndarray, inside: np.ndarray, radius: int) -> np.ndarray:
    lags = np.array(window(radius))
    pad = tuple(sfft.next_fast_len(n + radius, real=True) for n in inside.shape)
    m, fm, n = region_pairs(inside, pad, lags)
    return pair_pearson((values * m).astype(np.float32), fm, n, pad, lags)


def test_the_pairs_correlation_is_the_judges_with_each_ends_own_mean():
    rng = np.random.default_rng(2)
    inside = rng.random((90, 110)) < 0.4
    ramp = np.linspace(-3.0, 3.0, 110)[None, :] * np.ones((90, 1))  # a lag's ends sit apart in level
    values = ramp + rng.standard_normal((90, 110))
    values -= values[inside].mean()
    got = _pearson(values, inside, 6)
    assert np.abs(got - acf2d(values, inside, 6)).max() < 1e-4
    # with the region's one mean and variance, a lag along the ramp reads otherwise
    lags = np.array(window(6))
    along = int(np.flatnonzero((lags[:, 0] == 0) & (lags[:, 1] == 6))[0])
    pairs_a, pairs_b = values[:, :-6][inside[:, :-6] & inside[:, 6:]], values[:, 6:][inside[:, :-6] & inside[:, 6:]]
    one_mean = float(np.mean(pairs_a * pairs_b) / np.mean(values[inside] ** 2))
    assert abs(one_mean - got[along]) > 0.05


def test_an_end_that_never_varies_is_no_figure():
    inside = np.zeros((40, 40), bool)
    inside[10:30, 10:30] = True
    assert np.all(np.isnan(_pearson(np.where(inside, 1.0, 0.0), inside, 3)))


def test_the_zero_frequencys_power_goes_to_the_eight_around_it_and_the_total_stays():
    rng = np.random.default_rng(0)
    ring = rng.random((16, 16)) + 0.1
    ring = ring + ring[(-np.arange(16)) % 16][:, (-np.arange(16)) % 16]  # S(k) = S(-k)
    ring[0, 0] = 40.0
    half = spectrum.amplitude(ring, 16, 16).astype(np.float64) ** 2
    full = np.concatenate([half, half[:, 1:8][(-np.arange(16)) % 16][:, ::-1]], axis=1)
    assert full[0, 0] == 0.0 and full.mean() == pytest.approx(1.0, rel=1e-5)
    plain = ring / ring.mean()
    around = [(0, 1), (0, 15), (1, 0), (15, 0), (1, 1), (15, 15), (1, 15), (15, 1)]
    gain = [full[k] / plain[k] for k in around]
    assert np.allclose(gain, gain[0], rtol=1e-4) and gain[0] > 1.5  # each in proportion to its own
    rest = np.ones_like(full, bool)
    rest[0, 0] = False
    for k in around:
        rest[k] = False
    assert np.allclose(full[rest], plain[rest], rtol=1e-5)


def test_a_long_grain_on_a_box_the_size_of_the_ring_keeps_its_far_lags():
    """A draw fixes its mean: power left at the zero frequency would be lost, and on a box of
    the ring's size that was a quarter of it, every far lag short by about 0.1."""
    target = np.array(_exponential(0.97, 8))
    dep = Dependence((), (tuple(target.tolist()),), 8)
    grain = grain_of(dep, (NORMAL,))
    side = spectrum.RING
    drawn = _targets(grain, (side, side), 1.0)[0]  # the drawn fields' autocorrelation, zero frequency left out
    c0 = drawn.shape[0] // 2
    lags = np.array(window(8))
    assert np.abs(drawn[c0 + lags[:, 0], c0 + lags[:, 1]] - target).max() < 0.03
    assert float(_shaping(grain, (side, side), 1.0).amps[0][0, 0]) == 0.0
    gaps = [np.abs(acf2d(draw(grain, (side, side), np.random.default_rng(s))[0], np.ones((side, side), bool), 8)
                   - target).max() for s in range(4)]
    assert np.mean(gaps) < 0.1


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2 ** 31 - 1), st.sampled_from(["random", "mean only", "zero", "spike"]),
       st.sampled_from([(16, 16), (40, 30), (129, 200)]))
def test_any_spectrum_keeps_its_power_off_the_zero_frequency_finite_and_nonnegative(seed, kind, grid):
    rng = np.random.default_rng(seed)
    ring = {"random": lambda: rng.random((16, 16)) * 10 ** rng.uniform(-3, 3), "zero": lambda: np.zeros((16, 16)),
            "mean only": lambda: np.pad(np.ones((1, 1)), ((0, 15), (0, 15))),
            "spike": lambda: np.pad(np.ones((1, 1)), ((0, 15), (0, 15))) + 1e-9}[kind]()
    ny, nx = grid
    a = spectrum.amplitude(ring, ny, nx).astype(np.float64)
    assert a.shape == (ny, nx // 2 + 1) and np.all(np.isfinite(a)) and np.all(a >= 0) and a[0, 0] == 0.0
    weights = np.full(a.shape[1], 2.0)
    weights[0] = 1.0
    if nx % 2 == 0:
        weights[-1] = 1.0
    if ring.any():
        assert float((a * a).sum(axis=0) @ weights) / (ny * nx) == pytest.approx(1.0, rel=1e-4)


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 2 ** 31 - 1), st.floats(0.05, 0.95), st.integers(1, 8))
def test_any_region_and_values_read_as_the_judge_reads_them(seed, share, radius):
    rng = np.random.default_rng(seed)
    inside = rng.random((37, 53)) < share
    values = np.cumsum(rng.standard_normal((37, 53)), axis=1) * inside  # a grain along the rows
    values = np.where(inside, values - values[inside].mean(), 0.0)
    got = _pearson(values, inside, radius)
    judge = acf2d(values, inside, radius)
    lags = np.array(window(radius))
    pairs = np.array([np.count_nonzero(inside[:37 - dy, max(0, -dx):53 - max(0, dx)]
                                       & inside[dy:, max(0, dx):53 - max(0, -dx)]) for dy, dx in lags])
    read = np.isfinite(got) & (pairs >= 32)
    assert np.abs(got[read] - judge[read]).max(initial=0.0) < 1e-3
