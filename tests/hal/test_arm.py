"""Arm kinematics, calibration, limits and settling, on the fake servo bus and a fake clock."""
from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hal.arm import Arm, ArmCalibration, JointCalibration
from hal.fakes import Faults
from hal.fakes.servo import FakeClock, FakeServoBus
from hal.interfaces import DeviceTimeout, LimitError, ViewAngles

CAL = ArmCalibration(
    yaw=JointCalibration(1, -180.0, 179.0, offset_deg=0.5, sign=1.0),
    tilt=JointCalibration(2, 0.0, 80.0, offset_deg=-10.0, sign=-1.0,
                          corrections=((0.0, 0.4), (40.0, -0.6), (80.0, 1.2))),
)


def rig(faults: Faults | None = None) -> tuple[Arm, FakeServoBus, FakeClock]:
    clock = FakeClock()
    bus = FakeServoBus((1, 2), clock=clock, speed_deg_s=60.0, faults=faults or Faults())
    arm = Arm(bus, CAL, clock=clock, sleep=clock.sleep)
    arm.enable()
    return arm, bus, clock


def test_straight_down_is_tilt_zero_plus_calibration():
    arm, _, _ = rig()
    assert arm.joints_for(ViewAngles(90.0, 0.0)) == pytest.approx({1: 0.5, 2: -10.0 + 0.4})


def test_correction_table_is_interpolated():
    # elevation 70 -> tilt 20, halfway between corrections 0.4 and -0.6
    assert rig()[0].joints_for(ViewAngles(70.0, 0.0))[2] == pytest.approx(-20.0 - 10.0 - 0.1)


@given(st.floats(10.0, 90.0), st.one_of(st.floats(0.0, 179.0), st.floats(180.0, 359.9)))
def test_view_for_inverts_joints_for(elevation, azimuth):
    arm, _, _ = rig()
    back = arm.view_for(arm.joints_for(ViewAngles(elevation, azimuth)))
    assert back.elevation == pytest.approx(elevation, abs=1e-6)
    assert (back.azimuth - azimuth + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("view", [ViewAngles(5.0, 0.0), ViewAngles(95.0, 0.0), ViewAngles(float("nan"), 0.0),
                                  ViewAngles(60.0, 179.5)])
def test_out_of_limit_views_raise_before_anything_moves(view):
    arm, bus, _ = rig()
    with pytest.raises(LimitError):
        arm.move_to(view)
    assert [c.call for c in bus.history] == ["set_torque"]


def test_move_to_waits_until_settled_and_reaches_the_view():
    arm, bus, clock = rig()
    reached = arm.move_to(ViewAngles(30.0, 90.0), timeout_s=10.0)
    assert arm.view_for(reached).elevation == pytest.approx(30.0, abs=1e-6)
    assert arm.view_for(bus.true_positions()).azimuth == pytest.approx(90.0, abs=1e-6)
    assert 1.0 < clock.now < 2.0  # about 89.5 degrees of yaw at 60 deg/s


def test_wait_times_out_when_a_servo_stalls():
    arm, _, clock = rig(Faults(force={"stall"}, remaining=1))
    with pytest.raises(DeviceTimeout, match="did not stop within 3.0 s"):
        arm.move_to(ViewAngles(40.0, 0.0), timeout_s=3.0)
    assert clock.now == pytest.approx(3.0, abs=0.02)


def test_stop_and_hold_keeps_the_joints_where_they_are():
    arm, bus, clock = rig()
    bus.move(arm.joints_for(ViewAngles(30.0, 120.0)))
    clock.advance(0.5)
    arm.stop_and_hold()
    here = bus.true_positions()
    clock.advance(5.0)
    assert bus.true_positions() == here and not bus.is_moving([1, 2])


def test_torque_off_lets_the_arm_go_limp():
    arm, bus, clock = rig()
    arm.torque_off()
    bus.move({1: 40.0})
    clock.advance(2.0)
    assert bus.true_positions()[1] == pytest.approx(0.0)


@pytest.mark.parametrize("kwargs, match", [
    ({"sign": 2.0}, "sign"),
    ({"min_deg": 10.0, "max_deg": 0.0}, "empty"),
    ({"corrections": ((10.0, 0.0), (5.0, 0.0))}, "sorted"),
])
def test_bad_joint_calibration_is_refused(kwargs, match):
    args = {"servo_id": 1, "min_deg": 0.0, "max_deg": 90.0, **kwargs}
    with pytest.raises(ValueError, match=match):
        JointCalibration(**args)


def test_a_move_the_bus_refused_is_not_waited_for():
    arm, bus, _ = rig()
    arm.move_to(ViewAngles(80.0, 10.0), timeout_s=5.0)
    bus.faults = Faults(force={"timeout"}, remaining=1)
    with pytest.raises(DeviceTimeout, match="no status packet"):
        arm.move_to(ViewAngles(30.0, 90.0), timeout_s=5.0)
    reached = arm.wait_until_stopped(1.0)  # still where the last accepted move left it
    assert arm.view_for(reached).elevation == pytest.approx(80.0, abs=1e-6)
