"""Spike reads: a histogram with most of its pixels in one bin (a retina scan's black border) is
also read with that bin's mass in part of its width, so its curve keeps the tail beyond it."""
from __future__ import annotations

import numpy as np
import pytest
from skimage import data

from benchmarks.model_histograms import histogram_l1
from btf.codec import PercentileCodec
from btf.fit import histogram_fit
from btf.fit.fitter import FrameFitter, fit_histogram, fit_values
from btf.johnson import Family, Johnson
from btf.record import rebuild


@pytest.fixture(scope="module")
def border() -> np.ndarray:
    """The black border of scikit-image's retina scan (every other pixel), pixels x 3 bands:
    81-90% of each band at one level, with JPEG noise and the disc's rim as a tail."""
    img = data.retina()[::2, ::2]
    return img[img.astype(int).sum(axis=2) < 90]


def _without_spike_reads(monkeypatch, values: np.ndarray):
    with monkeypatch.context() as m:
        m.setattr(histogram_fit, "SPIKE_SHARE", 1.01)
        return fit_values(values)


def test_a_black_borders_curve_keeps_its_tail_and_halves_its_histogram_error(border, monkeypatch):
    for band in range(3):
        values = border[:, band]
        counts = np.bincount(values, minlength=256)
        assert counts.max() >= 0.8 * counts.sum()
        new, old = fit_values(values), _without_spike_reads(monkeypatch, values)
        err_new, err_old = histogram_l1(new.model, counts), histogram_l1(old.model, counts)
        assert err_new <= err_old
        if band != 1:  # green's plain read is already near (0.009)
            assert err_new <= 0.5 * err_old and err_new < 0.05, (band, err_old, err_new)
            above = counts[int(np.argmax(counts)) + 2:].sum() / counts.sum()  # the tail past the spike
            probs = np.diff(new.model.cdf(np.arange(-0.5, 256.5)))
            assert probs[int(np.argmax(counts)) + 2:].sum() == pytest.approx(above, abs=0.02)


def test_a_spike_read_travels_as_its_percentiles_and_the_host_rebuilds_the_same_model(border):
    codec = PercentileCodec.for_levels(256)
    for band in range(3):
        r = fit_values(border[:, band])
        assert rebuild(r, codec.decode(codec.encode(r.percentiles))) == r.model


def test_a_spiky_row_is_fitted_alike_alone_and_in_a_frames_batch(border):
    hists = [np.bincount(border[:, b], minlength=256) for b in range(3)]
    hists.append(np.bincount(np.random.default_rng(2).normal(120, 20, 5000).clip(0, 255).astype(int), minlength=256))
    f = FrameFitter(len(hists), 1)
    f.counts[:, 0, :] = np.stack(hists)
    batch = f.fit()
    for label, h in enumerate(hists):
        assert fit_histogram(h) == batch[(label, 0)]


@pytest.mark.parametrize("model", [Johnson(Family.SU, -0.6, 1.6, 110.0, 22.0),
                                   Johnson(Family.SB, 0.3, 0.9, 20.0, 200.0), Johnson.normal(128.0, 3.0)])
def test_histograms_without_a_spike_get_the_same_model_as_before(model, monkeypatch):
    values = model.sample_pixels(50_000, np.random.default_rng(4))
    counts = np.bincount(values, minlength=256)
    assert counts.max() < histogram_fit.SPIKE_SHARE * counts.sum()
    assert fit_values(values) == _without_spike_reads(monkeypatch, values)


def test_a_small_spiky_region_keeps_the_usual_reads(border, monkeypatch):
    """Under SPIKE_PIXELS the spike reads would chase counting noise."""
    values = border[::25, 0]  # about 4,700 pixels spread over the border
    assert np.bincount(values).max() >= histogram_fit.SPIKE_SHARE * values.size
    assert values.size < histogram_fit.SPIKE_PIXELS
    assert fit_values(values) == _without_spike_reads(monkeypatch, values)
