"""Skip rules: which labels are fitted, how much of a region is read, when a capture is unchanged."""
from dataclasses import dataclass

import numpy as np
import pytest

from onboard.capture import skip


@dataclass(frozen=True)
class R:
    percentiles: tuple[float, float, float, float]


def test_labels_absent_or_under_the_minimum_are_not_kept():
    labels = np.zeros((10, 10), np.uint8)
    labels[0, :5] = 2  # 5 pixels
    labels[5:, :] = 3  # 50 pixels
    counts = skip.label_counts(labels, 5)
    assert counts.tolist() == [45, 0, 5, 50, 0]
    assert skip.kept_labels(counts, 10) == (0, 3)
    assert skip.kept_labels(counts, 1) == (0, 2, 3)


def test_precision_sets_the_pixels_needed_and_the_stride():
    assert skip.pixels_for_precision(0.005) == 10_000
    counts = np.array([1_000_000, 40_000, 100])
    assert skip.subsample_stride(counts, (0, 1), 0.005) == 4
    # A small kept region forbids subsampling; 0 turns the rule off.
    assert skip.subsample_stride(counts, (0, 1, 2), 0.005) == 1
    assert skip.subsample_stride(counts, (0,), 0.0) == 1
    with pytest.raises(ValueError, match="precision"):
        skip.pixels_for_precision(0.7)


def test_stride_over_a_frame_visits_every_column_not_a_few():
    h, w = 600, 800
    counts = np.array([h * w])
    assert skip.subsample_stride(counts, (0,), 0.0125, width=1) == 300  # 1600 pixels needed
    stride = skip.subsample_stride(counts, (0,), 0.0125, width=w)
    assert stride == 299  # 300 shares factors with 800: the next smaller coprime stride
    cols = np.arange(0, h * w, stride) % w
    assert len(np.unique(cols)) == w and len(cols) >= 1600
    assert len(np.unique(np.arange(0, h * w, 300) % w)) == 8  # what 300 would have sampled


def test_strided_subsample_keeps_percentiles_within_the_target_precision():
    rng = np.random.default_rng(1)
    values = rng.gamma(2.0, 20.0, 1_000_000)
    stride = skip.subsample_stride(np.array([values.size]), (0,), 0.005)
    sub = values[::stride]
    for p in (5.8, 30, 70, 94.2):
        full = np.percentile(values, p)
        # The subsample's value at the full data's percentile: its CDF there is within 3 se.
        frac = np.mean(sub <= full)
        assert abs(frac - p / 100) < 3 * 0.005


def test_unchanged_needs_same_models_all_within_tolerance():
    a = {(0, 0): R((1.0, 2.0, 3.0, 4.0)), (0, 1): R((5.0, 6.0, 7.0, 8.0))}
    b = {(0, 0): R((1.2, 2.0, 3.1, 4.0)), (0, 1): R((5.0, 6.0, 7.0, 8.3))}
    assert skip.unchanged(a, b, 0.5)
    assert not skip.unchanged(a, b, 0.25)
    assert not skip.unchanged(a, {(0, 0): b[(0, 0)]}, 0.5)
    assert not skip.unchanged(None, b, 0.5)
    assert not skip.unchanged(a, a, 0.0)


def test_pose_key_pairs_nearby_commanded_poses():
    from hal.interfaces import ViewAngles
    assert skip.pose_key(ViewAngles(70.2, 360.0)) == skip.pose_key(ViewAngles(69.9, 0.0))
    assert skip.pose_key(ViewAngles(70, 0)) != skip.pose_key(ViewAngles(60, 0))
