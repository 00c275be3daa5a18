"""A device unplugged mid-sweep: every call is DeviceGone (never a fault worth retrying, never a
wrong value) until it is back, then it answers as before. The fakes, and the real BNO055 driver
on the register-map emulator, whose chip comes back from power-on and is set up again (the
servo bus on its pty emulator is tests/hal/test_dynamixel.py's)."""
from __future__ import annotations

import pytest

from hal.bno055 import BNO055Tracker, Mode, Reg
from hal.emulators.bno055 import EmulatedSMBus
from hal.fakes import Call
from hal.fakes.servo import FakeClock, FakeServoBus
from hal.fakes.tracker import FakeTracker
from hal.interfaces import DeviceGone, HalError, Orientation, ViewAngles


def test_the_fake_bus_unplugged_is_gone_and_its_servos_go_on_where_they_were():
    clock = FakeClock()
    bus = FakeServoBus(clock=clock)
    bus.set_torque([1, 2], True)
    bus.move({1: 30.0, 2: -20.0})
    bus.unplug()
    for call in (lambda: bus.positions([1]), lambda: bus.is_moving([1, 2]), lambda: bus.move({1: 0.0})):
        with pytest.raises(DeviceGone, match="fake servo bus: its port is gone"):
            call()
    assert not bus.ping(1) and bus.history[-1] == Call("ping", (1,), "gone")
    clock.advance(1.0)  # the servos keep their power: they reach the goals they had
    bus.replug()
    assert bus.positions([1, 2]) == {1: 30.0, 2: -20.0} and not bus.is_moving([1, 2])


def test_the_fake_tracker_unplugged_is_gone_then_reads_the_view_again():
    view = ViewAngles(60.0, 10.0)
    tracker = FakeTracker(lambda: view, noise_deg=0.0, bias_deg=0.0)
    tracker.unplug()
    with pytest.raises(DeviceGone, match="EIO"):
        tracker.orientation()
    assert tracker.history == [Call("orientation", (), "gone")]
    tracker.replug()
    assert tracker.orientation() == Orientation(10.0, 0.0, -60.0)


def test_an_unplugged_bno055_is_gone_not_a_nack_and_set_up_again_when_it_is_back():
    pose = Orientation(heading=40.0, roll=0.0, pitch=-50.0)
    bus = EmulatedSMBus(orientation_source=lambda: pose)
    t = BNO055Tracker(bus, bus_number=3, sleep=lambda s: None, retries=2)
    assert t.orientation() == pose
    bus.unplug()
    with pytest.raises(DeviceGone, match=r"bus 3 address 0x28: no answer \(EIO, 3 tries\)"):
        t.orientation()
    with pytest.raises(DeviceGone):
        t.calibration()
    bus.replug()  # it lost power meanwhile: CONFIG mode, Euler at zero
    assert bus.mode == Mode.CONFIG and bus.regs[Reg.EULER_H_LSB:Reg.EULER_H_LSB + 6] == bytes(6)
    assert t.orientation() == pose  # set up again first, never a zero read as the horizon
    assert bus.mode == Mode.NDOF and t.calibration().ok


def test_a_bno055_replugged_into_another_chip_is_refused_not_read():
    bus = EmulatedSMBus()
    t = BNO055Tracker(bus, sleep=lambda s: None)
    bus.unplug()
    with pytest.raises(DeviceGone):
        t.orientation()
    bus.chip_id = 0x55  # a different device answers at the address now
    bus.replug()
    with pytest.raises(HalError, match="chip id 0x55") as refused:
        t.orientation()
    assert not isinstance(refused.value, DeviceGone)


def test_persistent_nacks_are_a_fault_not_a_device_gone():
    bus = EmulatedSMBus()
    t = BNO055Tracker(bus, sleep=lambda s: None, retries=2)
    bus.nack_next = 10
    with pytest.raises(HalError, match="no answer after 3 tries") as nacked:
        t.orientation()
    assert not isinstance(nacked.value, DeviceGone)
