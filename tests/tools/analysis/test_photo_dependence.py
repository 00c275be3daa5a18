"""The researcher's path to correlated synthesis, with no robot: `fit` and `ingest` measure
grain and band dependence (btf.fit.dependence) by default, store it and carry it in the models
document, and `synth --model` / `synth --db` reproduce it.

The photographs are public ones shipped inside scikit-image (grass, gravel, brick and the
colour coffee photograph), written to PNG and used as a user would: whole image, label 0.
"""
from __future__ import annotations

import json

import numpy as np
import pytest
from skimage import data

from tools.analysis.fields import empirical_autocorrelation
from tools.data.images import read_image, write_image, write_mask
from tools.store.database import Store

PHOTOS = ("grass", "gravel", "brick", "coffee")


def _photo(tmp_path, name: str):
    img = getattr(data, name)()
    path = tmp_path / f"{name}.png"
    write_image(path, img)
    mask = tmp_path / f"{name}_mask.png"
    write_mask(mask, np.zeros(img.shape[:2], np.uint8))
    return path, mask


def _autocorr(img: np.ndarray) -> np.ndarray:
    """bands x (vertical, horizontal) x lags 1..8, over the whole image."""
    inside = np.ones(img.shape[:2], bool)
    return np.array([[[empirical_autocorrelation(img[..., b], inside, lag, axis) for lag in range(1, 9)]
                      for axis in (0, 1)] for b in range(img.shape[2])])


def _band_corr(img: np.ndarray) -> np.ndarray:
    return np.corrcoef(img.reshape(-1, img.shape[2]).T.astype(np.float64))


@pytest.mark.parametrize("name", PHOTOS)
def test_fit_then_synth_model_reproduces_grain_and_colour_of_a_photograph(host, tmp_path, name):
    image, mask = _photo(tmp_path, name)
    code, out, err = host("fit", image, "--json")
    assert code == 0, err
    doc = json.loads(out)
    assert doc["dependence"]["lags"] == [1, 2, 4, 8]
    assert [r["label"] for r in doc["dependence"]["regions"]] == [0]
    models = tmp_path / "models.json"
    models.write_text(out)
    outs = {}
    for flag in ([], ["--independent"]):
        outs[bool(flag)] = []
        for seed in range(3):  # one 512x512 draw's lag-8 autocorrelation scatters by about 0.03
            dest = tmp_path / f"synth{len(flag)}_{seed}.png"
            code, _, err = host("synth", "--model", models, "--mask", mask, "--angle", 90, "--out", dest,
                                "--seed", seed, *flag)
            assert code == 0, err
            outs[bool(flag)].append(read_image(dest))
    real = read_image(image)
    want = _autocorr(real)
    assert np.abs(np.mean([_autocorr(o) for o in outs[False]], axis=0) - want).max() <= 0.1
    assert np.abs(np.mean([_band_corr(o) for o in outs[False]], axis=0) - _band_corr(real)).max() <= 0.05
    # Without the dependence the same models give independent pixels: far from the photograph.
    assert np.abs(_autocorr(outs[True][0]) - want).max() > 0.5


def test_independent_only_measures_nothing_and_says_so_in_the_document(host, tmp_path):
    image, _ = _photo(tmp_path, "brick")
    code, out, _ = host("fit", image, "--json", "--independent-only")
    assert code == 0
    assert json.loads(out)["dependence"] is None
    code, out, _ = host("fit", image)
    assert code == 0 and "grain lag:h/v 1:0.8" in out and "bands RG 1.00" in out


def test_fit_db_stores_dependence_and_synth_db_uses_it(host, tmp_path):
    image, mask = _photo(tmp_path, "coffee")
    db = tmp_path / "c.db"
    code, out, err = host("fit", image, "--angle", 60, "--db", db)
    assert code == 0, err
    with Store.open(db) as store:
        (cap,) = store.captures()
        dep = store.dependence(cap.id)
        assert list(dep) == [0] and dep[0].dx[0] > 0.9 and cap.levels == 256
    dest = tmp_path / "s.png"
    assert host("synth", "--db", db, "--mask", mask, "--angle", 60, "--out", dest)[0] == 0
    real = read_image(image)
    assert np.abs(_autocorr(read_image(dest)) - _autocorr(real)).max() <= 0.1
    code, _, _ = host("fit", image, "--angle", 50, "--db", db, "--independent-only")
    with Store.open(db) as store:
        assert store.dependence(store.captures()[0].id) == {}  # the 50 degree capture, sorted first


def test_ingest_stores_dependence_unless_independent_only(host, tmp_path):
    folder = tmp_path / "photos"
    folder.mkdir()
    for name in ("brick", "coffee"):
        write_image(folder / f"{name}.png", getattr(data, name)()[:128, :128])
    for flag, db in (([], tmp_path / "on.db"), (["--independent-only"], tmp_path / "off.db")):
        code, _, err = host("ingest", folder, "--layout", "folder", "--db", db, "--workers", 0, "--quiet", *flag)
        assert code == 0, err
        with Store.open(db) as store:
            deps = [store.dependence(c.id) for c in store.captures()]
        assert len(deps) == 2
        if flag:
            assert deps == [{}, {}]
        else:
            assert all(list(d) == [0] and d[0].dx[0] > 0.5 for d in deps)


@pytest.mark.parametrize("section, message", [
    ({"lags": [1, 2, 3, 4], "regions": []}, "lags [1, 2, 3, 4]"),
    ({"lags": [1, 2, 4, 8], "regions": [{"label": 0, "corr": [0.5], "dx": [0.5] * 4, "dy": [0.5] * 4}]},
     "2 band(s), the models have 3"),
    ({"lags": [1, 2, 4, 8], "regions": [{"label": 0, "corr": [2, 0, 0], "dx": [0.5] * 4, "dy": [0.5] * 4}]},
     "[-1, 1]"),
    ("yes", "expected an object"),
])
def test_a_broken_dependence_section_is_one_line_and_exit_2(host, tmp_path, section, message):
    image, mask = _photo(tmp_path, "coffee")
    code, out, _ = host("fit", image, "--json")
    doc = json.loads(out)
    doc["dependence"] = section
    models = tmp_path / "m.json"
    models.write_text(json.dumps(doc))
    code, _, err = host("synth", "--model", models, "--mask", mask, "--angle", 90, "--out", tmp_path / "o.png")
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and message in err
