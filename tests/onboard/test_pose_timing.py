"""Each pose's compute by step: the robot's log line (plain or JSON) and the last pose's total in STATUS."""
import json
import logging

from onboard.capture.pipeline import PoseTiming
from onboard.cli.run import JsonLines
from radio import packets as pk
from tests.support.runtime import decoded, make, sweep


def test_each_pose_logs_its_compute_by_step_and_status_says_the_last_total(fake_robot, caplog):
    rt, tr = make(fake_robot, "mixed", extra={"features": {"dependence": True}})
    with caplog.at_level(logging.INFO, logger="btf.robot"):
        sweep(rt)
    lines = [r for r in caplog.records if "compute" in r.getMessage()]
    models = [p for p in decoded(tr) if isinstance(p, pk.ModelsPacket)]
    assert len(lines) == len(models) == 7
    for record, packet in zip(lines, models):
        fields = record.fields
        assert fields["capture"] == packet.seq
        steps = [fields[f"{k}_ms"] for k in PoseTiming.STEPS]
        assert all(v >= 0.0 for v in steps) and fields["fit_ms"] > 0.0 and fields["encode_ms"] > 0.0
        assert fields["dependence_ms"] > 0.0  # measured: dependence is on
        assert abs(fields["total_ms"] - sum(steps)) <= 0.3  # each rounded to 0.1 ms
        assert f"total {fields['total_ms']:.1f} ms" in record.getMessage()
    last = rt.captures.last_timing
    assert rt.status.report().pose_ms == round(last.total * 1e3, 1) == lines[-1].fields["total_ms"]
    said = [p for p in decoded(tr) if isinstance(p, pk.StatusPacket) and p.text == "sweep done"]
    assert said and said[-1].report.pose_ms == lines[-1].fields["total_ms"]


def test_json_lines_carry_the_message_and_its_fields():
    record = logging.LogRecord("btf.robot", logging.INFO, __file__, 1, "capture %d compute", (4,), None)
    record.fields = {"capture": 4, "fit_ms": 2.5}
    line = json.loads(JsonLines().format(record))
    assert line["message"] == "capture 4 compute" and line["fit_ms"] == 2.5 and line["capture"] == 4
    assert line["level"] == "info" and line["time"].endswith("Z")
    plain = logging.LogRecord("btf.robot", logging.WARNING, __file__, 1, "link down", (), None)
    bare = json.loads(JsonLines().format(plain))
    assert set(bare) == {"time", "level", "message"} and bare["level"] == "warning" and bare["message"] == "link down"
