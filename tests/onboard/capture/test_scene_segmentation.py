"""Scene-level ISODATA: centres fitted once per scene, exact table labelling, drift refits."""
import numpy as np
import pytest

from btf.fit.features import FeatureSpace, FeatureSpec, compute
from btf.fit.isodata import IsodataParams, Labeller, assign, fit_centres, spread
from onboard.capture.segmentation import Segmenter, SegmentMethod

CLUTTER = np.array([[194, 178, 128], [86, 125, 70], [112, 84, 62], [150, 150, 140]], float)


def _frame(seed, clutter=CLUTTER, side=96):
    rng = np.random.default_rng(seed)
    truth = np.kron(rng.integers(0, len(clutter), (6, 6)), np.ones((side // 6, side // 6), np.int64))
    img = clutter[truth] + rng.normal(0, 9, (side, side, 3))
    return np.clip(img, 0, 255).astype(np.uint8), truth


def _brute(x, c):
    return np.argmin(((x.reshape(-1, 1, x.shape[-1]).astype(float) - c[None]) ** 2).sum(axis=2), axis=1)


def test_two_level_table_matches_brute_force_where_centres_are_close():
    # Close centres put many colour cells on a decision boundary: the exact sub-tables decide.
    rng = np.random.default_rng(4)
    img = rng.integers(90, 170, (120, 160, 3), dtype=np.uint8)
    c = rng.uniform(100, 160, (9, 3))
    got = Labeller(c).assign(img).ravel()
    assert (got != _brute(img, c)).mean() < 1e-4  # float32 rounding at exact ties only


def test_names_are_written_instead_of_centre_indices():
    img, _ = _frame(1)
    c = fit_centres(img.reshape(-1, 3).astype(float), IsodataParams(k=4, split_std=20, merge_distance=25))
    names = (np.arange(len(c)) * 3 + 7).astype(np.uint8)
    np.testing.assert_array_equal(Labeller(c, names).assign(img), names[assign(img, c)])
    for bands in (1, 2):
        np.testing.assert_array_equal(Labeller(c[:, :bands], names).assign(img[..., :bands]),
                                      names[assign(img[..., :bands], c[:, :bands])])


def test_spread_is_the_mean_distance_to_the_nearest_centre():
    x = np.array([[0.0, 0.0], [3.0, 4.0], [10.0, 0.0]])
    assert spread(x, np.array([[0.0, 0.0], [10.0, 0.0]])) == pytest.approx(5.0 / 3)


def _segmenter(drift=0.25):
    params = IsodataParams(k=4, split_std=12, merge_distance=25, subsample=4000)
    return Segmenter(SegmentMethod.ISODATA, n_labels=16, isodata=params, refit_drift=drift)


def _feats(img):
    return compute(img, FeatureSpec(FeatureSpace.RGB))


def test_centres_are_fitted_once_per_scene_and_labels_stay_consistent():
    seg = _segmenter()
    first, truth1 = _frame(1)
    second, truth2 = _frame(2)  # same clutter types, another view of them
    lab1 = seg.labels_for(_feats(first))
    lab2 = seg.labels_for(_feats(second))
    assert seg.refits == 1
    # Each clutter type keeps its palette label from view to view.
    for t in range(4):
        assert np.bincount(lab1[truth1 == t]).argmax() == np.bincount(lab2[truth2 == t]).argmax()
    # Reused centres still label the second view as well as the first was labelled.
    for lab, truth in ((lab1, truth1), (lab2, truth2)):
        dominant = [np.bincount(lab[truth == t]).argmax() for t in range(4)]
        assert len(set(dominant)) == 4
        assert np.mean([(lab[truth == t] == dominant[t]).mean() for t in range(4)]) > 0.95


def test_a_view_the_centres_no_longer_fit_is_refitted():
    seg = _segmenter()
    seg.labels_for(_feats(_frame(1)[0]))
    other = np.array([[20, 20, 230], [230, 20, 20], [20, 230, 230], [240, 240, 20]], float)
    img, truth = _frame(3, other)
    lab = seg.labels_for(_feats(img))
    assert seg.refits == 2
    assert len(seg.palette.entries) >= 6  # new clutter types became new palette entries
    for t in range(4):  # every new type has a label of its own
        assert (lab[truth == t] == np.bincount(lab[truth == t]).argmax()).mean() > 0.95


def test_zero_drift_refits_every_frame_and_new_scene_forces_a_refit():
    seg = _segmenter(drift=0)
    img = _feats(_frame(1)[0])
    seg.labels_for(img)
    seg.labels_for(img)
    assert seg.refits == 2
    seg = _segmenter()
    seg.labels_for(img)
    seg.new_scene()
    seg.labels_for(img)
    assert seg.refits == 2


def test_bad_refit_settings_are_refused():
    with pytest.raises(ValueError, match="refit_drift"):
        Segmenter(SegmentMethod.ISODATA, refit_drift=-1)
    with pytest.raises(ValueError, match="scene_change"):
        Segmenter(SegmentMethod.ISODATA, scene_change=0)
