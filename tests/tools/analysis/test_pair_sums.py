"""The host's grain over every pixel pair (tools.analysis.pair_sums), against a loop over the
pairs themselves, through `measure`, and through `btf-host fit` on a photograph."""
from __future__ import annotations

import json

import numpy as np
from skimage import data

from btf.dependence import window
from btf.fit.dependence import measure
from btf.fit.fitter import FrameFitter
from tools.analysis import pair_sums
from tools.data.images import write_image, write_mask


def _frame(h: int = 61, w: int = 47, bands: int = 2, seed: int = 3):
    rng = np.random.default_rng(seed)
    base = rng.integers(0, 256, (h + 2, w + 2, bands)).astype(np.float64)
    smooth = (base[:-2, :-2] + base[1:-1, 1:-1] + base[2:, 2:] + base[2:, :-2]) / 4  # a diagonal grain
    labels = np.zeros((h, w), np.uint8)
    labels[h // 3:, : w // 2] = 1
    labels[rng.random((h, w)) < 0.15] = 2  # scattered specks over the whole frame
    return smooth.astype(np.uint8), labels


def _brute(img, labels, lab, centre, radius, anchor_rows=None):
    """The sums of `every_pair`, pair by pair (anchors limited to `anchor_rows` when given)."""
    h, w, n_bands = img.shape
    positions = (radius + 1) * (2 * radius + 1)
    side, partner = np.zeros((1 + 2 * n_bands, positions)), np.zeros((3, n_bands, positions))
    v = img.astype(np.float64) - centre
    ys, xs = np.nonzero(labels == lab)
    keep = np.ones(ys.size, bool) if anchor_rows is None else np.isin(ys, anchor_rows)
    for y, x in zip(ys[keep], xs[keep]):
        for p in range(positions):
            dy, dx = divmod(p, 2 * radius + 1)
            dx -= radius
            py, px = y + dy, x + dx
            if 0 <= py < h and 0 <= px < w and labels[py, px] == lab:
                a, b = v[y, x], v[py, px]
                side[0, p] += 1
                side[1:1 + n_bands, p] += a
                side[1 + n_bands:, p] += a * a
                partner[:, :, p] += (b, a * b, b * b)
    return side, partner


def test_the_sums_are_those_of_every_pair_of_each_region():
    img, labels = _frame()
    centre = np.array([[100.0, 120.0], [90.0, 80.0], [128.0, 128.0]])
    side, partner = pair_sums.every_pair(img, labels, [0, 1, 2], centre, 3)
    for j in range(3):
        want_side, want_partner = _brute(img, labels, j, centre[j], 3)
        np.testing.assert_allclose(side[:, j], want_side, rtol=1e-5, atol=1e-3)
        np.testing.assert_allclose(partner[:, :, j], want_partner, rtol=1e-5, atol=1e-3)


def test_a_large_box_is_read_as_blocks_of_anchor_rows_each_with_all_its_partners(monkeypatch):
    img, labels = _frame(h=90, w=40)
    monkeypatch.setattr(pair_sums, "BLOCK_PIXELS", 1200)  # 3,600 pixels: blocks needed
    blocks = pair_sums._blocks(90, 40, 3)
    assert len(blocks) > 1 and sum(b.stop - b.start for b in blocks) * 40 <= 1200
    assert all(b.stop - b.start >= 12 and 0 <= b.start < b.stop <= 90 for b in blocks)
    assert pair_sums._blocks(10, 400, 3) == [slice(0, 10)]  # a strip lower than a block: one block, all of it
    centre = np.array([[100.0, 120.0]])
    side, partner = pair_sums.every_pair(img, np.zeros((90, 40), np.uint8), [0], centre, 3)
    rows = np.concatenate([np.arange(b.start, b.stop) for b in blocks])
    want_side, want_partner = _brute(img, np.zeros((90, 40), np.uint8), 0, centre[0], 3, anchor_rows=rows)
    np.testing.assert_allclose(side[:, 0], want_side, rtol=1e-5, atol=1e-3)
    np.testing.assert_allclose(partner[:, :, 0], want_partner, rtol=1e-5, atol=1e-3)


def _pearson(values: np.ndarray, inside: np.ndarray, radius: int) -> np.ndarray:
    """Per window lag, the Pearson correlation of the region's pixel pairs (numpy's: each end of
    the pairs with its own mean and variance)."""
    h, w = values.shape
    out = []
    for dy, dx in window(radius):
        a = (slice(0, h - dy), slice(max(0, -dx), w - max(0, dx)))
        b = (slice(dy, h), slice(max(0, dx), w - max(0, -dx)))
        both = inside[a] & inside[b]
        out.append(np.corrcoef(values[a][both].astype(np.float64), values[b][both].astype(np.float64))[0, 1])
    return np.array(out)


def test_measure_with_every_pair_gives_each_regions_pearson_correlation_of_its_pairs():
    img, labels = _frame(h=80, w=70, bands=1)
    fitter = FrameFitter(3, 1)
    fitter.add(img, labels)
    models = {k: r.model for k, r in fitter.fit().items()}
    deps = measure(img, labels, models, radius=4, pair_sums=pair_sums.every_pair)
    for lab in (0, 1, 2):
        np.testing.assert_allclose(deps[lab].acf[0], _pearson(img[..., 0], labels == lab, 4), atol=1e-5)


def test_fit_measures_a_scattered_class_of_a_photograph_as_its_own_pairs_show(host, tmp_path):
    """The rocket's brightest 3%, scattered specks: the anchors (16,384 of them, half again for
    the sparse pass) missed their autocorrelation by 0.43."""
    img = np.ascontiguousarray(data.rocket()[:256, :384])
    grey = img.astype(np.float64).sum(axis=2)
    labels = np.digitize(grey, np.quantile(grey, [0.45, 0.97])).astype(np.uint8)
    image, mask = tmp_path / "rocket.png", tmp_path / "rocket_mask.png"
    write_image(image, img)
    write_mask(mask, labels)
    code, out, err = host("fit", image, "--mask", mask, "--json")
    assert code == 0, err
    regions = {r["label"]: r for r in json.loads(out)["dependence"]["regions"]}
    for lab in (0, 1, 2):
        for b in range(3):  # within half an int8 step of 1/127 (the radio's), every lag
            truth = _pearson(img[..., b], labels == lab, 8)
            assert np.abs(np.array(regions[lab]["acf"][b]) - truth).max() < 0.0045, (lab, b)
