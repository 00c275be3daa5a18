"""Correlated synthesis against measured images: grain, joint colour and marginals.

Fake plates from the scene renderer and real texture photographs (scikit-image's bundled
grass and gravel): fit, measure dependence as the robot does, send it through the packet
codec, synthesize with and without it, and compare with the measured image.
"""
from __future__ import annotations

import numpy as np
import pytest
from skimage import data

from btf.fit.dependence import measure
from btf.fit.fitter import FrameFitter
from hal.interfaces import ViewAngles
from hal.scene import render
from radio.packets.dependence import decode_dependence, encode_dependence
from tools.analysis.fields import empirical_autocorrelation
from tools.analysis.synth import interpolate, synthesize, synthesize_at

MIN_REGION = 8000  # smaller regions: too few pixel pairs for a 0.1 bar at lag 8


def _fit(img: np.ndarray, labels: np.ndarray):
    f = FrameFitter(int(labels.max()) + 1, img.shape[2], bins=256)
    f.add(img, labels)
    return {k: r.model for k, r in f.fit(min_count=64).items()}


def _autocorr(img: np.ndarray, inside: np.ndarray) -> np.ndarray:
    return np.array([[[empirical_autocorrelation(img[..., b], inside, lag, axis) for lag in range(1, 9)]
                      for axis in (0, 1)] for b in range(img.shape[2])])


def _hist(values: np.ndarray) -> np.ndarray:
    return np.bincount(values.ravel(), minlength=256) / values.size


def _tv(p: np.ndarray, q: np.ndarray) -> float:
    return 0.5 * float(np.abs(p - q).sum())


def _case(name: str) -> tuple[np.ndarray, np.ndarray]:
    if name in ("grass", "gravel"):
        img = getattr(data, name)()[:320, :320, None]
        return img, np.zeros(img.shape[:2], dtype=np.int64)
    v = render(name, ViewAngles(60.0, 0.0), (240, 320), seed=1)
    return v.image, v.mask.astype(np.int64)


@pytest.mark.parametrize("name", ["black", "white", "mixed", "field", "grass", "gravel"])
def test_correlated_synthesis_matches_grain_colour_and_marginals(name):
    img, labels = _case(name)
    bands = img.shape[2]
    models = _fit(img, labels)
    measured = measure(img, labels, models)
    regions = sorted(measured)
    deps = decode_dependence(encode_dependence(measured, regions, bands), regions, bands)
    # Marginals over eight draws: a grainy draw has fewer independent pixels, so one draw's
    # histogram is noisier even though its expected histogram is the model's exactly (over
    # four, the field's region 5 still scatters 0.041..0.055 around its independent 0.044).
    cors = [synthesize(labels, models, np.random.default_rng(s), dependence=deps) for s in range(8)]
    inds = [synthesize(labels, models, np.random.default_rng(s)) for s in range(8)]
    cor, ind = cors[0], inds[0]
    checked = 0
    for lab in regions:
        inside = labels == lab
        if inside.sum() < MIN_REGION:
            continue
        checked += 1
        want, got, flat = _autocorr(img, inside), _autocorr(cor, inside), _autocorr(ind, inside)
        assert np.abs(got - want).max() <= 0.1, f"{name} region {lab}: grain off"
        assert np.abs(flat).max() < 0.05  # independent synthesis has no grain
        if bands > 1:
            c_want, c_got = (np.corrcoef(x[inside].T.astype(float)) for x in (img, cor))
            assert np.abs(c_got - c_want).max() <= 0.05, f"{name} region {lab}: colour off"
        for b in range(bands):
            real = _hist(img[..., b][inside])
            e_cor = _tv(real, _hist(np.stack([x[..., b][inside] for x in cors])))
            e_ind = _tv(real, _hist(np.stack([x[..., b][inside] for x in inds])))
            assert e_cor <= 1.05 * e_ind + 0.01, f"{name} region {lab} band {b}: marginal worse"
    assert checked


def test_regions_stay_sharp_and_unmodelled_regions_stay_independent():
    img, labels = _case("mixed")
    models = _fit(img, labels)
    deps = measure(img, labels, models)
    only = {1: deps[1]}
    out = synthesize(labels, models, np.random.default_rng(1), dependence=only)
    for lab in (1, 2):
        inside = labels == lab
        lo, hi = (models[(lab, 0)].ppf(q) for q in (1e-6, 1 - 1e-6))
        vals = out[..., 0][inside]
        assert vals.min() >= np.floor(lo) and vals.max() <= np.ceil(hi)
    assert _autocorr(out, labels == 1)[0, 1, 0] > 0.2
    assert abs(_autocorr(out, labels == 2)[0, 1, 0]) < 0.05


def test_interpolation_blends_dependence_and_the_flag_turns_it_off():
    img, labels = _case("white")
    models = _fit(img, labels)
    dep = measure(img, labels, models)
    by_angle = {40.0: models, 60.0: models}
    at = synthesize_at(by_angle, labels, 50.0, np.random.default_rng(2), dependence={40.0: dep, 60.0: dep})
    off = synthesize_at(by_angle, labels, 50.0, np.random.default_rng(2), dependence={40.0: dep, 60.0: dep},
                        independent=True)
    inside = labels == 2
    want = _autocorr(img, inside)[:, :, 0]
    assert np.abs(_autocorr(at, inside)[:, :, 0] - want).max() <= 0.1
    assert np.abs(_autocorr(off, inside)[:, :, 0]).max() < 0.05
    half = interpolate(models, models, 0.5, labels, np.random.default_rng(3), dependence=(dep, None))
    assert np.abs(_autocorr(half, inside)[:, :, 0] - want).max() <= 0.1


def test_store_keeps_dependence_and_synth_cli_uses_it_unless_independent(tmp_path):
    from btf.fit.png import decode_png, encode_png
    from tools import cli
    from tools.store.database import Store

    img, labels = _case("white")
    f = FrameFitter(int(labels.max()) + 1, 3, bins=256)
    f.add(img, labels)
    results = f.fit(min_count=64)
    deps = measure(img, labels, {k: r.model for k, r in results.items()})
    db = tmp_path / "c.db"
    with Store.open(db) as store:
        assert store.add_capture("bot", 1, 0.0, None, (60.0, 0.0), "rgb", ("R", "G", "B"), results,
                                 dependence=deps)
        assert store.dependence_by_angle() == {60.0: deps}
    (tmp_path / "mask.png").write_bytes(encode_png(labels.astype(np.uint8)))
    outs = {}
    for flag in ([], ["--independent"]):
        out = tmp_path / f"out{len(flag)}.png"
        assert cli.main(["synth", "--db", str(db), "--mask", str(tmp_path / "mask.png"), "--angle", "60",
                         "--out", str(out), *flag]) == 0
        outs[bool(flag)] = decode_png(out.read_bytes()).pixels
    inside = labels == 2
    want = _autocorr(img, inside)[:, :, 0]
    assert np.abs(_autocorr(outs[False], inside)[:, :, 0] - want).max() <= 0.1
    assert np.abs(_autocorr(outs[True], inside)[:, :, 0]).max() < 0.05
