"""Synthesis from models, and quantile-space interpolation between measured angles."""
import warnings

import numpy as np
import pytest

from btf.fit.fitter import fit_histogram
from btf.johnson import Family, Johnson
from tools.analysis import metrics, synth


def fit(values):
    return fit_histogram(np.bincount(values.ravel(), minlength=256)).model


def texture(angle, n, rng):
    """Grain brightness whose mean, spread and skew all drift smoothly with the view angle."""
    g = rng.gamma(2.0 + angle / 15.0, 6.0 + angle / 10.0, n)
    return np.clip(np.rint(40 + angle + g), 0, 255).astype(np.int64)


def test_region_histograms_match_their_models():
    rng = np.random.default_rng(0)
    mask = np.zeros((200, 250), np.uint8)
    mask[:, 125:] = 1
    models = {(0, 0): Johnson.normal(80, 12), (1, 0): Johnson(Family.SU, -1.0, 1.5, 150, 20)}
    img = synth.synthesize(mask, models, rng)
    assert img.shape == (200, 250, 1) and img.dtype == np.uint8
    for label in (0, 1):
        h = metrics.histogram(img[mask == label, 0], 256)
        p = models[(label, 0)].level_probabilities(256)
        assert metrics.hist_diff(h, p) < 0.06


def test_missing_labels_are_named():
    mask = np.array([[0, 3], [5, 0]], np.uint8)
    with pytest.raises(synth.MissingModels, match=r"\[3, 5\]"):
        synth.synthesize(mask, {(0, 0): Johnson.normal(10, 2)}, np.random.default_rng(0))


def test_interpolation_beats_nearest_angle_on_smooth_texture():
    rng = np.random.default_rng(3)
    n = 40000
    by_angle = {a: {(0, 0): fit(texture(a, n, rng))} for a in (0.0, 60.0)}
    truth = metrics.histogram(texture(30.0, n, rng), 256)
    mask = np.zeros((200, 200), np.uint8)
    interp = synth.synthesize_at(by_angle, mask, 30.0, np.random.default_rng(1))
    err_interp = metrics.hist_diff(metrics.histogram(interp, 256), truth)
    for a in (0.0, 60.0):
        near = synth.synthesize(mask, by_angle[a], np.random.default_rng(1))
        assert err_interp < 0.5 * metrics.hist_diff(metrics.histogram(near, 256), truth)


def test_interpolation_across_families_stays_in_range_and_between():
    lo = {(0, 0): Johnson(Family.SB, 0.5, 0.8, 10, 100)}
    hi = {(0, 0): Johnson(Family.SU, -0.5, 2.0, 150, 10)}
    mask = np.zeros((100, 100), np.uint8)
    out = synth.interpolate(lo, hi, 0.5, mask, np.random.default_rng(0))
    m_lo = synth.synthesize(mask, lo, np.random.default_rng(0)).mean()
    m_hi = synth.synthesize(mask, hi, np.random.default_rng(0)).mean()
    assert out.dtype == np.uint8
    assert min(m_lo, m_hi) < out.mean() < max(m_lo, m_hi)
    # Quantile blending moves the mean linearly with the weight.
    assert out.mean() == pytest.approx((m_lo + m_hi) / 2, abs=2.0)


def test_outside_measured_range_uses_nearest_with_a_warning():
    by_angle = {20.0: {(0, 0): Johnson.constant(7)}, 40.0: {(0, 0): Johnson.constant(9)}}
    mask = np.zeros((4, 4), np.uint8)
    with pytest.warns(synth.ExtrapolationWarning, match="outside the measured range"):
        out = synth.synthesize_at(by_angle, mask, 75.0, np.random.default_rng(0))
    assert (out == 9).all()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert (synth.synthesize_at(by_angle, mask, 20.0, np.random.default_rng(0)) == 7).all()


def test_neighbours_and_weights():
    assert synth.neighbours([0.0, 30.0, 60.0], 45.0) == (30.0, 60.0, 0.5)
    assert synth.neighbours([0.0, 30.0, 60.0], 30.0) == (30.0, 30.0, 0.0)
