"""The feature-space criterion robot and host share (btf.fit.space_choice)."""
from __future__ import annotations

import numpy as np
import pytest

from btf.fit.fitter import FrameFitter
from btf.fit.space_choice import MARGIN, SpaceFigures, choose, decorrelation, draw_error, figures
from btf.johnson import Johnson


def fig(space, error, noise, decor, bands=3):
    return SpaceFigures(space, (error - noise / 2, error + noise / 2), decor, bands)


def test_a_space_that_decorrelates_wins_when_its_error_is_within_rgbs_noise():
    c = choose([fig("rgb", 0.10, 0.01, 0.95), fig("pca", 0.105, 0.0, 0.30), fig("hsv", 0.2, 0.0, 0.1)])
    assert c.space == "pca"  # hsv decorrelates more but its error is beyond rgb's + noise
    assert c.admissible == ("rgb", "pca")
    assert "0.30" in c.reason and "0.95" in c.reason


def test_rgb_stays_when_no_space_saves_the_margin():
    c = choose([fig("rgb", 0.10, 0.01, 0.50), fig("pca", 0.10, 0.0, 0.50 - MARGIN / 2)])
    assert c.space == "rgb"


def test_gray_is_never_chosen_for_colour_and_is_the_only_choice_for_one_band():
    assert choose([fig("rgb", 0.3, 0.0, 0.9), fig("gray", 0.01, 0.0, 0.0, bands=1)]).space == "rgb"
    assert choose([fig("gray", 0.2, 0.0, 0.0, bands=1)]).space == "gray"
    with pytest.raises(ValueError):
        choose([])


def test_decorrelation_is_the_worst_band_correlation_within_a_region():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(64, 64))
    bands = np.stack([a, a + 0.5 * rng.normal(size=a.shape), rng.normal(size=a.shape)], axis=2)
    labels = np.zeros((64, 64), np.uint8)
    labels[:, 32:] = 1
    bands[:, 32:, 1] = rng.normal(size=(64, 32))  # region 1: the bands are independent
    want = max(abs(np.corrcoef(bands[labels == lab].T)[i, j]) for lab in (0, 1) for i in range(3)
               for j in range(i + 1, 3))
    assert decorrelation(bands, labels) == pytest.approx(want, abs=1e-9)
    assert decorrelation(bands[..., :1], labels) == 0.0


def test_the_draw_error_is_small_for_a_model_of_its_own_data_and_large_for_a_wrong_one():
    rng = np.random.default_rng(2)
    values = np.clip(np.rint(rng.normal(120, 15, 50000)), 0, 255).astype(np.int64)
    counts = np.bincount(values, minlength=256)
    own = draw_error(counts, Johnson.normal(120, 15), 256, np.random.default_rng(0))
    wrong = draw_error(counts, Johnson.normal(60, 15), 256, np.random.default_rng(0))
    assert own < 0.1 < 1.5 < wrong


def test_figures_draw_at_two_seeds_and_a_deep_band_is_scored_over_few_bins():
    rng = np.random.default_rng(3)
    frame = np.clip(rng.normal(30000, 3000, (48, 48, 1)), 0, 65535).astype(np.uint16)
    labels = np.zeros((48, 48), np.uint8)
    fitter = FrameFitter(1, 1, bins=65536)
    fitter.add(frame, labels)
    models = {k: r.model for k, r in fitter.fit().items()}
    f = figures("gray", frame, labels, fitter.counts, models, 65536, seed=5)
    assert f.table2[0] != f.table2[1]
    assert 0.0 < f.error < 0.5  # per level, 2304 pixels over thousands of levels would score near 2
