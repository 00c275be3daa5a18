"""The report leads with its results: the summary (a demo's bars with their figures, Tables 1 and 2,
the link) before the contents and every other section, long tables folded, plots shown at the
size they are drawn, each capture's source named, and no literal backticks; the first screen of a
1400x900 browser shows the summary."""
import re

import numpy as np
import pytest

from radio.channel import ChannelConfig
from tests.support.browser import report_layout
from tests.support.packets import filled_database
from tools.data.datasets import Angles, write_rendered
from tools.data.images import read_image
from tools.data.ingest import ingest
from tools.demo.end_to_end import DemoResult
from tools.report.capture_views import Frames
from tools.report.document import write_report
from tools.store.database import Store


def demo_result(db, missed_angle=None):
    """A demo's result as run_demo fills it; `missed_angle` makes the mixed plate miss its bar there."""
    mixed = [{"angle": a, "synthetic": {b: 0.9 for b in "RGB"}, "ceiling": {b: 0.91 for b in "RGB"}}
             for a in (30.0, 60.0)]
    if missed_angle is not None:
        next(r for r in mixed if r["angle"] == missed_angle)["synthetic"]["G"] = 0.5
    return DemoResult(
        db, link={"delivered": 40, "lost": 6, "corrupted": 2, "retransmissions": 7, "retransmissions_robot": 5,
                  "retransmissions_host": 2, "duplicates": 1, "rejected": 2, "skipped": 0},
        captures={"mixed": 2}, mixed=mixed,
        unseen={"mixed": {"fitted": 0.3, "interpolated": 0.33, "nearest": 0.5, "lo": 40.0, "hi": 50.0}},
        pdfs={s: {"johnson": 0.2, "gaussian": 0.4, "uniform": 3.0, "weibull": 0.7, "lognormal": 0.5}
              for s in ("mixed", "field")},
        table1=[{"method": m, "space": sp, "regions": 4, "correlation": dict(zip(bands, (0.81, 0.82, 0.83)))}
                for sp, bands in (("rgb", "RGB"), ("hsv", "HSV")) for m in ("true", "kmeans")],
        seconds=12.5, channel=ChannelConfig(loss=0.05, ber=2e-5))


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    """A demo's report of a small database (written once: the tests only read it)."""
    where = tmp_path_factory.mktemp("report")
    db = filled_database(where / "scene.db")
    with Store.open(db) as s:
        return write_report(s, where / "rep", demo=demo_result(db, missed_angle=60.0))


def test_the_summary_comes_first_then_the_contents_then_the_sections_it_links(report):
    html = report.read_text()
    order = [html.index(k) for k in ("<section id=summary", "<nav class=toc", "<section id=btf",
                                     "<section id=captures", "<section id=images", "<div class=capture")]
    assert order == sorted(order)
    summary = html[order[0]:order[1]]
    for heading in ("Table 1: correlation per band", "Table 2: total histogram error", "The link"):
        assert heading in summary
    # every contents link leads to a section of the page
    toc = html[order[1]:html.index("</nav>")]
    anchors = re.findall(r"href=#([\w-]+)", toc)
    assert {"summary", "btf", "captures", "images"} <= set(anchors)
    assert all(f"id={a}>" in html or f"id={a} " in html for a in anchors)


def test_each_bar_says_met_or_missed_with_the_figure_that_decides_it(report):
    html = report.read_text()
    bars = html[html.index("<ul class=bars>"):html.index("</ul>")]
    mixed, unseen, johnson = re.findall(r"<li class=(\w+)>(.*?)</li>", bars)
    assert mixed[0] == "bad" and "missed" in mixed[1] and "0.549 at 60.0° band G" in mixed[1]  # 0.5 / 0.91
    assert unseen[0] == "ok" and "at most 1.100 (mixed)" in unseen[1]  # 0.33 / 0.3
    assert johnson[0] == "ok" and "lowest in 2 of 2 scenes" in johnson[1]
    assert "40" in html[html.index("packets delivered"):html.index("The database")]  # the link's figures


def test_long_tables_are_folded_under_a_line_saying_what_they_hold_and_no_backtick_is_left(report):
    html = report.read_text()
    for what in ("Captures per angle: 2 capture(s)", "Models: ", "Mixed plate reproduction per angle"):
        assert re.search(r"<details><summary>" + re.escape(what), html), what
    models = html[html.index("<summary>Models: "):]
    assert models.index("</summary>") < models.index("<table") < models.index("</details>")
    assert "`" not in html and "<code>synth --angle</code>" in html


def test_a_robot_capture_names_its_robot_sequence_and_pose(report):
    html = report.read_text()
    sources = re.findall(r"<p class=source>([^<]*)", html)
    assert len(sources) == 2
    assert sources[0].startswith("robot 3, sequence 1") and "pose elevation 50.20°, azimuth 0.10°" in sources[0]
    assert "(commanded 50.0° / 0.0°)" in sources[0]


def test_an_unmasked_ingest_is_drawn_as_one_region_over_its_image_and_names_its_file(tmp_path):
    data = tmp_path / "plates"
    write_rendered(data, "utia", [Angles(60.0, 0.0), Angles(30.0, 0.0)], size=(24, 32), masks=False)
    ingest(data, "utia", tmp_path / "ds.db", workers=0, dependence=False)
    with Store.open(tmp_path / "ds.db") as s:
        html = write_report(s, tmp_path / "rep", measured=Frames()).read_text()
        caps = s.captures()
    sources = re.findall(r"<p class=source>([^<]*)", html)
    assert len(sources) == 2
    for cap, line in zip(caps, sources):
        assert f"file {data.resolve() / cap.source}; dataset plates, item {cap.source}" in line
        assert "the whole image is region 0" in line
    synthetic = sorted((tmp_path / "rep").glob("*_synthetic.png"))
    assert len(synthetic) == 2 and all(read_image(p).shape == (24, 32, 3) for p in synthetic)


def test_captures_of_several_regions_without_a_mask_are_noted_with_the_commands_as_code(tmp_path):
    from btf.fit.fitter import FrameFitter

    labels = np.zeros((20, 30), np.int64)
    labels[:, 15:] = 1
    f = FrameFitter(2, 3)
    f.add(np.random.default_rng(1).integers(0, 256, (20, 30, 3), dtype=np.uint8), labels)
    with Store.open(tmp_path / "s.db") as s:
        s.add_capture("4", 1, 0.0, None, (40.0, 0.0), "rgb", ("R", "G", "B"), f.fit(), scene="halves")
        html = write_report(s, tmp_path / "rep").read_text()
    assert "no capture has a label mask" in html and "<code>fit --mask</code>" in html and "`" not in html


def test_the_first_screen_of_a_1400_by_900_browser_shows_the_summary(report):
    got = report_layout(report)
    assert 0 <= got["summary"] < got["bars"] <= 900
    tables = {h: bottom for h, bottom in got["heads"] if h.startswith(("Table 1", "Table 2", "The link"))}
    assert len(tables) == 3 and max(tables.values()) <= 900, tables
    assert got["summary"] < got["toc"] < got["capture"]
    # every plot is shown at the size it was drawn: its text as legible as drawn
    assert got["plots"] and all(natural == shown for natural, shown in got["plots"]), got["plots"]
