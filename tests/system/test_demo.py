"""The end-to-end demo at reduced size: robots over a pty and a lossy radio, and the bars."""
from pathlib import Path

import pytest

from radio.link import Link
from tests.support.browser import report_layout
from tools.demo.end_to_end import DemoConfig, run_demo


@pytest.fixture(scope="module")
def first_run(tmp_path_factory):
    """The demo's result, its report page, a copy of its database and a copy of its report folder,
    taken before a later test runs the demo again there."""
    import shutil
    import sqlite3

    out = tmp_path_factory.mktemp("demo")
    res = run_demo(out, DemoConfig(size=(48, 64), elevations=(30.0, 40.0, 50.0, 60.0)), progress=False)
    copy = tmp_path_factory.mktemp("demo-db") / "scene.db"
    with sqlite3.connect(res.db) as src, sqlite3.connect(copy) as dst:
        src.backup(dst)
    report = shutil.copytree(out / "report", tmp_path_factory.mktemp("demo-report") / "report")
    return res, (out / "report" / "index.html").read_text(), copy, report


@pytest.fixture(scope="module")
def result(first_run):
    return first_run[0]


def test_every_pose_of_every_plate_crossed_the_lossy_link_into_the_database(result):
    assert result.captures == {"black": 5, "white": 5, "mixed": 5}
    assert result.link["delivered"] >= 15
    assert (Path(result.db).parent / "report" / "index.html").is_file()


def test_mixed_plate_reproduction_reaches_95_percent_of_the_two_seed_ceiling(result):
    assert len(result.mixed) == 4
    for row in result.mixed:
        for band, value in row["synthetic"].items():
            assert value >= 0.95 * row["ceiling"][band], (row["angle"], band)


def test_unseen_angle_interpolation_beats_the_nearest_angle_and_stays_near_its_own_fit(result):
    for plate, u in result.unseen.items():
        assert u["interpolated"] <= 1.5 * u["fitted"], plate
        assert u["interpolated"] < u["nearest"], plate


def test_johnson_has_the_lowest_histogram_error_of_its_peers(result):
    for scene, t in result.pdfs.items():
        assert t["johnson"] < min(t["gaussian"], t["uniform"], t["weibull"]), scene


def test_table1_covers_every_mask_method_in_both_spaces(result):
    assert {(r["method"], r["space"]) for r in result.table1} == {
        (m, s) for m in ("true", "isodata5", "isodata8", "kmeans", "felzenszwalb") for s in ("rgb", "hsv")}
    assert all(-1.0 <= v <= 1.0 for r in result.table1 for v in r["correlation"].values())


def test_the_report_shows_a_btf_section_per_scene_with_its_leave_one_out_table(first_run):
    page = first_run[1]
    assert page.index("BTF: the models against angle") < page.index("Captures per angle")
    for scene in ("black", "white", "mixed"):
        assert f"BTF of {scene} (robot" in page
    # 5 elevations: 40, 45 and 50 have measured neighbours on both sides
    assert page.count("<table class=loo>") == 3 and page.count("Leave one out: the interpolation beats") == 3


def test_the_demos_report_opens_on_its_bars_tables_and_link_and_every_capture_names_its_pose(first_run):
    result, page, _, report = first_run
    got = report_layout(report / "index.html")
    assert 0 <= got["summary"] < got["bars"] <= 900  # a 1400x900 window's first screen
    shown = {h.split(":")[0]: bottom for h, bottom in got["heads"]}
    assert max(shown["Table 1"], shown["Table 2"], shown["The link"]) <= 900, shown
    assert got["summary"] < got["toc"] < got["capture"]
    assert all(natural == width for natural, width in got["plots"])
    bars = page[page.index("<ul class=bars>"):page.index("</ul>")]
    assert bars.count("<li class=ok>") == sum(result.bars().values()) == 3
    assert page.count("<p class=source>robot ") == sum(result.captures.values()) and "`" not in page


def test_the_demos_interpolation_beats_the_nearest_angle_or_says_why(host, first_run):
    import json

    code, out, err = host("btf", "--db", first_run[2], "--json")
    assert code == 0, err
    docs = {d["scene"]: d for d in json.loads(out)["btfs"]}
    assert set(docs) == {"black", "white", "mixed"}
    for scene, doc in docs.items():
        s, rows = doc["leave_one_out"]["summary"], doc["leave_one_out"]["rows"]
        assert s["interior"] == 3 * 3 * (2 if scene == "mixed" else 1), scene
        assert s["interpolation_better"] > s["interior"] / 2 and s["interpolated_mean_l1"] < s["nearest_mean_l1"], s
        assert all(r["why_not"] for r in rows if not r["interpolation_better"])


def test_the_demos_export_reads_back_one_row_per_stored_model(host, first_run, tmp_path):
    duckdb = pytest.importorskip("duckdb")
    pd = pytest.importorskip("pandas")
    import pyarrow.dataset as ds

    from tools.store.database import Store

    db = first_run[2]
    assert host("export", "--db", db, "--out", tmp_path / "x")[0] == 0
    with Store.open(db) as store:
        truth = {(c.robot, c.id, lab, b): (r.model.family.value, r.model.gamma, r.model.delta, r.model.xi,
                                           r.model.lam, r.count) for c in store.captures()
                 for (lab, b), r in store.models(c.id).items()}
    assert len(truth) == 5 * (3 + 3 + 6)
    tables = {"pyarrow": ds.dataset(tmp_path / "x", partitioning="hive").to_table().to_pylist(),
              "duckdb": duckdb.sql(f"SELECT * FROM read_parquet('{tmp_path}/x/**/*.parquet', hive_partitioning = true,"
                                   " hive_types_autocast = false)").df().to_dict("records"),
              "pandas": pd.read_parquet(tmp_path / "x").to_dict("records")}
    for name, rows in tables.items():
        got = {(str(r["robot"]), r["capture_id"], r["label"], r["band"]):
               (r["family"], r["gamma"], r["delta"], r["xi"], r["lam"], r["pixels"]) for r in rows}
        assert len(rows) == len(truth) and got == truth, name


def test_a_second_run_in_the_same_directory_starts_from_fresh_robot_state(result):
    # Robot state left by the first run (replay counters, outbox) must not reach the second.
    out = Path(result.db).parent
    again = run_demo(out, DemoConfig(size=(48, 64), elevations=(30.0, 60.0)), progress=False)
    assert again.captures == {"black": 3, "white": 3, "mixed": 3}
    assert all(again.bars().values())


def test_a_robot_that_dies_is_reported_with_the_last_lines_of_its_stderr(tmp_path, monkeypatch):
    import tools.demo.end_to_end as demo
    from radio.keys import write_key
    from tools.store.database import Store

    def broken(work, scene, robot_id, size):
        path = work / f"robot-{scene}.toml"
        path.write_text('robot_id = 1\nno_such_setting = 3\n[link]\nkey_file = "robot.key"\n')
        return path

    monkeypatch.setattr(demo, "_robot_config", broken)
    write_key(tmp_path / "robot.key")
    with Store.open(tmp_path / "s.db") as store, pytest.raises(RuntimeError) as err:
        demo.sweep_robots(tmp_path, ["black"], store, DemoConfig(robot_timeout_s=20), [30.0])
    assert "black exited early" in str(err.value) and "no_such_setting" in str(err.value)


def test_report_and_console_state_the_same_run_time(first_run):
    from tools.cli.demo import _summary

    result, page = first_run[:2]
    console = "\n".join(_summary(result))
    stated = f"run time {result.seconds:.1f} s"
    assert stated in console and stated in page.lower()


def test_retransmissions_count_both_ends(result):
    link = result.link
    assert link["retransmissions"] == link["retransmissions_robot"] + link["retransmissions_host"]


def test_resends_read_off_the_byte_stream_match_the_links_own_count():
    """Two links over a channel that drops every fourth frame each way; the counter on each
    end's bytes agrees with that end's own retransmission count."""
    from radio.auth import MemoryCounterStore
    from radio.frame import Deframer
    from tools.demo.end_to_end import Resends

    key = bytes(range(32))
    robot = Link(1, 2, 1, key, MemoryCounterStore(), heartbeat=0.2)
    host = Link(2, 1, 1, key, MemoryCounterStore(), heartbeat=0.2)
    for k in range(40):
        robot.send(bytes([k]) * 300, 0.0)
    host.send(b"command" * 40, 0.0)
    taps = {"robot": Resends(key), "host": Resends(key)}
    frames = {"robot": 0, "host": 0}

    def lossy(end: str, data: bytes) -> bytes:
        taps[end].feed(data)
        kept = []
        for body in Deframer(4096).feed(data):
            frames[end] += 1
            if frames[end] % 4:
                kept.append(b"\x00" + body + b"\x00")
        return b"".join(kept)

    t = 0.0
    while t < 60.0 and not (robot.idle and host.idle):
        host.receive(lossy("robot", robot.poll(t)), t)
        robot.receive(lossy("host", host.poll(t)), t)
        t += 0.01
    assert robot.idle and host.idle
    assert robot.stats().retransmissions > 5
    assert taps["robot"].count == robot.stats().retransmissions
    assert taps["host"].count == host.stats().retransmissions
