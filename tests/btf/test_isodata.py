"""ISODATA: recovers blob structure, splits and merges as specified, never degenerates."""
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from btf.fit import isodata as I
from btf.fit.isodata import IsodataParams, Labeller, assign, isodata

CENTRES = np.array([[40, 40, 40], [200, 60, 60], [60, 200, 60], [60, 60, 200]], float)


def _blobs(centres, n=3000, std=6.0, seed=0):
    rng = np.random.default_rng(seed)
    return np.vstack([rng.normal(c, std, (n, len(c))) for c in centres])


def _matched(found, truth, tol):
    return all(np.linalg.norm(found - t, axis=1).min() < tol for t in truth)


@pytest.mark.parametrize("k", [2, 3, 4])
def test_recovers_k_when_data_has_k_clusters(k):
    x = _blobs(CENTRES[:k], seed=k)
    res = isodata(x, IsodataParams(k=k, seed=1))
    assert len(res.centres) == k
    assert _matched(res.centres, CENTRES[:k], 2.0)
    # every blob's points share one label
    per_blob = res.labels.reshape(k, -1)
    assert all(len(np.unique(row)) == 1 for row in per_blob)


def test_image_input_gives_image_shaped_uint8_labels():
    rng = np.random.default_rng(2)
    which = rng.integers(0, 4, (60, 80))
    img = np.clip(rng.normal(CENTRES[which], 5), 0, 255).astype(np.uint8)
    res = isodata(img, IsodataParams(k=4))
    assert res.labels.shape == (60, 80) and res.labels.dtype == np.uint8
    # labels agree with the true partition up to renaming
    for j in range(4):
        assert len(np.unique(res.labels[which == j])) == 1


def test_splits_a_cluster_holding_two_groups():
    x = _blobs(CENTRES[:2], seed=3)
    res = isodata(x, IsodataParams(k=2, init_clusters=1, split_std=10))
    assert len(res.centres) == 2 and _matched(res.centres, CENTRES[:2], 2.0)


def test_splits_an_elongated_cluster_along_its_long_axis():
    rng = np.random.default_rng(4)
    x = np.column_stack([rng.uniform(0, 200, 6000), rng.normal(100, 2, 6000), rng.normal(100, 2, 6000)])
    res = isodata(x, IsodataParams(k=2, init_clusters=1, split_std=20, merge_distance=10))
    assert len(res.centres) >= 2  # a uniform bar keeps splitting up to the 2k bound
    spread = np.ptp(res.centres, axis=0)
    assert spread[0] > 50 and spread[1] < 5 and spread[2] < 5


def test_unsplittable_cluster_is_left_alone():
    x = _blobs(CENTRES[:1], std=3, seed=5)
    res = isodata(x, IsodataParams(k=2, init_clusters=1, split_std=10))
    assert len(res.centres) == 1


def test_merges_two_close_clusters():
    close = np.array([[100, 100, 100], [106, 100, 100]], float)
    x = _blobs(close, std=2, seed=6)
    res = isodata(x, IsodataParams(k=1, init_clusters=2, merge_distance=10, split_std=50))
    assert len(res.centres) == 1
    np.testing.assert_allclose(res.centres[0], [103, 100, 100], atol=0.5)


def test_merge_respects_max_merges_per_iteration():
    c = np.array([[0.0, 0], [1, 0], [10, 0], [11, 0], [20, 0], [21, 0]])
    lab = np.repeat(np.arange(6), 10)
    p = IsodataParams(k=3, merge_distance=2, max_merges=2)
    merged = I._merge(c, lab, p)
    assert len(merged) == 4
    p0 = IsodataParams(k=3, merge_distance=2, max_merges=0)
    assert len(I._merge(c, lab, p0)) == 6


def test_small_clusters_are_dissolved():
    x = np.vstack([_blobs(CENTRES[:2], n=2000, seed=7), [[250.0, 250, 250]] * 5])
    res = isodata(x, IsodataParams(k=3, min_samples=20, split_std=15))
    assert len(res.centres) == 2


def test_deterministic_for_a_seed():
    x = _blobs(CENTRES, std=25, seed=8)
    a = isodata(x, IsodataParams(k=4, seed=11, subsample=3000))
    b = isodata(x, IsodataParams(k=4, seed=11, subsample=3000))
    np.testing.assert_array_equal(a.centres, b.centres)
    np.testing.assert_array_equal(a.labels, b.labels)


def test_constant_image_gives_one_finite_cluster():
    res = isodata(np.full((30, 40, 3), 9, np.uint8), IsodataParams(k=4))
    np.testing.assert_array_equal(res.centres, [[9, 9, 9]])
    assert np.all(res.labels == 0)


def test_fewer_pixels_than_k():
    x = np.array([[[0, 0, 0], [200, 200, 200]]], np.uint8)
    res = isodata(x, IsodataParams(k=5, min_samples=1, merge_distance=1))
    assert len(res.centres) == 2 and sorted(res.labels.ravel()) == [0, 1]


def test_lookup_table_assignment_matches_brute_force():
    rng = np.random.default_rng(9)
    img = rng.integers(0, 256, (150, 200, 3), dtype=np.uint8)
    for k in (2, 5, 9):
        c = rng.uniform(0, 255, (k, 3))
        brute = np.argmin(((img.reshape(-1, 1, 3) - c[None]) ** 2).sum(axis=2), axis=1)
        for bands in (1, 2, 3):
            got = assign(img[..., :bands], c[:, :bands]).ravel()
            ref = np.argmin(((img.reshape(-1, 1, 3)[..., :bands] - c[None, :, :bands]) ** 2).sum(axis=2), axis=1)
            assert (got != ref).mean() < 1e-4  # float32 rounding at exact ties only
        assert (assign(img, c).ravel() != brute).mean() < 1e-4


def test_sixteen_bit_and_multiband_data_use_the_general_path():
    rng = np.random.default_rng(10)
    x = np.vstack([rng.normal(c, 50, (500, 5)) for c in ([1000] * 5, [30000] * 5)]).clip(0, 65535)
    res = isodata(x.astype(np.uint16), IsodataParams(k=2, split_std=500, merge_distance=100))
    assert len(res.centres) == 2
    assert np.all(res.labels[:500] == res.labels[0]) and np.all(res.labels[500:] != res.labels[0])


def test_bad_input_names_the_problem():
    with pytest.raises(ValueError, match="NaN"):
        isodata(np.array([[1.0, np.nan]]))
    with pytest.raises(ValueError, match="non-empty"):
        isodata(np.zeros((0, 3)))
    with pytest.raises(ValueError, match="k must be"):
        IsodataParams(k=0)
    with pytest.raises(ValueError, match="centres shape"):
        assign(np.zeros((4, 3)), np.zeros((2, 2)))


@settings(max_examples=40, deadline=None)
@given(
    arrays(np.uint8, st.tuples(st.integers(1, 12), st.integers(1, 12), st.integers(1, 3))),
    st.integers(1, 6),
    st.integers(1, 30),
    st.integers(0, 2**16),
)
def test_never_nan_never_empty_labels_in_range(data, k, min_samples, seed):
    res = isodata(data, IsodataParams(k=k, min_samples=min_samples, seed=seed, split_std=5, merge_distance=8))
    assert np.all(np.isfinite(res.centres)) and 1 <= len(res.centres) <= 2 * k
    counts = np.bincount(res.labels.ravel(), minlength=len(res.centres))
    assert len(counts) == len(res.centres) and np.all(counts > 0)
    assert res.centres.min() >= data.min() and res.centres.max() <= data.max()


def test_the_labellers_colour_table_gives_every_frame_layout_the_brute_force_labels():
    rng = np.random.default_rng(11)
    img = rng.integers(0, 256, (120, 90, 3), dtype=np.uint8)
    c = rng.uniform(0, 255, (6, 3))
    brute = np.argmin(((img.reshape(-1, 1, 3) - c[None]) ** 2).sum(axis=2), axis=1).reshape(img.shape[:2])
    names = np.array([5, 3, 9, 0, 1, 7], np.uint8)
    lab = Labeller(c, names)
    for frame in (img, img[:, ::-1], img[::2, 1::3], img[:1, :1], np.ascontiguousarray(img[:, :1])):
        want = names[np.argmin(((frame.reshape(-1, 1, 3) - c[None]) ** 2).sum(axis=2), axis=1)]
        got = lab.assign(frame)
        assert got.shape == frame.shape[:2]
        assert (got.ravel() != want).mean() < 1e-3  # float32 rounding at exact ties only
    assert (lab.assign(img) != names[brute]).mean() < 1e-3
    # the last pixel is read on its own (its word would run past the frame): a colour of its own
    edge = img.copy()
    edge[-1, -1] = np.round(c[2]).astype(np.uint8)
    assert lab.assign(edge)[-1, -1] == names[2]
