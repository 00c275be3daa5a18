"""Station events are typed records, one declaration per kind: their JSON form (the log file, the
control socket, watch, the page) and the line a person reads come from that declaration."""
import dataclasses
import io
import json

from tools.cli.watch import summary
from tools.station import events as ev
from tools.station.log import StationLog
from tools.station.snapshot import StationSnapshot


def test_every_kind_has_one_declaration_and_its_json_form_names_its_fields():
    assert set(ev.KINDS) == {"capture", "unchanged", "mask", "status", "failsafe", "log", "other", "bad", "command",
                             "answer", "link", "rejected", "station", "lost"}
    for kind, cls in ev.KINDS.items():
        js = cls(1_700_000_000.25, "said").to_json()
        fields = {f.name for f in dataclasses.fields(cls)} - {"t", "text"}
        assert js["kind"] == kind and js["time"] == "2023-11-14T22:13:20Z" and js["t"] == 1_700_000_000.25
        assert js["text"] == "said" and fields <= set(js) and js["tone"] in ("", "ok", "bad")
        assert kind in ev.schema()


def test_tone_and_shown_are_the_events_own():
    assert ev.AnswerEvent(0.0, "x", ok=True).to_json()["tone"] == "ok"
    assert ev.AnswerEvent(0.0, "x", ok=False).to_json()["tone"] == "bad"
    assert ev.LinkEvent(0.0, "up", up=True).to_json()["tone"] == "ok"
    assert ev.LinkEvent(0.0, "stale", up=True, stale=True).to_json()["tone"] == "bad"
    assert ev.StationEvent(0.0, "failed: x", failed=True).to_json()["tone"] == "bad"
    assert ev.RefusedEvent(0.0, "refused", msg_id=4).to_json()["tone"] == "bad"
    poll = ev.StatusEvent(0.0, "the robot's report", poll=True).to_json()
    assert poll["shown"] is False and "shown" not in ev.StatusEvent(0.0, "boot").to_json()


def test_the_log_writes_the_json_form_and_one_line_a_person_reads(tmp_path):
    err = io.StringIO()
    log = StationLog(tmp_path / "x.log", echo=err)
    log.write(ev.CaptureEvent(10.0, "robot 1 seq 2: capture", robot=1, seq=2, stored=True, capture={"seq": 2}))
    log.close()
    (written,) = [json.loads(line) for line in (tmp_path / "x.log").read_text().splitlines()]
    assert written["kind"] == "capture" and written["capture"] == {"seq": 2} and written["stored"] is True
    assert err.getvalue() == "capture: robot 1 seq 2: capture\n"
    assert ev.line(written, timed=True) == "1970-01-01T00:00:10Z capture: robot 1 seq 2: capture"


def test_watch_says_what_the_robot_left_out():
    snap = StationSnapshot("pty", "db", 0.0).to_json(0.0)
    snap["robot"].update(errors=["e"] * 16, left_out={"errors": 4, "faults": 0},
                         dead_letters={"count": 2, "latest": []})
    snap["captures"]["bad"] = 3
    text = summary(snap)
    assert "errors 16 (+4 older)" in text and "2 messages refused" in text and "refused 3" in text
