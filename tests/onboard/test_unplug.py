"""A device unplugged mid-sweep: the robot pauses (nothing measured, nothing skipped), says so in
a STATUS and its log, asks the device again every PROBE_S, and resumes once it is back, said
again: every planned pose ends measured. On the fakes with a clock the test moves, and on the
real drivers with their emulators (the servo bus's pty closing, the tracker answering EIO and
coming back from power-on)."""
import logging

import pytest

from hal.fakes.servo import FakeClock
from onboard.runtime import Mode
from onboard.sweep.control import PROBE_S
from radio import packets as pk
from tests.support.emulated import emulated_hal
from tests.support.robots import SMALL
from tests.support.runtime import decoded, make

PLAN4 = {"sweep": {"start": 90, "stop": 60, "step": 10}}


def statuses(tr):
    return [p for p in decoded(tr) if isinstance(p, pk.StatusPacket)]


def finish(rt, limit=200):
    for _ in range(limit):
        if rt.mode is not Mode.SWEEPING:
            return
        rt.step()
    raise AssertionError(f"the sweep did not end: {rt.progress}")


@pytest.mark.parametrize("device, step", [("tracker", "tracker"), ("servo_bus", "move")])
def test_an_unplugged_device_pauses_the_sweep_which_resumes_when_it_is_back_and_loses_no_capture(
        fake_robot, caplog, device, step):
    clock = FakeClock(100.0)
    rt, tr = make(fake_robot, extra=(SMALL, PLAN4), clock=clock)
    caplog.set_level(logging.INFO, logger="btf.robot")
    rt.boot()
    assert [rt.step(), rt.step()] == ["measured", "measured"]
    gone = getattr(rt.hal, device)
    gone.unplug()
    assert rt.step() == "paused"
    (said,) = [p for p in statuses(tr) if p.text.startswith("device gone")]
    assert said.text.startswith(f"device gone: {step}: fake ") and "unplugged" in said.text
    assert said.state is pk.RobotState.PAUSED and said.report.paused.endswith("sweep paused until it answers again")
    assert rt.status.report().paused == said.report.paused and rt.mode is Mode.SWEEPING
    asked = len(gone.history)
    assert [rt.step() for _ in range(5)] == ["paused"] * 5 and len(gone.history) == asked  # not before PROBE_S
    clock.advance(PROBE_S)
    assert rt.step() == "paused" and len(gone.history) > asked  # asked again: still gone, said once
    assert len([p for p in statuses(tr) if p.text.startswith("device gone")]) == 1
    gone.replug()
    clock.advance(PROBE_S)
    finish(rt)
    p = rt.progress
    assert p.done and not p.skipped and sorted(i for i, _ in p.measured) == [0, 1, 2, 3]
    models = [round(x.commanded[0]) for x in decoded(tr) if isinstance(x, pk.ModelsPacket)]
    assert models == [90, 80, 70, 60]
    (back,) = [x for x in statuses(tr) if x.text.startswith("devices answer again: sweep resumes")]
    assert back.report.paused == "" and rt.status.report().paused == ""
    logged = [r.getMessage() for r in caplog.records]
    assert any(m.startswith("device gone: ") for m in logged) and any("sweep resumes" in m for m in logged)


def test_the_real_drivers_unplugged_and_replugged_lose_no_capture(fake_robot):
    """The servo chain's pty closes and comes back under its name; then the BNO055 answers EIO and
    comes back from power-on (CONFIG mode, Euler at zero): every pose measured at its own angle."""
    rig = emulated_hal()
    clock = FakeClock(100.0)
    try:
        rt, tr = make(fake_robot, extra=(SMALL, PLAN4), hal=rig.hal, clock=clock)
        rt.boot()
        assert rt.step() == "measured"
        rig.servos.unplug()
        assert rt.step() == "paused"
        rig.servos.replug()
        clock.advance(PROBE_S)
        assert rt.step() == "measured"
        rig.i2c.unplug()
        assert rt.step() == "paused"
        rig.i2c.replug()
        clock.advance(PROBE_S)
        finish(rt)
        captures = [x for x in decoded(tr) if isinstance(x, pk.ModelsPacket)]
        assert [round(x.commanded[0]) for x in captures] == [90, 80, 70, 60] and not rt.progress.skipped
        assert all(abs(x.measured[0] - x.commanded[0]) < 1.0 for x in captures)  # never a zero from a reset chip
        gone = [x.text for x in statuses(tr) if x.text.startswith("device gone")]
        assert len(gone) == 2 and "port failed" in gone[0] and "EIO" in gone[1], gone
        assert len([x for x in statuses(tr) if x.text.startswith("devices answer again")]) == 2
    finally:
        rig.hal.close()
