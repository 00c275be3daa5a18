"""Correlated synthesis against measured images: 2-D grain, joint colour, marginals kept to the
levels each region took.

Fake plates from the scene renderer and real texture photographs (scikit-image's bundled grass
and gravel): fit, measure as the robot does, send through the packet codec, synthesize with and
without the grain, and compare with the measured image.
"""
from __future__ import annotations

import warnings

import numpy as np
import pytest
from skimage import data

from btf.fit.dependence import measure, observed
from btf.fit.fitter import FrameFitter
from btf.johnson import Family, Johnson
from hal.interfaces import ViewAngles
from hal.scene import render
from radio.packets.dependence import quantized
from tools.analysis.grain_metrics import acf_gap, band_gap, outside
from tools.analysis.synth import ReachWarning, interpolate, synthesize, synthesize_at

MIN_REGION = 8000  # smaller regions: too few pixel pairs for a 0.1 bar
RADIUS = 6  # the window the robot measures (beyond it the grain is the spectrum's extension)


def _measured(img: np.ndarray, labels: np.ndarray):
    """(models, records as the host receives them) of an image, fitted and measured as on board."""
    f = FrameFitter(int(labels.max()) + 1, img.shape[2], bins=256)
    f.add(img, labels)
    models = {k: r.model for k, r in f.fit(min_count=64).items()}
    deps = measure(img, labels, models, levels_seen=observed(f.counts, f.centre0, f.bin_width))
    return models, quantized(deps, sorted(deps), img.shape[2])


def _hist(values: np.ndarray) -> np.ndarray:
    return np.bincount(values.ravel(), minlength=256) / values.size


def _case(name: str) -> tuple[np.ndarray, np.ndarray]:
    if name in ("grass", "gravel"):
        img = getattr(data, name)()[:256, :256, None]
        return img, np.zeros(img.shape[:2], dtype=np.uint8)
    v = render(name, ViewAngles(60.0, 0.0), (240, 320), seed=1)
    return v.image, v.mask.astype(np.uint8)


@pytest.mark.parametrize("name", ["mixed", "field", "grass", "gravel"])
def test_correlated_synthesis_matches_grain_colour_and_marginals(name):
    img, labels = _case(name)
    models, deps = _measured(img, labels)
    cors = [synthesize(labels, models, np.random.default_rng(s), dependence=deps) for s in range(3)]
    ind = synthesize(labels, models, np.random.default_rng(9), dependence=deps, independent=True)
    checked = 0
    for lab in deps:
        inside = labels == lab
        assert max(outside(img, c, inside) for c in cors + [ind]) == 0.0  # only levels the region took
        if inside.sum() < MIN_REGION:
            continue
        checked += 1
        assert np.mean([acf_gap(img, c, inside, RADIUS) for c in cors]) <= 0.1, f"{name} region {lab}: grain off"
        assert acf_gap(np.zeros_like(ind), ind, inside) < 0.05  # independent pixels have no grain
        assert max(band_gap(img, c, inside) for c in cors) <= 0.05, f"{name} region {lab}: colour off"
        for b in range(img.shape[2]):  # three draws' histogram: as close as independent pixels'
            real = _hist(img[..., b][inside])
            e_cor = 0.5 * np.abs(real - _hist(np.stack([c[..., b][inside] for c in cors]))).sum()
            e_ind = 0.5 * np.abs(real - _hist(ind[..., b][inside])).sum()
            assert e_cor <= 1.1 * e_ind + 0.01, f"{name} region {lab} band {b}: marginal worse"
    assert checked


def test_regions_stay_sharp_and_unmodelled_regions_stay_independent():
    img, labels = _case("mixed")
    models, deps = _measured(img, labels)
    only = {1: deps[1], 2: type(deps[2]).observed(deps[2].lo, deps[2].hi)}
    out = synthesize(labels, models, np.random.default_rng(1), dependence=only)
    for lab in (1, 2):
        assert outside(img, out, labels == lab) == 0.0
    inside = labels == 2
    assert acf_gap(img, out, labels == 1, RADIUS) <= 0.1
    assert acf_gap(np.zeros_like(out), out, inside) < 0.05  # levels only: pixel by pixel


def test_interpolation_blends_the_grain_and_the_flag_turns_it_off():
    img, labels = _case("field")
    models, deps = _measured(img, labels)
    by_angle = {40.0: models, 60.0: models}
    at = synthesize_at(by_angle, labels, 50.0, np.random.default_rng(2), dependence={40.0: deps, 60.0: deps})
    off = synthesize_at(by_angle, labels, 50.0, np.random.default_rng(2), dependence={40.0: deps, 60.0: deps},
                        independent=True)
    inside = labels == max(deps, key=lambda k: (labels == k).sum())
    assert acf_gap(img, at, inside, RADIUS) <= 0.1 and acf_gap(np.zeros_like(off), off, inside) < 0.05
    for lab in deps:
        assert outside(img, at, labels == lab) == 0.0 and outside(img, off, labels == lab) == 0.0
    half = interpolate(models, models, 0.5, labels, np.random.default_rng(3), dependence=(deps, None))
    assert acf_gap(img, half, inside, RADIUS) <= 0.1


def test_a_band_correlation_the_marginals_cannot_reach_is_named_once():
    labels = np.zeros((64, 64), np.uint8)
    rng = np.random.default_rng(4)
    img = rng.integers(100, 140, (64, 64, 2), dtype=np.uint8)
    # a bell curve and a long right tail: even comonotone their pixels correlate far below 0.99
    models = {(0, 0): Johnson.normal(120.0, 10.0), (0, 1): Johnson(Family.SL, 0.0, 0.5, 100.0, 1.0)}
    dep = measure(img, labels, models)[0]
    strong = type(dep)((0.99,), dep.acf, dep.radius)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        synthesize(labels, models, rng, dependence={0: strong})
    reach = [w for w in caught if issubclass(w.category, ReachWarning)]
    assert len(reach) == 1 and "label 0 bands 0-1 0.99, at most 0." in str(reach[0].message)


def test_store_keeps_the_records_and_synth_cli_uses_them_unless_independent(tmp_path):
    from btf.fit.png import decode_png, encode_png
    from tools import cli
    from tools.store.database import Store

    img, labels = _case("field")
    f = FrameFitter(int(labels.max()) + 1, 3, bins=256)
    f.add(img, labels)
    results = f.fit(min_count=64)
    deps = measure(img, labels, {k: r.model for k, r in results.items()},
                   levels_seen=observed(f.counts, f.centre0, f.bin_width))
    db = tmp_path / "c.db"
    with Store.open(db) as store:
        assert store.add_capture("bot", 1, 0.0, None, (60.0, 0.0), "rgb", ("R", "G", "B"), results,
                                 dependence=deps)
        assert store.dependence_by_angle() == {60.0: deps}
    (tmp_path / "mask.png").write_bytes(encode_png(labels))
    outs = {}
    for flag in ([], ["--independent"]):
        out = tmp_path / f"out{len(flag)}.png"
        assert cli.main(["synth", "--db", str(db), "--mask", str(tmp_path / "mask.png"), "--angle", "60",
                         "--out", str(out), *flag]) == 0
        outs[bool(flag)] = decode_png(out.read_bytes()).pixels
    inside = labels == max(deps, key=lambda k: (labels == k).sum())
    assert acf_gap(img, outs[False], inside, RADIUS) <= 0.1
    assert acf_gap(np.zeros_like(img), outs[True], inside) < 0.05
    assert all(outside(img, o, labels == lab) == 0.0 for o in outs.values() for lab in deps)


def test_a_region_on_every_other_row_has_its_drawn_band_correlation_read():
    from tools.analysis.synth import _drawn_corr

    inside = np.zeros((600, 600), bool)
    inside[1::2] = True  # 180,000 pixels: the check's lattice (every other row and column) misses them all
    rng = np.random.default_rng(0)
    base = rng.normal(30000, 3000, inside.shape).astype(np.float32)
    fields = [base, (0.6 * base + 0.8 * rng.normal(30000, 3000, inside.shape)).astype(np.float32)]
    tables = [np.arange(65536, dtype=np.uint16)] * 2
    got = _drawn_corr(fields, tables, inside)
    assert np.allclose(np.diag(got), 1.0) and got[0, 1] == pytest.approx(0.6, abs=0.01)
