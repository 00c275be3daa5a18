"""The host CLI never surprises: outputs never clobber inputs or files, angles are checked,
"stored" means stored, damaged images can be skipped, a database's robots and scenes are
chosen, pipes close quietly, and start-up loads no heavy library."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from btf.fit.fitter import FrameFitter
from tests.support import ROOT
from tests.support.images import plate
from tools.data.images import read_image, read_mask, write_image, write_mask
from tools.store.database import Store


@pytest.fixture
def files(tmp_path):
    img, mask = plate(0)
    write_image(tmp_path / "a.png", img)
    write_mask(tmp_path / "m.png", mask)
    return tmp_path


def one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


# --- --out -------------------------------------------------------------------------------
def test_mask_out_never_overwrites_its_input_image(run, files):
    before = (files / "a.png").read_bytes()
    for extra in ((), ("--force",)):
        code, _, err = run("mask", files / "a.png", "--method", "kmeans", "--k", 2, "--out", files / "a.png", *extra)
        assert code == 2 and "input" in one_line(err)
        assert (files / "a.png").read_bytes() == before


def test_mask_out_refuses_an_existing_file_unless_forced(run, files):
    target = files / "o.png"
    target.write_bytes(b"precious")
    code, _, err = run("mask", files / "a.png", "--method", "kmeans", "--k", 2, "--out", target)
    assert code == 2 and "exists" in one_line(err) and "--force" in err
    assert target.read_bytes() == b"precious"
    assert run("mask", files / "a.png", "--method", "kmeans", "--k", 2, "--out", target, "--force")[0] == 0
    assert read_mask(target).shape == (60, 80)


def test_synth_out_refuses_its_mask_its_models_and_an_existing_file(run, files):
    code, out, _ = run("fit", files / "a.png", "--mask", files / "m.png", "--json")
    (files / "models.json").write_text(out)
    base = ("synth", "--model", files / "models.json", "--mask", files / "m.png", "--angle", 30)
    for target in ("m.png", "models.json"):
        before = (files / target).read_bytes()
        code, _, err = run(*base, "--out", files / target, "--force")
        assert code == 2 and "input" in one_line(err)
        assert (files / target).read_bytes() == before
    (files / "s.png").write_bytes(b"keep me")
    code, _, err = run(*base, "--out", files / "s.png")
    assert code == 2 and "exists" in one_line(err)
    assert (files / "s.png").read_bytes() == b"keep me"
    assert run(*base, "--out", files / "s.png", "--force")[0] == 0
    assert read_image(files / "s.png").shape == (60, 80, 3)


def test_report_out_refuses_a_directory_holding_a_report_unless_forced(run, files):
    db = files / "x.db"
    assert run("fit", files / "a.png", "--angle", 30, "--db", db)[0] == 0
    assert run("report", "--db", db, "--out", files / "rep", "--quiet")[0] == 0
    page = files / "rep" / "index.html"
    page.write_text("edited by hand")
    code, _, err = run("report", "--db", db, "--out", files / "rep", "--quiet")
    assert code == 2 and "exists" in one_line(err) and page.read_text() == "edited by hand"
    assert run("report", "--db", db, "--out", files / "rep", "--quiet", "--force")[0] == 0
    assert "btfscout report" in page.read_text()
    code, _, err = run("report", "--db", db, "--out", files / "a.png", "--quiet")
    assert code == 2 and "not a directory" in one_line(err)


def test_demo_out_refuses_a_directory_that_is_not_a_demo_output(run, tmp_path):
    (tmp_path / "work").mkdir()
    (tmp_path / "work" / "thesis.tex").write_text("years of work")
    (tmp_path / "notes.txt").write_text("mine")
    code, _, err = run("demo", "--out", tmp_path, "--quiet")
    assert code == 2 and "--force" in one_line(err)
    assert (tmp_path / "work" / "thesis.tex").read_text() == "years of work"


# --- angles and what is stored -------------------------------------------------------------
@pytest.mark.parametrize("angle, words", [("nan", "finite"), ("inf", "finite"), ("200", "0..90"),
                                          ("-45", "0..90")])
def test_fit_refuses_angles_that_are_not_elevations_and_stores_nothing(run, files, angle, words):
    db = files / "x.db"
    code, out, err = run("fit", files / "a.png", f"--angle={angle}", "--db", db)
    assert code == 2 and words in one_line(err) and "stored" not in out
    if db.exists():
        with Store.open(db, create=False) as s:
            assert s.captures() == []


@pytest.mark.parametrize("angle", ["95", "-1", "60,0,120,0", "nan,0"])
def test_synth_refuses_elevations_outside_the_hemisphere(run, files, angle):
    code, out, _ = run("fit", files / "a.png", "--mask", files / "m.png", "--json")
    (files / "models.json").write_text(out)
    code, _, err = run("synth", "--model", files / "models.json", "--mask", files / "m.png",
                       f"--angle={angle}", "--out", files / "s.png")
    assert code == 2 and ("0..90" in one_line(err) or "finite" in err)
    assert not (files / "s.png").exists()


def test_fit_says_stored_only_for_a_capture_it_stored(run, files, monkeypatch):
    db = files / "x.db"
    assert run("fit", files / "a.png", "--angle", 30, "--db", db)[0] == 0
    # Another writer took the sequence between our look-up and our insert.
    monkeypatch.setattr(Store, "next_sequence", lambda self, robot: 0)
    code, out, err = run("fit", files / "a.png", "--angle", 40, "--db", db, "--json")
    assert code == 2 and "not stored" in one_line(err)
    assert "stored" not in out
    with Store.open(db, create=False) as s:
        assert [c.elevation for c in s.captures()] == [30.0]


@pytest.mark.parametrize("argv, words", [
    (("--method", "slic", "--segments", "0"), "--segments"),
    (("--method", "slic", "--segments", "-3"), "--segments"),
    (("--method", "felzenszwalb", "--scale", "0"), "--scale"),
    (("--method", "felzenszwalb", "--scale", "nan"), "--scale"),
])
def test_mask_parameters_out_of_range_are_one_line(run, files, argv, words):
    code, _, err = run("mask", files / "a.png", *argv, "--out", files / "o.png")
    assert code == 2 and words in one_line(err)
    assert not (files / "o.png").exists()


# --- pipes ---------------------------------------------------------------------------------
def test_decode_into_a_pipe_closed_early_exits_quietly(tmp_path):
    """`btf-host decode ... | head -3`: no BrokenPipeError traceback, no 'Exception ignored'."""
    from radio.auth import MemoryCounterStore
    from radio.keys import load_key, write_key
    from radio.link import Link

    key = load_key(write_key(tmp_path / "k.key"))
    robot = Link(1, 2, 1, key, MemoryCounterStore(), heartbeat=0.001)
    stream = b"".join(robot.poll(i * 0.01) for i in range(4000))  # SYNs and heartbeats: one JSON line each
    (tmp_path / "s.bin").write_bytes(stream)
    proc = subprocess.Popen([sys.executable, "-c", "import sys; from tools.cli import main; sys.exit(main())",
                             "decode", str(tmp_path / "s.bin"), "--no-auth"],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    head = [proc.stdout.readline() for _ in range(3)]
    proc.stdout.close()  # what head does after three lines
    _, err = proc.communicate(timeout=60)
    assert all(json.loads(line)["frame"] == i for i, line in enumerate(head))
    assert err == b"", err.decode()
    assert proc.returncode == 141  # 128 + SIGPIPE, as a shell tool killed by the pipe


# --- ingest --keep-going ---------------------------------------------------------------------
def test_ingest_keep_going_skips_damaged_images_and_names_them_at_the_end(run, tmp_path):
    from tools.data.datasets import Angles, write_rendered

    views = [Angles(el, 0.0, 50.0, 0.0) for el in (30.0, 45.0, 60.0, 75.0, 90.0)]
    write_rendered(tmp_path / "d", "utia", views, size=(24, 24))
    pngs = sorted((tmp_path / "d").glob("*.png"))
    pngs[1].write_bytes(b"not a png")
    pngs[3].write_bytes(pngs[3].read_bytes()[:60])  # truncated
    db = tmp_path / "x.db"
    code, _, err = run("ingest", tmp_path / "d", "--layout", "utia", "--db", db, "--workers", 0, "--quiet")
    assert code == 2 and pngs[1].name in one_line(err)
    code, out, err = run("ingest", tmp_path / "d", "--layout", "utia", "--db", db, "--workers", 0,
                         "--keep-going", "--quiet")
    assert code == 1
    lines = err.strip().splitlines()
    assert lines[-1].startswith("btf-host: 2 damaged image(s) skipped")
    assert any(pngs[1].name in line for line in lines) and any(pngs[3].name in line for line in lines)
    assert "2 image(s) stored, 1 already there, 2 damaged" in out  # the first run kept the image before
    with Store.open(db, create=False) as s:
        assert sorted(c.source for c in s.captures()) == sorted(p.name for i, p in enumerate(pngs) if i not in (1, 3))


def test_ingest_keep_going_skips_an_image_the_masks_folder_has_no_mask_for(run, tmp_path):
    from tools.data.datasets import Angles, write_rendered

    write_rendered(tmp_path / "d", "utia", [Angles(el, 0.0, 50.0, 0.0) for el in (30.0, 60.0, 90.0)], size=(24, 24))
    pngs = sorted((tmp_path / "d").glob("*.png"))
    (tmp_path / "masks").mkdir()
    for p in pngs[:2]:  # the last image has none
        write_mask(tmp_path / "masks" / p.name, np.zeros((24, 24), np.uint8))
    argv = ("ingest", tmp_path / "d", "--layout", "utia", "--mask", tmp_path / "masks", "--db", tmp_path / "x.db",
            "--workers", 0, "--quiet")
    code, _, err = run(*argv)
    assert code == 2 and "masks folder has none for " + pngs[2].name in one_line(err)
    code, out, err = run(*argv, "--keep-going")
    assert code == 1 and "2 image(s) stored" in out and err.strip().splitlines()[-1].startswith("btf-host: 1 damaged")
    with Store.open(tmp_path / "x.db", create=False) as s:
        assert sorted(c.source for c in s.captures()) == [p.name for p in pngs[:2]]


# --- --robot / --scene -------------------------------------------------------------------------
def _two_scene_db(path: Path) -> Path:
    """Robot 1 measured a dark plate, robot 2 a bright one, both at 30 and 60 degrees."""
    with Store.open(path) as s:
        for robot, scene, level in (("1", "dark", 60), ("2", "bright", 190)):
            for seq, angle in enumerate((30.0, 60.0)):
                rng = np.random.default_rng(seq)
                img = np.clip(rng.normal(level, 8, (30, 40, 3)), 0, 255).astype(np.uint8)
                f = FrameFitter(1, 3)
                f.add(img, np.zeros((30, 40), np.int64))
                s.add_capture(robot, seq, 1.0 + seq, None, (angle, 0.0), "rgb", ("R", "G", "B"), f.fit(),
                              scene=scene)
    return path


def test_synth_db_lists_the_robots_and_scenes_when_the_choice_is_ambiguous(run, tmp_path):
    db = _two_scene_db(tmp_path / "two.db")
    write_mask(tmp_path / "m.png", np.zeros((20, 20), np.uint8))
    base = ("synth", "--db", db, "--mask", tmp_path / "m.png", "--angle", 45)
    code, _, err = run(*base, "--out", tmp_path / "x.png")
    line = one_line(err)
    assert code == 2 and "--robot" in line and "--scene" in line
    assert "robot 1 scene dark (2 captures)" in line and "robot 2 scene bright (2 captures)" in line
    assert run(*base, "--scene", "bright", "--out", tmp_path / "b.png")[0] == 0
    assert run(*base, "--robot", "1", "--out", tmp_path / "d.png")[0] == 0
    assert read_image(tmp_path / "b.png").mean() > 150 > 100 > read_image(tmp_path / "d.png").mean()
    code, _, err = run("synth", "--db", db, "--mask", tmp_path / "m.png", "--angle", "45,0", "--scene", "dark",
                       "--out", tmp_path / "e.png")
    assert code == 0, err
    code, _, err = run(*base, "--scene", "grass", "--out", tmp_path / "g.png")
    assert code == 2 and "no captures" in one_line(err) and "scene bright" in err


def test_report_filters_by_robot_and_scene_and_says_what_holds_none(run, tmp_path):
    db = _two_scene_db(tmp_path / "two.db")
    code, out, err = run("report", "--db", db, "--out", tmp_path / "r", "--scene", "bright", "--quiet")
    assert code == 0, err
    page = (tmp_path / "r" / "index.html").read_text()
    assert "bright" in page and "dark" not in page
    code, _, err = run("report", "--db", db, "--out", tmp_path / "q", "--robot", "7", "--quiet")
    assert code == 2 and "robot 1 scene dark" in one_line(err)


def test_report_shows_progress_draws_one_region_whole_and_notes_captures_it_cannot_draw(run, tmp_path):
    db = _two_scene_db(tmp_path / "two.db")  # one region each, no masks: drawn over the whole image
    with Store.open(db) as s:  # two regions and no label map: nothing says where each lies
        labels = np.zeros((30, 40), np.int64)
        labels[:, 20:] = 1
        f = FrameFitter(2, 3)
        f.add(np.random.default_rng(5).integers(0, 256, (30, 40, 3), dtype=np.uint8), labels)
        s.add_capture("3", 0, 1.0, None, (45.0, 0.0), "rgb", ("R", "G", "B"), f.fit(), scene="halves")
    code, _, err = run("report", "--db", db, "--out", tmp_path / "r")
    assert code == 0
    assert "5/5" in err  # the progress bar over the captures
    page = (tmp_path / "r" / "index.html").read_text()
    section = page[page.index("<h2>Synthetic beside measured</h2>"):]
    assert section.count("the whole image is region 0") == 4
    assert len(list((tmp_path / "r").glob("*_synthetic.png"))) == 4
    assert "1 capture(s) without a label mask are not shown" in section


# --- start-up ----------------------------------------------------------------------------------
HEAVY = ("scipy", "matplotlib", "skimage", "cv2", "tqdm", "dask", "distributed")


@pytest.mark.parametrize("argv", [["--help"], ["resolve"], ["resolve", "--grain-mm", "1", "--pixel-mm", "5"],
                                  ["resolve", "--help"], ["fit", "--help"]])
def test_help_and_resolve_load_no_heavy_library(argv):
    code = ("import contextlib, io, sys\n"
            "from tools.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            "    try:\n"
            f"        rc = main({argv!r})\n"
            "    except SystemExit as e:\n"
            "        rc = e.code\n"
            f"heavy = sorted({{m.split('.')[0] for m in sys.modules}} & set({HEAVY!r}))\n"
            "print(rc, ' '.join(heavy))\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=60)
    rc, *heavy = out.stdout.split()
    assert rc in ("0", "None") and heavy == [], out.stdout + out.stderr


def test_report_synthesizes_captures_whose_mask_fit_stored(run, files):
    db = files / "x.db"
    assert run("fit", files / "a.png", "--mask", files / "m.png", "--angle", 30, "--db", db)[0] == 0
    assert run("report", "--db", db, "--out", files / "rep", "--quiet")[0] == 0
    assert len(list((files / "rep").glob("*_synthetic.png"))) == 1
    assert "no capture has a label mask" not in (files / "rep" / "index.html").read_text()


def test_the_parsers_feature_spaces_are_the_images_module_s():
    from tools.cli.options import FEATURE_SPACES
    from tools.data.images import SPACES

    assert FEATURE_SPACES == SPACES
