"""A region's record (btf.dependence) and its measurement on board (btf.fit.dependence)."""
from __future__ import annotations

import numpy as np
import pytest

from btf.dependence import LAGS, MAX_RADIUS, RADIUS, Dependence, window, window_size
from btf.fit import anchors
from btf.fit import dependence as onboard
from btf.fit.dependence import MAX_ANCHORS, MIN_PAIRS, measure, observed
from btf.fit.fitter import FrameFitter
from btf.johnson import Johnson


def _fits(image: np.ndarray, labels: np.ndarray):
    f = FrameFitter(int(labels.max()) + 1, image.shape[2], bins=256)
    f.add(image, labels)
    return {k: r.model for k, r in f.fit(min_count=64).items()}, f


def _diagonal_field(h: int, w: int, phi: float, seed: int) -> np.ndarray:
    """Unit-variance field whose grain runs down the diagonal: r(k, k) = phi^k, r(0, 1) =
    r(1, 0) = r(1, -1) = 0 (each row the row above shifted one pixel right, plus noise)."""
    e = np.random.default_rng(seed).standard_normal((h, w))
    f = np.empty_like(e)
    f[0] = e[0]
    for y in range(1, h):
        f[y] = phi * np.roll(f[y - 1], 1) + np.sqrt(1 - phi ** 2) * e[y]
    return f


def _image(h: int, w: int, phi: float, mix: float, seed: int) -> np.ndarray:
    """Three bands: two sharing the diagonal field (correlation `mix`), one independent white."""
    a, b = _diagonal_field(h, w, phi, seed), _diagonal_field(h, w, phi, seed + 1)
    white = np.random.default_rng(seed + 2).standard_normal((h, w))
    z = np.stack([a, mix * a + np.sqrt(1 - mix ** 2) * b, white], axis=-1)
    return np.clip(np.rint(120 + 25 * z), 0, 255).astype(np.uint8)


def _at(dep: Dependence, lag: tuple[int, int], row: int = 0) -> float:
    return dep.acf[row][window(dep.radius).index(lag)]


def test_window_is_the_half_plane_in_record_order():
    lags = window(2)
    assert len(lags) == window_size(2) == 12
    assert lags[:2] == ((0, 1), (0, 2)) and lags[2:7] == ((1, -2), (1, -1), (1, 0), (1, 1), (1, 2))
    assert not set(lags) & {(-dy, -dx) for dy, dx in lags}  # no lag with its mirror


def test_a_diagonal_grain_is_measured_diagonally_not_as_a_product_of_rows_and_columns():
    img = _image(240, 300, phi=0.8, mix=0.7, seed=1)
    labels = np.zeros(img.shape[:2], np.uint8)
    models, _ = _fits(img, labels)
    dep = measure(img, labels, models, per_band=True)[0]
    assert dep.radius == RADIUS and len(dep.acf) == 3
    for band in (0, 1):
        assert _at(dep, (1, 1), band) == pytest.approx(0.8, abs=0.05)
        assert _at(dep, (2, 2), band) == pytest.approx(0.64, abs=0.06)
        for lag in ((0, 1), (1, 0), (1, -1)):
            assert abs(_at(dep, lag, band)) < 0.06  # a separable product would need these near 0.9
    assert max(abs(v) for v in dep.acf[2]) < 0.06  # the white band has no grain
    assert dep.corr == pytest.approx([0.7, 0.0, 0.0], abs=0.05)
    shared = measure(img, labels, models, per_band=False)[0]
    assert len(shared.acf) == 1 and _at(shared, (1, 1)) == pytest.approx(np.mean([_at(dep, (1, 1), b) for b in range(3)]))


def test_regions_are_measured_apart_and_pairs_never_cross_a_border():
    img = _image(120, 160, phi=0.9, mix=0.0, seed=2)
    noise = np.random.default_rng(3).integers(90, 160, size=img.shape, dtype=np.uint8)
    labels = np.zeros(img.shape[:2], np.uint8)
    labels[:, 80:] = 1
    img[:, 80:] = noise[:, 80:]
    models, _ = _fits(img, labels)
    deps = measure(img, labels, models, per_band=True)
    assert _at(deps[0], (1, 1), 0) > 0.8
    assert max(abs(v) for v in deps[1].acf[0]) < 0.08  # white noise region: no grain borrowed


def test_constant_band_and_tiny_frames_report_independence_not_nan():
    img = np.full((40, 40, 2), 7, dtype=np.uint8)
    img[..., 1] = np.random.default_rng(4).integers(0, 255, size=(40, 40))
    labels = np.zeros((40, 40), np.uint8)
    models, _ = _fits(img, labels)
    dep = measure(img, labels, models)[0]
    assert dep.corr == (0.0,) and all(np.isfinite(dep.acf[0]))
    tiny = measure(img[:5, :9], labels[:5, :9], models)[0]  # narrower than one window
    assert tiny.corr == (0.0,) and set(tiny.acf[0]) == {0.0}
    assert tiny.unmeasured == (tuple(range(window_size(RADIUS))),)  # no pair at all: nothing measured


def test_an_anchor_budget_bounds_the_work_but_keeps_the_estimate():
    img = _image(200, 240, phi=0.8, mix=0.5, seed=5)
    labels = np.zeros(img.shape[:2], np.uint8)
    models, _ = _fits(img, labels)
    dep = measure(img, labels, models, max_anchors=2048, chunk=256, per_band=False)[0]
    assert _at(dep, (1, 1)) == pytest.approx(np.mean([0.8, 0.8, 0.0]), abs=0.06)


def test_bands_keep_their_own_rows_only_when_their_grains_differ():
    img = _image(160, 200, phi=0.8, mix=0.7, seed=7)
    labels = np.zeros(img.shape[:2], np.uint8)
    models, _ = _fits(img, labels)
    apart = measure(img, labels, models)[0]  # the white band's grain is far from the others'
    assert len(apart.acf) == 3 and _at(apart, (1, 1), 0) > 0.7 and abs(_at(apart, (1, 1), 2)) < 0.06
    alike = np.repeat(img[..., :1], 3, axis=2)  # three copies of one band: one row says it all
    models, _ = _fits(alike, labels)
    shared = measure(alike, labels, models)[0]
    assert len(shared.acf) == 1 and _at(shared, (1, 1)) == pytest.approx(_at(apart, (1, 1), 0), abs=0.02)


def test_observed_levels_are_the_regions_lowest_and_highest_per_band():
    rng = np.random.default_rng(6)
    img = rng.integers(40, 200, (60, 80, 3), dtype=np.uint8)
    labels = np.zeros((60, 80), np.uint8)
    labels[:, 40:] = 2
    img[:, 40:, 1] = np.clip(img[:, 40:, 1], 90, 95)
    _, f = _fits(img, labels)
    seen = observed(f.counts, f.centre0, f.bin_width)
    assert set(seen) == {0, 2}
    for lab, cols in ((0, slice(0, 40)), (2, slice(40, 80))):
        region = img[:, cols].reshape(-1, 3)
        assert seen[lab] == (tuple(region.min(axis=0).tolist()), tuple(region.max(axis=0).tolist()))


def test_observed_levels_of_binned_16_bit_histograms_cover_every_pixel():
    rng = np.random.default_rng(7)
    img = rng.integers(3000, 9000, (50, 50, 1), dtype=np.uint16)
    f = FrameFitter(1, 1, bins=4096, value_range=(-0.5, 65535.5))
    f.add(img, np.zeros((50, 50), np.uint8))
    (lo,), (hi,) = observed(f.counts, f.centre0, f.bin_width, 65536)[0]
    assert lo <= img.min() < lo + 16 and hi - 16 < img.max() <= hi


def test_measure_carries_the_observed_levels_it_is_given():
    img = _image(64, 64, 0.5, 0.5, seed=8)
    labels = np.zeros((64, 64), np.uint8)
    models, f = _fits(img, labels)
    seen = observed(f.counts, f.centre0, f.bin_width)
    dep = measure(img, labels, models, levels_seen=seen)[0]
    assert (dep.lo, dep.hi) == seen[0] and dep.measured


def test_the_older_layout_becomes_its_separable_window():
    dep = Dependence.from_lags((0.5, 0.2, 0.1), (0.9, 0.7, 0.5, 0.25), (0.8, 0.6, 0.4, 0.2))
    assert dep.radius == MAX_RADIUS
    for k, lag in enumerate(LAGS):
        assert _at(dep, (0, lag)) == pytest.approx((0.9, 0.7, 0.5, 0.25)[k])
        assert _at(dep, (lag, 0)) == pytest.approx((0.8, 0.6, 0.4, 0.2)[k])
    assert _at(dep, (2, -4)) == pytest.approx(0.6 * 0.5)
    assert _at(dep, (0, 3)) == pytest.approx(0.7 * (0.5 / 0.7) ** 0.5)  # geometric between lags 2 and 4


@pytest.mark.parametrize("kwargs, reason", [
    ({"corr": (0.5,), "acf": ((0.1,) * 84,), "radius": 6, "lo": (0,), "hi": (9,)}, "bands"),
    ({"corr": (0.5,), "acf": ((0.0,) * 84,), "unmeasured": ((3,), (4,))}, "one entry per acf row"),
    ({"corr": (0.5,), "acf": ((0.0,) * 84,), "unmeasured": ((5, 3),)}, "increasing window indices"),
    ({"corr": (0.5,), "acf": ((0.0,) * 84,), "unmeasured": ((84,),)}, "increasing window indices"),
    ({"corr": (0.5,), "acf": ((0.1,) * 84,), "unmeasured": ((3,),)}, "must hold 0.0"),
    ({"lo": (1,), "hi": (9,), "unmeasured": ((3,),)}, "one entry per acf row"),
    ({"corr": (1.5,), "acf": ((0.1,) * 84,)}, r"\[-1, 1\]"),
    ({"corr": (0.5,), "acf": ((0.1,) * 83,)}, "rows of 84 lags"),
    ({"corr": (0.5,), "acf": ((0.1,) * 84,), "radius": 9}, "radius"),
    ({"lo": (5,), "hi": (4,)}, "lo <= hi"),
    ({}, "neither"),
    ({"corr": (0.5,)}, "both"),
])
def test_an_inconsistent_record_is_refused_with_a_reason(kwargs, reason):
    with pytest.raises(ValueError, match=reason):
        Dependence(**kwargs)


def test_dependence_memory_does_not_grow_with_the_frame():
    import tracemalloc

    def peak(n):
        rng = np.random.default_rng(0)
        img = rng.integers(0, 256, (n, n, 3), dtype=np.uint8)
        labels = np.zeros((n, n), np.uint8)
        models = {(0, b): Johnson.normal(128.0, 70.0) for b in range(3)}
        measure(img[:64, :64], labels[:64, :64], models)
        tracemalloc.start()
        measure(img, labels, models)
        _, top = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        return top

    assert peak(1500) <= 1.2 * peak(400) + 200_000


def test_band_correlations_read_every_phase_of_a_two_by_two_mosaic():
    """A sensor's 2x2 mosaic (or JPEG's 8x8 blocks) gives each phase its own band statistics; a
    lattice of even step reads one phase only. The step is odd, and `corr_points` covering the
    frame reads every pixel."""
    rng = np.random.default_rng(8)
    base = rng.normal(128, 20, (240, 240))
    img = np.stack([base, base, rng.normal(128, 20, (240, 240))], axis=-1)
    img[::2, ::2, 1] = rng.normal(128, 20, (120, 120))  # one phase of four: green independent of red
    img = np.clip(np.rint(img), 0, 255).astype(np.uint8)
    labels = np.zeros(img.shape[:2], np.uint8)
    models, _ = _fits(img, labels)
    every = np.corrcoef(img.reshape(-1, 3).T.astype(np.float64))[0, 1]  # about 0.75
    for points in (240 * 240 // 16, 240 * 240 // 36):  # steps 4 and 6 before they were made odd
        lattice = measure(img, labels, models, corr_points=points)[0]
        assert lattice.corr[0] == pytest.approx(every, abs=0.05)
    whole = measure(img, labels, models, corr_points=240 * 240)[0]
    assert whole.corr[0] == pytest.approx(every, abs=1e-6)


def _scattered(h: int, w: int, share: float, seed: int) -> np.ndarray:
    """Blobs over the whole frame, about `share` of the pixels (the peaks of a smooth noise): as
    the moon's smallest k-means class, 2,412 pixels in 57 blobs over 512 x 512."""
    e = np.random.default_rng(seed).standard_normal((h, w))
    fy, fx = np.fft.fftfreq(h)[:, None], np.fft.fftfreq(w)[None, :]
    s = np.fft.ifft2(np.fft.fft2(e) * np.exp(-50 * np.pi ** 2 * (fy ** 2 + fx ** 2))).real  # sigma 5
    return s >= np.quantile(s, 1 - share)


def _all_pairs(values: np.ndarray, inside: np.ndarray, radius: int) -> np.ndarray:
    """Pearson correlation over every pixel pair of the region at each window lag."""
    out = []
    h, w = values.shape
    for dy, dx in window(radius):
        a = (slice(0, h - dy), slice(max(0, -dx), w - max(0, dx)))
        b = (slice(dy, h), slice(max(0, dx), w - max(0, -dx)))
        both = inside[a] & inside[b]
        out.append(np.corrcoef(values[a][both], values[b][both])[0, 1])
    return np.array(out)


@pytest.fixture(scope="module")
def specks():
    """A 512 x 512 gray frame of the diagonal grain, a large region and 2,400 scattered pixels
    (label 2) of the same grain, as the moon's smallest k-means class."""
    img = _image(512, 512, phi=0.8, mix=0.0, seed=11)[..., :1]
    labels = np.zeros((512, 512), np.uint8)
    labels[_scattered(512, 512, 2400 / 512 ** 2, seed=12)] = 2
    models, _ = _fits(img, labels)
    return img, labels, models


def test_a_small_scattered_region_gets_enough_pairs_and_every_pairs_grain(specks, monkeypatch):
    img, labels, models = specks
    truth = _all_pairs(img[..., 0].astype(np.float64), labels == 2, RADIUS)
    dep = measure(img, labels, models, sparse_budget=MAX_ANCHORS // 2)[2]  # btf-host fit's share
    assert dep.unmeasured == ()
    assert np.abs(np.array(dep.acf[0]) - truth).max() < 0.1
    assert _at(dep, (1, 1)) == pytest.approx(0.8, abs=0.1)
    robot = measure(img, labels, models)[2]  # an eighth of the anchors: coarser, every lag measured
    assert robot.unmeasured == () and np.abs(np.array(robot.acf[0]) - truth).max() < 0.2
    monkeypatch.setattr(onboard, "SPARSE_PAIRS", 0)  # the lattice alone, as before the second pass
    alone = measure(img, labels, models)[2]
    assert len(alone.unmeasured[0]) > 10  # lags of fewer than MIN_PAIRS pairs
    assert np.abs(np.array(alone.acf[0]) - truth).max() > 0.3


def test_large_regions_come_out_exactly_as_without_the_second_pass(specks, monkeypatch):
    img, labels, models = specks
    with_pass = measure(img, labels, models, per_band=True)
    monkeypatch.setattr(onboard, "SPARSE_PAIRS", 0)
    assert measure(img, labels, models, per_band=True)[0] == with_pass[0]


def test_a_budget_thin_over_large_regions_runs_no_second_pass(monkeypatch):
    img = _image(240, 320, phi=0.8, mix=0.5, seed=14)
    labels = (np.arange(240)[:, None] * 4 // 240 * 4 + np.arange(320)[None, :] * 4 // 320).astype(np.uint8)
    models, _ = _fits(img, labels)

    def refuse(*args):
        raise AssertionError("a second pass ran")

    monkeypatch.setattr(onboard, "_points", refuse)
    deps = measure(img, labels, models, max_anchors=512)  # 32 anchors a region, 16 of the second pass's
    assert len(deps) == 16 and all(np.all(np.isfinite(d.acf)) for d in deps.values())


def test_several_sparse_regions_and_signed_labels_share_the_second_pass():
    img = _image(512, 512, phi=0.8, mix=0.0, seed=11)[..., :1]
    labels = np.zeros((512, 512), np.int32)
    for lab, seed in ((2, 12), (3, 15), (4, 16)):
        labels[_scattered(512, 512, 1000 / 512 ** 2, seed)] = lab  # together within the budget
    labels[:, :40] = -1  # unlabelled pixels, never a region
    unsigned = np.where(labels < 0, 9, labels).astype(np.uint8)
    models = {k: m for k, m in _fits(img, unsigned)[0].items() if k[0] != 9}
    deps = measure(img, labels, models, sparse_budget=MAX_ANCHORS // 2)
    for lab in (2, 3, 4):
        truth = _all_pairs(img[..., 0].astype(np.float64), labels == lab, RADIUS)
        assert deps[lab].unmeasured == () and np.abs(np.array(deps[lab].acf[0]) - truth).max() < 0.1
    assert measure(img, unsigned, models, sparse_budget=MAX_ANCHORS // 2) == deps


def test_the_second_pass_keeps_to_its_budget_and_off_the_lattice(specks, monkeypatch):
    img, labels, models = specks
    seen = []
    points = onboard._points
    monkeypatch.setattr(onboard, "_points", lambda sums, data, lab, ys, xs, *rest: seen.append(
        (ys.copy(), xs.copy())) or points(sums, data, lab, ys, xs, *rest))
    measure(img, labels, models, max_anchors=2048)
    ys, xs = np.concatenate([y for y, _ in seen]), np.concatenate([x for _, x in seen])
    assert 0 < len(ys) <= 1024 and len(set(zip(ys.tolist(), xs.tolist()))) == len(ys)
    assert np.all(labels[ys, xs] == 2)  # only the sparse region's own pixels
    lattice = {(int(y), c + RADIUS + k * (2 * RADIUS + 1)) for rows, c, nx in anchors.lattice(512, 512, RADIUS, 2048)
               for y in rows for k in range(nx)}
    assert not lattice & set(zip(ys.tolist(), xs.tolist()))
    assert anchors.on_lattice(np.array([p[0] for p in lattice]), np.array([p[1] for p in lattice]),
                               anchors.lattice(512, 512, RADIUS, 2048), RADIUS).all()


def test_the_pixels_read_for_one_region_stay_within_their_cap_and_the_frame():
    labels = np.full((200, 300), 2, np.uint8)
    index = np.array([-1, -1, 0, -1])
    found = anchors._candidates(labels, index, np.array([0]), np.array([1.0]), RADIUS, 500, np.random.default_rng(0))
    ys, xs = np.divmod(found[0], 300)
    assert 100 < len(ys) <= 500 and len(set(found[0].tolist())) == len(ys)
    assert ys.max() < 200 - RADIUS and RADIUS <= xs.min() and xs.max() < 300 - RADIUS


def test_the_smallest_regions_keep_all_their_pixels_when_the_budget_is_shared():
    shares = anchors.shares(np.array([0, 100, 5000, 40000]), 3000)
    assert shares.tolist() == [0.0, 100.0, 1450.0, 1450.0]


def test_lags_with_too_few_pairs_are_unmeasured_not_independent():
    img = _image(120, 160, phi=0.8, mix=0.0, seed=13)[..., :1]
    labels = np.ones((120, 160), np.uint8)
    labels[:, 40:43] = 0  # a strip three pixels wide: no pair at |dx| >= 3
    models, _ = _fits(img, labels)
    dep = measure(img, labels, models)[0]
    gaps = {window(RADIUS)[k] for k in dep.unmeasured[0]}
    assert gaps == {(dy, dx) for dy, dx in window(RADIUS) if abs(dx) >= 3}
    assert all(dep.acf[0][k] == 0.0 for k in dep.unmeasured[0])
    assert _at(dep, (1, 1)) == pytest.approx(0.8, abs=0.1) and np.all(np.isfinite(dep.acf[0]))
    assert MIN_PAIRS > 0 and dep.known(0).sum() == window_size(RADIUS) - len(gaps)


def test_a_record_keeps_its_unmeasured_lags_through_rows_with_gaps_and_new_levels():
    acf = tuple(0.0 if k in (2, 40) else 0.5 for k in range(84))
    dep = Dependence((0.3,), (acf,), 6, unmeasured=((2, 40),))
    rows = dep.acf_rows()
    assert rows[0][2] is None and rows[0][40] is None and rows[0][0] == 0.5
    assert Dependence.from_rows((0.3,), rows, 6) == dep
    assert dep.with_levels((1, 2), (9, 9)).unmeasured == ((2, 40),)
    assert Dependence((0.3,), (acf,), 6, unmeasured=((),)) == Dependence((0.3,), (acf,), 6)  # none: ()
