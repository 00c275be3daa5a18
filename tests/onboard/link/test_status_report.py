"""STATUS is a typed record with a declared wire schema: the fullest report the robot can say
travels whole, it grows by a declaration (past the 16 extras a packet once held) with nothing
dropped, and what its bounds cut is cut visibly, counted."""
import dataclasses

import msgpack
import pytest

from onboard.link.status import fit
from radio import FrameError
from radio import packets as pk
from radio.packets.base import MAX_EXTRAS
from radio.packets.schema import CUT, Float, Latest, Maybe, Record, Text, Word, layout, wire


def fullest() -> pk.StatusReport:
    plan = pk.Plan(90.0, 30.0, 10.0, (0.0, 90.0))
    return pk.StatusReport(
        mode="sweeping", outbox=3, paused="disk low", disk=pk.Disk("low", 1 << 20),
        rejected=pk.Kept((pk.Rejection("stale", 2), pk.Rejection("tag", 1))),
        failsafe=pk.Kept((pk.FailsafeEvent(1.7e9, 1.7e9 + 5.0), pk.FailsafeEvent(1.7e9 + 60.0)), 3),
        failsafe_s=5.0, torque=True, faults=pk.Kept(("servo 1: overload",)), errors=pk.Kept(("OSError: disk full",)),
        sweep=pk.SweepReport(4, next=2, poses=14, active=True, plan=plan,
                             skipped=pk.Kept((pk.SkippedPose(1, 80.0, 0.0, "servo timeout"),))),
        camera="exposure 5000 us, gain 1.0, locked",
        dead_letters=pk.DeadLetters(1, pk.Kept((pk.DeadLetter(41, pk.Kind.STATUS, "sweep must be an int", 1.7e9),))),
        pose_ms=42.5)


def answer(report, packet=pk.AckPacket):
    body = pk.encode(packet(7, "STATUS", status=report))
    return pk.decode(body).status


def test_the_fullest_report_travels_whole():
    report = fullest()
    assert answer(report) == report
    said = [f.name for f in layout(pk.StatusReport) if getattr(report, f.name) is not None]
    assert len(said) == len(layout(pk.StatusReport))  # every field said, none dropped


def test_a_field_added_to_the_report_travels_past_the_sixteen_an_extras_map_held():
    @dataclasses.dataclass(frozen=True, slots=True)
    class Grown(pk.StatusReport):
        humidity: float | None = wire(Maybe(Float(0.0, 100.0)), "air humidity, %", tag=15, default=None)
        lamp: str | None = wire(Maybe(Word(("on", "off"))), "the lamp", tag=16, default=None)
        notes: pk.Kept | None = wire(Maybe(Latest(Text(40), 4)), "notes", tag=17, default=None)
        battery_v: float | None = wire(Maybe(Float(0.0, 60.0)), "battery, volts", tag=18, default=None)

    @dataclasses.dataclass(frozen=True, slots=True)
    class GrownAck(pk.AckPacket):
        status: Grown | None = wire(Maybe(Record(Grown)), "the grown report", since=4, default=None)

    grown = Grown(**{f.name: getattr(fullest(), f.name) for f in layout(pk.StatusReport)},
                  humidity=41.5, lamp="on", notes=pk.Kept(("a", "b")), battery_v=12.6)
    assert len(layout(Grown)) == 18 > MAX_EXTRAS
    kinds = dict(pk.KINDS)
    pk.KINDS[pk.Kind.ACK] = GrownAck  # a writer and reader that know the new declaration
    try:
        body = pk.encode(GrownAck(7, "STATUS", status=grown))
        back = pk.decode(body).status
    finally:
        pk.KINDS.clear()
        pk.KINDS.update(kinds)
    assert back == grown and all(getattr(back, f.name) is not None for f in layout(Grown))
    with pytest.raises(FrameError, match="no field tagged 15"):  # a reader that does not refuses it, whole
        pk.decode(body)


def test_what_the_bounds_cut_is_cut_visibly_and_counted():
    errors = [f"error {i}" for i in range(20)]
    report = fit(pk.StatusReport(errors=errors, paused="x" * 400,
                                 sweep=pk.SweepReport(1, skipped=[pk.SkippedPose(i, 80.0, 0.0, "r") for i in range(30)])))
    assert report.errors.items == tuple(errors[4:]) and report.errors.left_out == 4 and report.errors.total == 20
    assert len(report.paused) == 300 and report.paused.endswith(CUT)
    assert [k.index for k in report.sweep.skipped] == list(range(14, 30)) and report.sweep.skipped.left_out == 14
    assert answer(report) == report  # the encoder sends what was fitted, the count with it
    # the encoder fits on its own too: nothing past a bound is dropped unsaid
    raw = pk.StatusReport(errors=pk.Kept(tuple(errors), 5))
    assert answer(raw).errors == pk.Kept(tuple(errors[4:]), 9)


def test_a_hostile_nested_record_is_refused_by_the_decoder():
    good = pk.encode(pk.AckPacket(7, "STATUS", status=pk.StatusReport(sweep=pk.SweepReport(3, next=1, poses=2))))
    items = msgpack.unpackb(good, strict_map_key=False)  # [version, kind, command id, text, report]
    sweep_tag = 11

    def with_sweep(sweep: dict) -> bytes:
        return msgpack.packb([*items[:4], {sweep_tag: sweep}])

    old = items[4][sweep_tag]
    assert pk.decode(with_sweep(old)).status.sweep == pk.SweepReport(3, next=1, poses=2)
    with pytest.raises(FrameError, match="active must be true or false"):
        pk.decode(with_sweep({**old, 4: 2}))
    with pytest.raises(FrameError, match="next pose 5 beyond the plan's 2"):
        pk.decode(with_sweep({**old, 2: 5}))
    with pytest.raises(FrameError, match="sweep id must be an integer"):
        pk.decode(with_sweep({1: "abc"}))
