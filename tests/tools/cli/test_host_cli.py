"""btf-host analysis subcommands: exit codes, one-line errors and --json shapes."""
import json

import numpy as np
import pytest

from tests.support.images import plate
from tools.data.images import read_image, read_mask, write_image, write_mask


@pytest.fixture
def files(tmp_path):
    img, mask = plate(0)
    write_image(tmp_path / "a.png", img)
    write_image(tmp_path / "b.png", plate(1)[0])
    write_mask(tmp_path / "m.png", mask)
    return tmp_path


def test_fit_json_then_synth_from_it(host, files):
    code, out, _ = host("fit", files / "a.png", "--mask", files / "m.png", "--angle", 30, "--json")
    assert code == 0
    doc = json.loads(out)
    assert doc["space"] == "rgb" and doc["bands"] == ["R", "G", "B"] and doc["angle"] == 30
    assert len(doc["models"]) == 6
    assert set(doc["models"][0]) >= {"label", "band", "family", "gamma", "delta", "xi", "lam", "count"}
    (files / "models.json").write_text(out)
    code, _, err = host("synth", "--model", files / "models.json", "--mask", files / "m.png",
                        "--angle", 30, "--out", files / "s.png")
    assert code == 0, err
    s = read_image(files / "s.png")
    assert s.shape == (60, 80, 3)
    assert s[:, :40].mean() < 100 < s[:, 40:].mean()


def test_db_round_trip_interpolates_and_warns_outside(host, files):
    db = files / "scene.db"
    for angle, name in ((0, "a.png"), (60, "b.png")):
        assert host("fit", files / name, "--mask", files / "m.png", "--angle", angle, "--db", db)[0] == 0
    code, _, err = host("synth", "--db", db, "--mask", files / "m.png", "--angle", 30, "--out", files / "i.png")
    assert code == 0 and err == ""
    code, _, err = host("synth", "--db", db, "--mask", files / "m.png", "--angle", 80, "--out", files / "x.png")
    assert code == 0 and "outside the measured range" in err


def test_mask_labels_absent_from_db_are_one_line_exit_2(host, files):
    db = files / "scene.db"
    host("fit", files / "a.png", "--angle", 10, "--db", db)  # only label 0
    code, _, err = host("synth", "--db", db, "--mask", files / "m.png", "--angle", 10, "--out", files / "o.png")
    assert code == 2 and "[1]" in err and len(err.strip().splitlines()) == 1


def test_compare_json_shape_and_self_comparison(host, files):
    code, out, _ = host("compare", files / "a.png", files / "a.png", "--mask", files / "m.png", "--json")
    doc = json.loads(out)
    assert code == 0 and set(doc) == {"bands", "correlation", "regions", "total", "space"}
    assert doc["correlation"] == {"R": 1.0, "G": 1.0, "B": 1.0}
    assert doc["total"]["hist_diff"] == 0.0 and len(doc["regions"]) == 6
    code, out, _ = host("compare", files / "a.png", files / "b.png", "--space", "hsv", "--json")
    doc = json.loads(out)
    assert code == 0 and doc["bands"] == ["H", "S", "V"] and doc["total"]["hist_diff"] > 0


def test_pdfs_json_shape(host, files):
    code, out, _ = host("pdfs", files / "a.png", "--mask", files / "m.png", "--json")
    doc = json.loads(out)
    assert code == 0 and doc["peers"] == ["johnson", "gaussian", "uniform", "weibull", "lognormal"]
    assert len(doc["rows"]) == 6 and set(doc["total"]) == set(doc["peers"])


@pytest.mark.parametrize("method", ["isodata", "kmeans", "felzenszwalb", "slic"])
def test_mask_methods_find_the_two_plates(host, files, method):
    code, _, err = host("mask", files / "a.png", "--method", method, "--k", 2, "--out", files / "o.png")
    assert code == 0, err
    got = read_mask(files / "o.png")
    truth = read_mask(files / "m.png")
    # Every class lies within one plate (ISODATA may split a plate, never mix two).
    pure = sum(np.bincount(truth[got == c], minlength=2).max() for c in np.unique(got))
    assert pure / got.size > 0.95
    assert len(np.unique(got)) >= 2


def test_resolve_json(host):
    code, out, _ = host("resolve", "--grain-mm", 0.02, "--wavelength-nm", 700, "--pixel-mm", 0.125, "--json")
    doc = json.loads(out)
    assert code == 0 and doc["physical"]["verdict"] == "statistical" and doc["physical"]["rayleigh_height_nm"] == 87.5
    assert doc["paper"]["verdict"] == "statistical"


@pytest.mark.parametrize("argv, words", [
    (("fit", "{d}/nope.png"), "no such file"),
    (("fit", "{d}/junk.png"), "not a readable image"),
    (("fit", "{d}/a.png", "--mask", "{d}/small.png"), "differs from the image"),
    (("fit", "{d}/a.png", "--db", "{d}/x.db"), "--angle"),
    (("fit", "{d}/a.png", "--angle", "5", "--db", "{d}/junk.png"), "not an SQLite file"),
    (("compare", "{d}/a.png", "{d}/small.png"), "differs"),
    (("pdfs", "{d}/a.png", "--mask", "{d}/nope.png"), "no such file"),
    (("compare", "{d}/a.png", "{d}"), "not a regular file"),
    (("pdfs", "{d}/a.png", "--mask", "{d}"), "not a regular file"),
    (("synth", "--model", "{d}/junk.png", "--mask", "{d}/m.png", "--angle", "1", "--out", "{d}/o.png"), "JSON"),
    (("synth", "--db", "{d}/none.db", "--mask", "{d}/m.png", "--angle", "1", "--out", "{d}/o.png"), "no such"),
    (("synth", "--db", "{d}", "--mask", "{d}/m.png", "--angle", "1", "--out", "{d}/o.png"), "not a regular file"),
    (("fit", "{d}/a.png", "--angle", "5", "--db", "{d}"), "not a regular file"),
    (("synth", "--model", "{d}/m.json", "--mask", "{d}/m.png", "--angle", "nan", "--out", "{d}/o.png"), "finite"),
    (("synth", "--model", "{d}/m.json", "--mask", "{d}/m.png", "--angle=inf", "--out", "{d}/o.png"), "finite"),
    (("synth", "--model", "{d}/angle.json", "--mask", "{d}/m.png", "--angle", "1", "--out", "{d}/o.png"), "angle"),
    (("synth", "--model", "{d}/levels.json", "--mask", "{d}/m.png", "--angle", "1", "--out", "{d}/o.png"), "levels"),
    (("resolve", "--grain-mm", "-1", "--wavelength-nm", "700"), "positive"),
    (("resolve", "--grain-mm", "1e308", "--wavelength-nm", "1e-308"), "too far apart"),
    (("mask", "{d}/a.png", "--method", "slic", "--out", "{d}/o.jpg"), ".png"),
])
def test_bad_input_is_one_line_and_exit_2(host, files, argv, words):
    (files / "junk.png").write_bytes(b"definitely not a png")
    write_mask(files / "small.png", np.zeros((5, 5), np.uint8))
    write_image(files / "small.png", np.zeros((5, 5, 3), np.uint8))
    doc = {"angle": None, "space": "rgb", "levels": 256, "models": [
        {"label": 0, "band": b, "family": "SN", "gamma": 0.0, "delta": 1.0, "xi": 9.0, "lam": 2.0}
        for b in range(3)]}
    (files / "m.json").write_text(json.dumps(doc))
    (files / "angle.json").write_text(json.dumps(doc | {"angle": [1]}))
    (files / "levels.json").write_text(json.dumps(doc | {"levels": "many"}))
    before = (files / "junk.png").read_bytes()
    code, out, err = host(*[a.format(d=files) for a in argv])
    assert code == 2
    assert words in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert (files / "junk.png").read_bytes() == before
