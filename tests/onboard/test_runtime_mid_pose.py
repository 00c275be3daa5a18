"""Commands and the failsafe while a pose is being measured: the pipeline services the link
while the arm moves, so these arrive mid-pose."""
import pytest

from onboard.runtime import Mode
from radio import packets as pk
from radio.link import Delivered, LinkDown, LinkUp
from tests.support.runtime import PLAN3, host_view, make, poses_by_seq, replies, sweep


def mid_pose(fake_robot, *events):
    """A runtime past its first pose, with `events` waiting for the next pose's move."""
    rt, tr = make(fake_robot, "black", extra=PLAN3)
    rt.boot()
    tr.deliver(LinkUp())
    rt.step()
    assert rt.progress.next_index == 1
    for ev in events:
        tr.deliver(ev)
    return rt, tr


def test_abort_mid_pose_stops_the_sweep_without_skipping_or_reviving_the_pose(fake_robot):
    rt, tr = mid_pose(fake_robot, Delivered(2, 1, pk.encode(pk.CommandPacket(7, pk.CommandName.ABORT, {}))))
    assert rt.sweep.step() == "interrupted"
    assert isinstance(replies(tr)[7], pk.AckPacket)
    assert rt.mode is Mode.IDLE and not rt.progress.active
    assert rt.progress.next_index == 1 and not rt.progress.skipped
    saved = rt.sweep.sweeps.load()  # what a restart would resume from
    assert not saved.active and saved.next_index == 1 and not saved.skipped


def test_failsafe_mid_pose_holds_the_arm_and_measures_the_pose_after_the_link_returns(fake_robot):
    rt, tr = mid_pose(fake_robot, LinkDown())
    assert rt.sweep.step() == "interrupted"
    assert rt.mode is Mode.FAILSAFE and rt.progress.next_index == 1 and not rt.progress.skipped
    bus = rt.hal.servo_bus
    held = bus.positions([1, 2])
    rt.step()
    rt.sleep(0.05)
    rt.step()
    assert bus.positions([1, 2]) == pytest.approx(held, abs=0.5)  # no move while failsafe
    tr.deliver(LinkUp())
    sweep(rt)
    assert not rt.progress.skipped
    assert [e for e, _ in poses_by_seq(host_view(tr))] == [70, 80, 90]


def test_arm_commands_mid_pose_are_refused_as_busy_and_the_pose_completes(fake_robot):
    goto = pk.CommandPacket(8, pk.CommandName.GOTO, {"elevation": 40.0, "azimuth": 0.0})
    rt, tr = mid_pose(fake_robot, Delivered(2, 1, pk.encode(goto)))
    assert rt.sweep.step() == "measured"
    nack = replies(tr)[8]
    assert isinstance(nack, pk.NackPacket) and nack.reason is pk.Reason.BUSY
    assert rt.progress.next_index == 2 and not rt.progress.skipped


def test_a_sweep_command_mid_pose_replaces_the_sweep_for_good(fake_robot):
    new = pk.CommandPacket(9, pk.CommandName.SWEEP, {"elevations": [60.0], "azimuths": [0.0]})
    rt, tr = mid_pose(fake_robot, Delivered(2, 1, pk.encode(new)))
    old_id = rt.progress.sweep_id
    assert rt.sweep.step() == "interrupted"
    assert rt.progress.sweep_id == old_id + 1 and rt.progress.next_index == 0
    assert rt.sweep.sweeps.load().sweep_id == old_id + 1  # the old sweep's pose did not overwrite it
    sweep(rt)
    assert [e for e, _ in poses_by_seq(host_view(tr))] == [60, 90]


def test_an_unforeseen_fault_skips_the_pose_with_its_reason_and_the_sweep_goes_on(fake_robot):
    rt, tr = make(fake_robot, "black", extra=PLAN3)
    real = rt.pipeline.process

    def broken_once(frame, commanded, measured, *settings):
        if commanded.elevation == 80.0:
            raise RuntimeError("fitter state corrupt")
        return real(frame, commanded, measured, *settings)

    rt.pipeline.process = broken_once
    sweep(rt)
    assert [(s.index, s.reason) for s in rt.progress.skipped] == \
        [(1, "internal: RuntimeError: fitter state corrupt")]
    assert [e for e, _ in poses_by_seq(host_view(tr))] == [70, 90]
