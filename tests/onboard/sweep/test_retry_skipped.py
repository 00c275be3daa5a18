"""Skipped poses are measured again: after a sweep's planned poses, each pose a device fault
skipped is tried again, up to `[sweep] retry_skipped` more times, the oldest first; the sweep
ends with every pose measured or listed as missing, each with why."""
import os

import pytest

from hal.fakes import Faults
from hal.interfaces import ViewAngles
from onboard.sweep.plan import SkippedPose, SweepPlan, SweepProgress
from radio import packets as pk
from tests.support.robots import SMALL
from tests.support.runtime import decoded, make, sweep


def test_a_pose_skipped_for_a_fault_is_tried_again_after_the_plan_until_its_tries_run_out():
    p = SweepProgress(1, SweepPlan(90, 60, 10), retry_skipped=2)  # poses 90, 80, 70, 60
    p.record_measured(ViewAngles(90.0))
    p.record_skipped("move failed after 3 attempts", fault=True)  # 80
    p.record_skipped("already measured in this sweep")  # 70: not a device's fault, not tried again
    p.record_skipped("tracker failed after 3 attempts", fault=True)  # 60
    assert not p.done and p.retrying and p.current() == ViewAngles(80.0) and p.current_index() == 1
    p.record_skipped("settle failed", fault=True)  # 80 again: it goes behind 60
    assert p.current() == ViewAngles(60.0) and [(k.index, k.tries) for k in p.skipped] == [(2, 1), (3, 1), (1, 2)]
    p.record_measured(ViewAngles(60.2))
    assert p.current() == ViewAngles(80.0)
    p.record_skipped("settle failed again", fault=True)  # its third try: no more
    assert p.done and p.current() is None
    assert [(k.index, k.reason, k.tries) for k in p.skipped] == [
        (2, "already measured in this sweep", 1), (1, "settle failed again", 3)]
    assert sorted(i for i, _ in p.measured) == [0, 3]


def test_without_retries_a_sweep_ends_with_its_plan():
    p = SweepProgress(1, SweepPlan(90, 80, 10))
    p.record_skipped("move failed", fault=True)
    p.record_measured(ViewAngles(80.0))
    assert p.done and [k.index for k in p.skipped] == [0]


def test_progress_keeps_its_tries_across_a_restart_and_reads_a_sweep_saved_before_them():
    p = SweepProgress(3, SweepPlan(90, 80, 10), retry_skipped=1)
    p.record_skipped("move failed", fault=True)
    p.record_skipped("move failed", fault=True)
    p.record_skipped("settle failed", fault=True)
    again = SweepProgress.from_record(p.to_record())
    assert again == p and again.skipped[-1] == SkippedPose(0, ViewAngles(90.0), "settle failed", True, 2)
    old = p.to_record()
    old["skipped"] = [row[:4] for row in old["skipped"]]
    del old["retry_skipped"]
    before = SweepProgress.from_record(old)
    assert before.retry_skipped == 0 and before.skipped[0] == SkippedPose(1, ViewAngles(80.0), "move failed")


def nack_first_pose(rt):
    """The tracker NACKs every read of the first pose (3 attempts of 4 tries), then answers."""
    rt.hal.tracker.faults = Faults(force={"nack"}, remaining=3 * 4)


def test_a_pose_the_tracker_failed_is_measured_once_the_plan_is_through(fake_robot):
    rt, tr = make(fake_robot, extra=(SMALL, {"sweep": {"start": 90, "stop": 70, "step": 10}}))
    nack_first_pose(rt)
    sweep(rt)
    packets = decoded(tr)
    order = [round(p.commanded[0]) for p in packets if isinstance(p, pk.ModelsPacket)]
    assert order == [80, 70, 90]  # 90 measured last, on its second try
    (skip,) = [p for p in packets if isinstance(p, pk.StatusPacket) and p.text.startswith("skipped pose")]
    assert skip.text.startswith("skipped pose: tracker failed after 3 attempts")
    (done,) = [p for p in packets if isinstance(p, pk.StatusPacket) and p.text == "sweep done"]
    assert done.report.sweep.measured == 3 and done.report.sweep.missing == pk.Kept(())
    assert rt.progress.done and not rt.progress.skipped
    # it says the robot as it is once the sweep is over: idle, its last capture the sweep's last
    last = [p.seq for p in packets if isinstance(p, pk.ModelsPacket)][-1]
    assert (done.state, done.report.mode, done.last_seq) == (pk.RobotState.IDLE, "idle", last)


def test_with_retry_skipped_zero_the_pose_stays_missing_with_its_reason(fake_robot):
    rt, tr = make(fake_robot, extra=(SMALL, {"sweep": {"start": 90, "stop": 70, "step": 10, "retry_skipped": 0}}))
    nack_first_pose(rt)
    sweep(rt)
    (done,) = [p for p in decoded(tr) if isinstance(p, pk.StatusPacket) and p.text == "sweep done"]
    (missing,) = done.report.sweep.missing.items
    assert (missing.index, missing.elevation, missing.tries) == (0, 90.0, None)
    assert missing.reason.startswith("tracker failed after 3 attempts") and done.report.sweep.measured == 2


def faulty_sweep(fake_robot, stop: float, seed: int = 3, retry_skipped: int = 2):
    """A sweep from 90 to `stop` in 2 degree steps at two azimuths, 20% of device calls failing
    (stalls, timeouts, NACKs); a quick servo, so a stall costs only the settle timeout."""
    plan = {"start": 90, "stop": stop, "step": 2, "azimuths": [0, 90], "settle_timeout_s": 0.02,
            "retry_skipped": retry_skipped}
    rt, tr = make(fake_robot, rate=0.2, extra=(SMALL, {"sweep": plan, "hal": {"fault_seed": seed}}))
    rt.hal.servo_bus.speed_deg_s = 20000.0
    sweep(rt)
    return rt, tr


def test_a_sweep_at_a_twenty_percent_fault_rate_ends_with_every_pose_measured_or_missing_with_why(fake_robot):
    rt, tr = faulty_sweep(fake_robot, 50)
    p, packets = rt.progress, decoded(tr)
    measured, missing = {i for i, _ in p.measured}, {k.index for k in p.skipped}
    assert p.done and measured | missing == set(range(42)) and not measured & missing
    (done,) = [x for x in packets if isinstance(x, pk.StatusPacket) and x.text == "sweep done"]
    said = done.report.sweep
    assert said.measured == len(measured) and said.missing.total == len(missing)
    assert {(k.index, k.reason) for k in said.missing} == {(k.index, k.reason) for k in p.skipped}
    assert all(k.reason and (not k.fault or k.tries == 3) for k in p.skipped)  # a fault's pose had its 3 tries
    first_skips = {x.report.sweep.skipped.items[0].index for x in packets
                   if isinstance(x, pk.StatusPacket) and x.text.startswith("skipped pose: ")}
    assert len(first_skips) > len(missing) and first_skips & measured  # skipped once, measured on a later try
    # every pose measured has a capture in its direction (the zenith's, at whichever azimuth came first)
    def direction(el: float, az: float) -> tuple[int, int]:
        return (90, 0) if round(el) == 90 else (round(el), round(az))
    captured = {direction(*x.commanded) for x in packets if isinstance(x, (pk.ModelsPacket, pk.UnchangedPacket))}
    assert captured == {direction(v.elevation, v.azimuth) for v in (p.plan.pose(i) for i in measured)}


@pytest.mark.slow
@pytest.mark.skipif(not os.environ.get("BTF_STRESS"), reason="stress run only (make stress): 82 poses, 5 fault seeds")
@pytest.mark.parametrize("seed", range(5))
def test_82_poses_at_a_twenty_percent_fault_rate_end_measured_or_missing_and_the_retries_win_most_back(
        fake_robot, seed):
    rt, tr = faulty_sweep(fake_robot, 10, seed)
    p = rt.progress
    measured, missing = {i for i, _ in p.measured}, {k.index for k in p.skipped}
    assert p.done and measured | missing == set(range(82)) and not measured & missing
    (done,) = [x for x in decoded(tr) if isinstance(x, pk.StatusPacket) and x.text == "sweep done"]
    assert {(k.index, k.reason) for k in done.report.sweep.missing} == {(k.index, k.reason) for k in p.skipped}
    first = {x.report.sweep.skipped.items[0].index for x in decoded(tr)
             if isinstance(x, pk.StatusPacket) and x.text.startswith("skipped pose: ")}
    assert len(missing) * 3 < len(first)  # most poses skipped once were measured on a later try


def test_a_station_started_after_the_sweep_hears_the_robot_its_pose_and_the_sweep_at_once(fake_robot):
    """An idle robot says nothing of itself: when a base opens a session (a station restarted
    while the link stayed up) it sends its whole report, so the new station knows it at once."""
    rt, tr = make(fake_robot, extra=(SMALL, {"sweep": {"start": 90, "stop": 70, "step": 10}}))
    sweep(rt)
    before = len(tr.sent)
    rt.service()
    assert len(tr.sent) == before  # no session opened: nothing more
    tr.sessions += 1
    rt.service()
    (told,) = [p for p in decoded(tr)[before:] if isinstance(p, pk.StatusPacket)]
    assert told.text == "the base opened a session" and told.state is pk.RobotState.IDLE
    assert told.pose is not None and abs(told.pose[0] - 70.0) < 2.0
    assert (told.report.sweep.measured, told.report.sweep.active, told.report.mode) == (3, False, "idle")
    rt.service()
    assert len(tr.sent) == before + 1  # once a session


def test_the_zenith_at_a_second_azimuth_counts_as_measured_not_missing(fake_robot):
    """90° at azimuths 0 and 90 is one direction: measured once, and the sweep ends with nothing
    missing (it was listed as missing, so the demo seemed to have failed a pose)."""
    rt, tr = make(fake_robot, extra=(SMALL, {"sweep": {"start": 90, "stop": 80, "step": 10, "azimuths": [0, 90]}}))
    sweep(rt)
    packets = decoded(tr)
    captures = [p for p in packets if isinstance(p, pk.ModelsPacket)]
    (done,) = [p for p in packets if isinstance(p, pk.StatusPacket) and p.text == "sweep done"]
    assert len(captures) == 3 and [round(p.commanded[0]) for p in captures].count(90) == 1
    assert (done.report.sweep.measured, done.report.sweep.missing.total) == (4, 0) and not rt.progress.skipped
