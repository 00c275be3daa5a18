"""`btf-host spaces` and `fit --space auto` as a person meets them: the table, the picture, the
choice, a stored capture, and bad input in one line."""
from __future__ import annotations

import json

import numpy as np
import pytest

from btf.fit.fitter import FrameFitter
from tests.support.cli import refused
from tests.support.images import plate, public_photos
from tests.support.spaces import bands_of, table2
from tools.data.images import read_image, stretched_8bit, three_bands, write_image, write_mask
from tools.data.masks import segment
from tools.store.database import Store

PHOTOS = public_photos(48)
COLOUR = [n for n, p in PHOTOS.items() if p.shape[2] == 3]


@pytest.fixture
def photo(tmp_path):
    img, mask = plate(0)
    write_image(tmp_path / "a.png", img)
    write_mask(tmp_path / "m.png", mask)
    write_image(tmp_path / "g.png", img[:, :, :1])
    return tmp_path


def test_the_table_has_a_row_per_mask_and_space_and_ends_with_the_choice(run, photo):
    code, out, _ = run("spaces", photo / "a.png", "--masks", "kmeans2,isodata2", "--spaces", "rgb,hsv",
                       "--picture", photo / "p.png")
    lines = out.strip().splitlines()
    assert code == 0 and len(lines) == 2 + 4 + 1
    assert [ln.split()[:2] for ln in lines[2:6]] == [["kmeans2", "rgb"], ["kmeans2", "hsv"],
                                                    ["isodata2", "rgb"], ["isodata2", "hsv"]]
    assert lines[-1].startswith("choice: ") and (" in rgb; rgb: " in lines[-1] or " in hsv; hsv: " in lines[-1])
    pic = read_image(photo / "p.png")
    assert pic.shape[1] > 3 * 80 and pic.shape[2] == 3  # photograph | chosen | worst, enlarged
    # the photograph's panel shows the photograph, enlarged pixel for pixel
    zoom = pic.shape[1] // (3 * 80)
    panel = pic[24:24 + 60 * zoom:zoom, :80 * zoom:zoom]
    assert np.array_equal(panel, read_image(photo / "a.png"))


def test_a_given_mask_is_the_one_mask_and_json_is_one_document(run, photo):
    code, out, _ = run("spaces", photo / "a.png", "--mask", photo / "m.png", "--spaces", "rgb,pca", "--json")
    doc = json.loads(out)
    assert code == 0 and [r["mask"] for r in doc["rows"]] == ["mask", "mask"] and doc["rows"][0]["regions"] == 2
    assert doc["choice"]["space"] in ("rgb", "pca")


@pytest.mark.parametrize("argv, said", [
    (("--masks", "blobs3"), "'blobs3' is not a mask"),
    (("--masks", "kmeans0"), "asks for 0 classes"),
    (("--spaces", "rgb,xyz"), "xyz is not a feature space"),
    (("--spaces", "rgb,rgb"), "a space named twice"),
    (("--capture", "host/1"), "give --db DB too"),
])
def test_bad_options_are_one_line(run, photo, argv, said):
    assert said in refused(*run("spaces", photo / "a.png", *argv)[::2])


def test_a_one_band_photograph_offers_gray_alone(run, photo):
    line = refused(*run("spaces", photo / "g.png", "--spaces", "rgb,gray")[::2])
    assert "offers only gray; drop rgb" in line
    code, out, _ = run("spaces", photo / "g.png", "--masks", "kmeans2", "--json")
    assert code == 0 and [r["space"] for r in json.loads(out)["rows"]] == ["gray"]
    # fit, pdfs and compare say the same: a one-band image has no colours to fit or compare
    for argv in (("fit", photo / "g.png", "--space", "hsv"),
                 ("pdfs", photo / "g.png", "--mask", photo / "m.png", "--space", "rgb"),
                 ("compare", photo / "g.png", photo / "g.png", "--space", "hsv")):
        assert "the image is one band, which has no colours; use gray" in refused(*run(*argv)[::2])
    line = refused(*run("compare", photo / "a.png", photo / "g.png")[::2])
    assert "1 band(s)" in line and "in gray (--space gray)" in line
    code, out, _ = run("compare", photo / "a.png", photo / "g.png", "--space", "gray")
    assert code == 0 and "Y" in out


def test_a_photograph_of_flat_colours_is_judged_without_a_warning(run, tmp_path, recwarn):
    image = np.zeros((48, 48, 3), np.uint8)
    image[:, 24:] = (200, 100, 50)  # two flat regions: every band constant in each
    write_image(tmp_path / "flat.png", image)
    code, out, err = run("spaces", tmp_path / "flat.png", "--masks", "kmeans2", "--spaces", "rgb", "--json")
    assert code == 0 and err == ""
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]  # numpy's, of a flat band's correlation
    assert json.loads(out)["rows"][0]["texture"]["band_gap"] == 0.0


def test_missing_files_and_an_existing_picture_are_one_line(run, photo):
    assert "no such file" in refused(*run("spaces", photo / "none.png")[::2])
    (photo / "p.png").write_bytes(b"x")
    assert "--force" in refused(*run("spaces", photo / "a.png", "--picture", photo / "p.png")[::2])
    assert "give a photograph" in refused(*run("spaces")[::2])


def test_a_stored_capture_is_judged_by_its_image_or_said_to_have_none(run, photo):
    ds = photo / "ds"
    ds.mkdir()
    write_image(ds / "a.png", read_image(photo / "a.png"))
    assert run("ingest", ds, "--layout", "folder", "--db", photo / "d.db")[0] == 0
    with Store.open(photo / "d.db") as s:
        cap = s.captures()[0]
    code, out, _ = run("spaces", "--db", photo / "d.db", "--capture", f"{cap.robot}/{cap.sequence}",
                       "--masks", "kmeans2", "--spaces", "rgb", "--json")
    assert code == 0 and json.loads(out)["image"].startswith(f"capture {cap.robot}/")
    assert run("fit", photo / "a.png", "--db", photo / "f.db", "--angle", 30)[0] == 0
    line = refused(*run("spaces", "--db", photo / "f.db", "--capture", "host/0")[::2])
    assert "capture host/0 has no image to judge by" in line
    assert "no capture host/5" in refused(*run("spaces", "--db", photo / "f.db", "--capture", "host/5")[::2])
    assert "--db needs --capture" in refused(*run("spaces", "--db", photo / "f.db")[::2])


def test_a_robots_capture_is_found_in_whichever_state_numbered_it(run, photo):
    """Robot captures carry the id of the robot state that numbered them: ROBOT/SEQ finds the
    newest, and says so where two states numbered the same."""
    fitter = FrameFitter(1, 3)
    fitter.add(read_image(photo / "a.png"), np.zeros(read_image(photo / "a.png").shape[:2], np.uint8))
    with Store.open(photo / "r.db") as s:
        for incarnation in ("a1b2", "c3d4"):
            s.add_capture("1", 3, 0.0, None, (40.0, 0.0), "rgb", ("R", "G", "B"), fitter.fit(), incarnation=incarnation)
    code, _, err = run("spaces", "--db", photo / "r.db", "--capture", "1/3")
    assert code == 2 and "capture 1/3 has no image to judge by" in err
    assert "numbered 2 captures 3 (one per robot state); judging the newest, stored as capture id 2" in err


def test_fit_space_auto_is_recorded_with_the_capture(run, photo):
    code, out, _ = run("fit", photo / "a.png", "--mask", photo / "m.png", "--space", "auto", "--json")
    doc = json.loads(out)
    assert code == 0 and doc["space_choice"]["automatic"] and doc["space_choice"]["reason"].startswith(doc["space"])
    code, out, _ = run("fit", photo / "a.png", "--space", "auto", "--db", photo / "s.db", "--angle", 40)
    said = out.strip().splitlines()[-2]
    assert code == 0 and said.startswith("space chosen automatically: ")
    assert run("fit", photo / "a.png", "--space", "rgb", "--db", photo / "s.db", "--angle", 50)[0] == 0
    with Store.open(photo / "s.db") as s:
        auto, configured = sorted(s.captures(), key=lambda c: c.sequence)
        assert s.space_choice(auto.id) == said.removeprefix("space chosen automatically: ")
        assert s.space_choice(configured.id) is None  # a fit's space is its own, never inherited


def test_a_pca_fit_is_stored_with_its_basis_and_synthesized_back_into_the_photographs_colours(run, photo):
    assert run("fit", photo / "a.png", "--mask", photo / "m.png", "--space", "pca", "--db", photo / "p.db",
               "--angle", 40)[0] == 0
    with Store.open(photo / "p.db") as s:
        (cap,) = s.captures()
        assert s.pca_basis(cap.id) is not None
    code, _, err = run("synth", "--db", photo / "p.db", "--mask", photo / "m.png", "--angle", 40,
                       "--out", photo / "s.png")
    assert code == 0, err
    image, mask = read_image(photo / "a.png"), read_image(photo / "m.png")[:, :, 0]
    drawn = read_image(photo / "s.png")
    for label in np.unique(mask):
        assert np.abs(drawn[mask == label].mean(0) - image[mask == label].mean(0)).max() < 10


@pytest.mark.parametrize("damage", ["no mean", "nan", "sizes", "a list", "two channels"])
def test_a_models_document_with_a_damaged_pca_basis_is_refused_in_one_line(run, photo, damage):
    code, out, _ = run("fit", photo / "a.png", "--mask", photo / "m.png", "--space", "pca", "--json")
    doc = json.loads(out)
    basis = doc["pca"]
    if damage == "no mean":
        del basis["mean"]
    elif damage == "nan":
        basis["mean"][0] = float("nan")
    elif damage == "sizes":
        basis["rotation"] = basis["rotation"][:2]
    elif damage == "a list":
        doc["pca"] = [1, 2]
    else:
        doc["pca"] = {"mean": [0, 0], "rotation": [[1, 0], [0, 1]], "scale": [1, 1], "offset": [0, 0]}
    (photo / "bad.json").write_text(json.dumps(doc))
    said = run("synth", "--model", photo / "bad.json", "--mask", photo / "m.png", "--out", photo / "s.png")
    line = refused(said[0], said[2])
    assert "pca" in line and "bad.json" in line and not (photo / "s.png").exists()


@pytest.mark.parametrize("name", COLOUR)
@pytest.mark.parametrize("masked", [False, True])
def test_auto_never_chooses_a_space_worse_than_rgb_beyond_the_noise_between_two_seeds(run, tmp_path, name, masked):
    image = PHOTOS[name]
    write_image(tmp_path / "p.png", image)
    labels = np.zeros(image.shape[:2], np.uint8)
    argv = ["fit", tmp_path / "p.png", "--space", "auto", "--json", "--independent-only"]
    if masked:
        labels = segment(three_bands(stretched_8bit(image)), "kmeans", 3, 0)
        write_mask(tmp_path / "m.png", labels)
        argv += ["--mask", tmp_path / "m.png"]
    code, out, _ = run(*argv)
    chosen = json.loads(out)["space"]
    errors = {}
    for space in {"rgb", chosen}:
        data, levels = bands_of(image, space)
        fitter = FrameFitter(int(labels.max()) + 1, data.shape[2], bins=levels)
        fitter.add(data, labels)
        models = {k: r.model for k, r in fitter.fit().items()}
        errors[space] = [table2(fitter.counts, models, levels, seed) for seed in (0, 1)]
    noise = abs(errors["rgb"][0] - errors["rgb"][1])
    assert code == 0 and chosen != "gray"
    assert np.mean(errors[chosen]) <= np.mean(errors["rgb"]) + noise
