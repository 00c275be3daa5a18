"""Bad input to btf-host is one line on stderr naming the problem and the fix, exit status 2:
no traceback, no usage block, no line of libpng's or OpenCV's, nothing written or half-done."""
from __future__ import annotations

import json

import numpy as np
import pytest

from tests.support.cli import refused
from tests.support.images import plate
from tools.data.images import read_image, write_image, write_mask
from tools.store.database import Store


@pytest.fixture
def files(tmp_path):
    img, mask = plate(0)
    write_image(tmp_path / "a.png", img)
    write_mask(tmp_path / "m.png", mask)
    deep = (img.astype(np.uint16) * 257)
    write_image(tmp_path / "deep.png", deep)
    return tmp_path


def test_a_goto_the_robot_would_refuse_is_refused_at_parse_time_with_its_range(run, tmp_path):
    code, _, err = run("cmd", "--db", tmp_path / "none.db", "goto", "--elevation", 120)
    assert refused(code, err) == "btf-host cmd goto: error: --elevation 120: must lie in -90..90 degrees"
    code, _, err = run("cmd", "--db", tmp_path / "none.db", "sweep", "--elevations", "90,nan")
    assert "--elevations 90,nan: must lie in -90..90 degrees" in refused(code, err)


def test_a_sweep_short_of_an_option_or_with_a_value_lost_between_commas_says_which(run, tmp_path):
    db = tmp_path / "none.db"
    assert "sweep --start, --stop: --step missing" in refused(*run("cmd", "--db", db, "sweep", "--start", 90,
                                                                  "--stop", 30)[::2])
    line = refused(*run("cmd", "--db", db, "sweep", "--elevations", "80,,60")[::2])
    assert "--elevations 80,,60: an empty value between commas" in line


@pytest.mark.parametrize(("argv", "option"), [
    (("synth", "--model", "m.json", "--mask", "m.png", "--angle", 30, "--out", "s.png", "--seed", -1), "--seed -1"),
    (("mask", "a.png", "--method", "kmeans", "--k", 300, "--out", "o.png"), "--k 300"),
    (("demo", "--size", 8, 8), "--size 8"),
    (("ingest", "d", "--layout", "plain", "--db", "x.db"), "--layout"),
])
def test_a_number_or_word_out_of_its_range_names_its_option(run, argv, option):
    line = refused(*run(*argv)[::2])
    assert option in line and ("must lie in" in line or "choose from" in line), line


def test_an_empty_file_given_as_a_database_is_said_to_be_one(run, tmp_path):
    (tmp_path / "empty.db").write_bytes(b"")
    line = refused(*run("report", "--db", tmp_path / "empty.db", "--out", tmp_path / "r")[::2])
    assert "empty.db: an empty file, not a btfscout database" in line
    assert (tmp_path / "empty.db").read_bytes() == b"" and not (tmp_path / "r").exists()


def test_outputs_are_checked_before_any_work(run, files, monkeypatch):
    import tools.cli.mask as mask_cli

    monkeypatch.setattr(mask_cli, "segment", lambda *a: pytest.fail("segmented before --out was checked"))
    line = refused(*run("mask", files / "a.png", "--method", "kmeans", "--out", files / "o.jpg")[::2])
    assert "--out" in line and ".png" in line
    # the models file does not exist: the --out problem is found first, before reading anything
    for out, words in (("s8.xyz", ".xyz is not a file type"), ("s8", "no file type"),
                       ("nowhere/s.png", "directory")):
        line = refused(*run("synth", "--model", files / "missing.json", "--mask", files / "m.png", "--angle", 30,
                            "--out", files / out)[::2])
        assert f"--out {files / out}" in line and words in line, line
    assert sorted(p.name for p in files.iterdir()) == ["a.png", "deep.png", "m.png"]


@pytest.mark.parametrize("damage", ["truncated", "crc", "jpeg"])
def test_a_damaged_image_is_one_line_with_no_decoder_chatter(run, files, damage):
    good = (files / "a.png").read_bytes()
    if damage == "truncated":
        bad, words = files / "bad.png", "truncated PNG"
        bad.write_bytes(good[:len(good) // 2])
    elif damage == "crc":
        bad, words = files / "bad.png", "fails its CRC"
        bad.write_bytes(good[:100] + bytes(60) + good[160:])
    else:
        write_image(files / "a.jpg", read_image(files / "a.png"))
        jpeg = (files / "a.jpg").read_bytes()
        bad, words = files / "bad.jpg", "Premature end of JPEG file"  # libjpeg fills the rest with grey
        bad.write_bytes(jpeg[:len(jpeg) // 2])
    for argv in (("fit", bad), ("mask", bad, "--method", "kmeans", "--out", files / "o.png")):
        line = refused(*run(*argv)[::2])
        assert f"image {bad}" in line and words in line and "again" in line, line
    assert not (files / "o.png").exists()


def _fit(run, files, image, angle, *labels):
    code, out, err = run("fit", files / image, "--mask", files / "m.png", "--angle", angle, "--db", files / "p.db",
                         *labels, "--json")
    assert code == 0, err
    return json.loads(out)["stored"]


def test_captures_of_different_depths_are_never_blended(run, files):
    _fit(run, files, "a.png", 30)
    _fit(run, files, "deep.png", 60)
    for angle in ("45", "45,0"):
        line = refused(*run("synth", "--db", files / "p.db", "--mask", files / "m.png", "--angle", angle,
                            "--out", files / "s.png")[::2])
        assert "8-bit (30°)" in line and "16-bit (60°)" in line and "--scene" in line, line
    assert not (files / "s.png").exists()


def test_photographs_stored_under_their_own_scene_are_chosen_never_mixed(run, files):
    assert _fit(run, files, "a.png", 30, "--scene", "sand") == {
        "db": str(files / "p.db"), "robot": "host", "scene": "sand", "sequence": 0}
    _fit(run, files, "deep.png", 60, "--scene", "sand-16bit", "--robot", "cam2")
    base = ("synth", "--db", files / "p.db", "--mask", files / "m.png", "--angle", 45)
    line = refused(*run(*base, "--out", files / "s.png")[::2])
    assert "robot host scene sand (1 capture)" in line and "robot cam2 scene sand-16bit (1 capture)" in line
    code, _, err = run(*base, "--scene", "sand", "--out", files / "s.png")
    assert code == 0 and "60" not in err  # the nearest of its own scene's angles, not the other's
    assert read_image(files / "s.png").dtype == np.uint8
    with Store.open(files / "p.db", create=False) as s:
        assert sorted((c.robot, c.scene, c.levels) for c in s.captures()) == [("cam2", "sand-16bit", 65536),
                                                                              ("host", "sand", 256)]
    line = refused(*run("fit", files / "a.png", "--scene", "sand")[::2])
    assert "--db" in line


@pytest.mark.parametrize(("edit", "said"), [
    ("second model", "a second model of label 0 band 0; keep one"),
    ("half a label", "label 0.5 and band 0 must be whole numbers from 0"),
    ("band missing", "label 0 has no model of band(s) [1]"),
    ("angle 95", "angle 95: an elevation lies in 0..90 degrees"),
    ("--space", "--space: chooses among a database's captures (--db)"),
])
def test_a_hand_edited_models_document_is_refused_where_it_would_mislead(run, files, edit, said):
    """A model of one band given twice took the first's place silently, and the region's band
    came out one level; database-only options were ignored."""
    code, out, _ = run("fit", files / "a.png", "--mask", files / "m.png", "--json")
    doc = json.loads(out)
    first = doc["models"][0]
    assert (first["label"], first["band"]) == (0, 0)
    extra: tuple = ()
    if edit == "second model":
        doc["models"].append({**first, "xi": 200.0})
    elif edit == "half a label":
        first["label"] = 0.5
    elif edit == "band missing":
        doc["models"] = [m for m in doc["models"] if (m["label"], m["band"]) != (0, 1)]
    elif edit == "angle 95":
        doc["angle"] = 95
    else:
        extra = ("--space", "hsv")
    (files / "edited.json").write_text(json.dumps(doc))
    code, _, err = run("synth", "--model", files / "edited.json", "--mask", files / "m.png", "--out",
                       files / "s.png", *extra)
    assert said in refused(code, err) and not (files / "s.png").exists()
