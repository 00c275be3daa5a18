"""The BTF panel's data without a browser: the query checked, the chosen sweep's points, curve and
leave one out, and GET /api/btf behind the page's token."""
import json

import pytest

from tests.support.btf_sweeps import curved_su, linear_normal, write_sweep
from tests.support.station_rig import request, served
from tools.page.btf_panel import panel
from tools.page.data import btf_query as parse_query

ELEVATIONS = (20.0, 35.0, 50.0, 65.0, 80.0)


def test_the_query_is_checked():
    assert parse_query({"robot": "7", "scene": "", "label": "2", "band": "0"}) == {
        "robot": "7", "scene": "", "space": None, "label": 2, "band": 0}
    assert parse_query({}) == {"robot": None, "scene": None, "space": None, "label": None, "band": None}
    for bad in ({"label": "-1"}, {"band": "x"}, {"label": "12345678"}):
        with pytest.raises(ValueError):
            parse_query(bad)


def test_the_panel_shows_the_newest_sweep_or_the_chosen_one(tmp_path):
    db = tmp_path / "s.db"
    write_sweep(db, linear_normal, ELEVATIONS, robot="7", scene="plate")
    write_sweep(db, curved_su, ELEVATIONS[:3], robot="8", scene="grass", labels=(3,))
    newest = panel(str(db), parse_query({}))
    assert (newest["robot"], newest["scene"], newest["points"], newest["label"], newest["band"]) == ("8", "grass", 3, 3, 0)
    assert [s["robot"] for s in newest["sources"]] == ["7", "8"]
    (series,) = newest["series"]
    assert [p["seq"] for p in series["points"]] == [1, 2, 3] and len(series["curve"]) > 3
    assert newest["loo"]["summary"]["interior"] == 1
    plate = panel(str(db), parse_query({"robot": "7", "scene": "plate", "space": "rgb", "label": "2", "band": "1"}))
    assert (plate["label"], plate["band"], plate["band_name"], plate["points"]) == (2, 1, "G", 5)
    s = plate["loo"]["summary"]
    assert (s["interior"], s["interpolation_better"]) == (3, 3) and s["interpolated_mean_l1"] < 1e-6 < s["nearest_mean_l1"]
    assert "no captures of robot 9" in panel(str(db), parse_query({"robot": "9"}))["empty"]


def test_the_endpoint_needs_the_token_and_answers_a_bad_query_in_one_line(rig):  # noqa: F811
    write_sweep(rig.db, linear_normal, ELEVATIONS, robot="7", scene="plate")
    station, host, port, token = served(rig)
    assert request(host, port, "GET", "/api/btf")[0] == 401
    status, _, body = request(host, port, "GET", "/api/btf?label=x", headers={"X-BTF-Token": token})
    assert status == 400 and "label" in json.loads(body)["error"]
    status, _, body = request(host, port, "GET", "/api/btf", headers={"X-BTF-Token": token})
    assert status == 200 and json.loads(body)["points"] == 5
    assert rig.stop(station) == 0
