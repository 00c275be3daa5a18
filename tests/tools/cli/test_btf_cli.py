"""`btf-host btf`: the BTF table with leave one out, as text, JSON and a plot; every error one line, status 2."""
import json

import pytest

from tests.support.btf_sweeps import curved_su, linear_normal, write_sweep
from tools.data.datasets import Angles, write_rendered
from tools.data.ingest import ingest
from tools.store.database import Store

ELEVATIONS = (20.0, 30.0, 45.0, 60.0, 75.0, 90.0)


@pytest.fixture
def two_sweeps(tmp_path):
    db = tmp_path / "s.db"
    write_sweep(db, linear_normal, ELEVATIONS, robot="7", scene="plate")
    write_sweep(db, curved_su, ELEVATIONS, robot="8", scene="grass", labels=(3,))
    return db


def test_json_gives_every_row_and_the_leave_one_out_figures_of_a_known_sweep(host, two_sweeps):
    code, out, err = host("btf", "--db", two_sweeps, "--json")
    assert code == 0, err
    docs = {d["scene"]: d for d in json.loads(out)["btfs"]}
    plate, grass = docs["plate"], docs["grass"]
    assert (plate["robot"], plate["varied"], plate["directions"]) == ("7", ["elevation"], 6)
    assert len(plate["rows"]) == 6 * 2 * 3 and len(grass["rows"]) == 6 * 3
    loo = plate["leave_one_out"]
    assert loo["summary"]["interior"] == 4 * 2 * 3 and loo["summary"]["interpolation_better"] == 24
    # linear in angle: the interpolation recovers the truth, the nearest angle misses it
    assert all(r["interpolated_l1"] < 1e-6 < 0.2 < r["nearest_l1"] for r in loo["rows"])
    assert grass["leave_one_out"]["summary"]["interpolation_better"] == 12
    row = next(r for r in plate["rows"] if r["interpolated_l1"] is not None)
    assert row["family"] == "SN" and row["nearest_angle"].endswith("°") and row["mean"] > row["sd"] > 0


def test_the_table_and_a_plot_of_one_robot_and_scene(host, two_sweeps, tmp_path):
    png = tmp_path / "btf.png"
    code, out, err = host("btf", "--db", two_sweeps, "--robot", "8", "--plot", png)
    assert code == 0, err
    lines = out.splitlines()
    assert lines[0].startswith("BTF of grass (robot 8, rgb, 256 levels): 6 direction(s)")
    assert "interpL1" in lines[1] and len(lines) == 2 + 18 + 2
    assert lines[-2].startswith("leave one out: interpolation beats the nearest measured angle at 12 of 12")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000


def test_a_rendered_dataset_over_view_and_light_angles(host, tmp_path):
    views = [Angles(el, az, lel, 0.0) for el in (30.0, 50.0, 70.0, 90.0) for az in (0.0, 90.0) for lel in (40.0, 70.0)]
    write_rendered(tmp_path / "data", "utia", views, size=(32, 40), seed=3)
    ingest(tmp_path / "data", "utia", tmp_path / "d.db", mask=tmp_path / "data" / "masks", workers=0)
    code, out, err = host("btf", "--db", tmp_path / "d.db", "--json")
    assert code == 0, err
    (doc,) = json.loads(out)["btfs"]
    assert doc["varied"] == ["elevation", "azimuth", "light_elevation"] and doc["directions"] == 16
    s = doc["leave_one_out"]["summary"]
    assert s["interior"] > 0 and all(r["why_not"] for r in doc["leave_one_out"]["rows"] if not r["interpolation_better"])


def _one_line_error(host, *argv):
    code, out, err = host(*argv)
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1, (code, out, err)
    return err


def test_every_error_is_one_line_and_status_2(host, two_sweeps, tmp_path):
    assert "no such database" in _one_line_error(host, "btf", "--db", tmp_path / "none.db")
    (tmp_path / "bad.db").write_bytes(b"not a database" * 20)
    assert "not an SQLite file" in _one_line_error(host, "btf", "--db", tmp_path / "bad.db")
    with Store.open(tmp_path / "empty.db"):
        pass
    assert "no captures" in _one_line_error(host, "btf", "--db", tmp_path / "empty.db")
    err = _one_line_error(host, "btf", "--db", two_sweeps, "--robot", "9")
    assert "no captures of robot 9" in err and "robot 7 scene plate" in err
    assert "no captures of scene x" in _one_line_error(host, "btf", "--db", two_sweeps, "--scene", "x")
    assert "draws one robot and scene" in _one_line_error(host, "btf", "--db", two_sweeps, "--plot", tmp_path / "p.png")
    assert "PNG" in _one_line_error(host, "btf", "--db", two_sweeps, "--robot", "7", "--plot", tmp_path / "p.svg")
    (tmp_path / "old.png").write_bytes(b"x")
    assert "--force" in _one_line_error(host, "btf", "--db", two_sweeps, "--robot", "7", "--plot", tmp_path / "old.png")
    assert "--space: invalid choice" in _one_line_error(host, "btf", "--db", two_sweeps, "--space", "cmyk")
    assert "no captures in feature space hsv" in _one_line_error(host, "btf", "--db", two_sweeps, "--space", "hsv")
