"""The real BNO055 driver against the register-map emulator, through every bus fault."""
from __future__ import annotations

import errno

import pytest

from hal.bno055 import FROM_CONFIG_S, TO_CONFIG_S, BNO055Tracker, Mode, Reg
from hal.emulators.bno055 import EmulatedSMBus
from hal.interfaces import HalError, Orientation, OrientationTracker, view_from_orientation


def tracker(bus: EmulatedSMBus, **kw) -> tuple[BNO055Tracker, list[float]]:
    sleeps: list[float] = []
    return BNO055Tracker(bus, bus_number=3, sleep=sleeps.append, **kw), sleeps


def test_init_goes_through_config_into_ndof_with_datasheet_delays():
    bus = EmulatedSMBus()
    t, sleeps = tracker(bus)
    assert isinstance(t, OrientationTracker)
    assert bus.mode == Mode.NDOF
    modes = [a.value for a in bus.history if a.op == "write" and a.register == Reg.OPR_MODE]
    assert modes == [Mode.CONFIG, Mode.NDOF]
    assert TO_CONFIG_S in sleeps and FROM_CONFIG_S in sleeps


def test_euler_angles_follow_the_commanded_orientation_in_degrees():
    pose = [Orientation(heading=123.4375, roll=-5.5, pitch=-60.25)]
    t, _ = tracker(EmulatedSMBus(orientation_source=lambda: pose[0]))
    assert t.orientation() == pose[0]
    pose[0] = Orientation(heading=359.9375, roll=1.0, pitch=-90.0)
    got = t.orientation()
    assert got == pose[0]
    view = view_from_orientation(got)
    assert view.elevation == 90.0 and view.azimuth == pytest.approx(359.9375)


def test_noise_stays_within_a_few_sigma():
    t, _ = tracker(EmulatedSMBus(orientation_source=lambda: Orientation(10.0, 0.0, -45.0), noise_deg=0.5, seed=4))
    pitches = [t.orientation().pitch for _ in range(200)]
    assert all(abs(p + 45.0) < 2.5 for p in pitches)
    assert len(set(pitches)) > 10  # noise really varies


def test_calibration_bits_are_decoded():
    t, _ = tracker(EmulatedSMBus(calibration=0b11_10_01_00))
    c = t.calibration()
    assert (c.system, c.gyro, c.accel, c.mag) == (3, 2, 1, 0)
    assert not c.ok


def test_transient_nacks_are_retried_and_the_value_is_right():
    bus = EmulatedSMBus(orientation_source=lambda: Orientation(45.0, 2.0, -30.0))
    t, _ = tracker(bus, retries=3)
    bus.nack_next = 3  # three NACKs, the fourth try answers
    assert t.orientation() == Orientation(45.0, 2.0, -30.0)
    assert t.retried == 3
    assert [a.ok for a in bus.history[-4:]] == [False, False, False, True]


def test_random_nacks_during_init_and_reads_never_give_a_wrong_value():
    bus = EmulatedSMBus(orientation_source=lambda: Orientation(200.0, 0.0, -70.0), nack_rate=0.3, seed=1)
    t, _ = tracker(bus, retries=8)
    for _ in range(50):
        assert t.orientation() == Orientation(200.0, 0.0, -70.0)
    assert t.retried > 0


def test_persistent_nack_raises_naming_bus_and_address():
    bus = EmulatedSMBus()
    t, _ = tracker(bus, retries=2)
    bus.nack_next = 10
    with pytest.raises(HalError, match=r"bus 3 address 0x28.*3 tries"):
        t.orientation()


@pytest.mark.parametrize("code", [errno.EIO, errno.EBUSY])
def test_eio_and_ebusy_are_retried_too(code):
    bus = EmulatedSMBus()
    t, _ = tracker(bus)
    real = bus.read_byte_data
    fails = [2]

    def flaky(addr, reg):
        if fails[0]:
            fails[0] -= 1
            raise OSError(code, "bus trouble")
        return real(addr, reg)

    bus.read_byte_data = flaky
    assert t.calibration().ok
    assert t.retried == 2


def test_other_os_errors_are_not_retried():
    bus = EmulatedSMBus()
    t, _ = tracker(bus)

    def gone(addr, reg):
        raise OSError(errno.ENODEV, "No such device")

    bus.read_byte_data = gone
    with pytest.raises(HalError, match="bus 3 address 0x28"):
        t.calibration()
    assert t.retried == 0


def test_wrong_chip_id_is_a_clear_error():
    with pytest.raises(HalError, match=r"chip id 0x55, expected 0xA0"):
        tracker(EmulatedSMBus(chip_id=0x55))


def test_wrong_address_nacks_and_names_it():
    with pytest.raises(HalError, match="address 0x29"):
        tracker(EmulatedSMBus(), address=0x29)


def test_emulator_honours_the_mode_state_machine():
    bus = EmulatedSMBus(orientation_source=lambda: Orientation(90.0, 0.0, -45.0))
    assert bus.read_i2c_block_data(0x28, Reg.EULER_H_LSB, 6) == [0] * 6  # no fusion yet
    bus.write_byte_data(0x28, Reg.OPR_MODE, Mode.NDOF)
    assert bus.read_i2c_block_data(0x28, Reg.EULER_H_LSB, 2) == [0xA0, 0x05]  # 90 * 16 = 0x5A0
    bus.write_byte_data(0x28, Reg.OPR_MODE, Mode.IMU)  # fusion to fusion must pass CONFIG
    assert bus.mode == Mode.NDOF
    bus.write_byte_data(0x28, 0x55, 0x12)  # an offset register outside CONFIG: ignored
    assert bus.regs[0x55] == 0
    bus.write_byte_data(0x28, Reg.OPR_MODE, Mode.CONFIG)
    bus.write_byte_data(0x28, 0x55, 0x12)
    assert bus.regs[0x55] == 0x12
    bus.source = lambda: Orientation(10.0, 0.0, -45.0)
    assert bus.read_i2c_block_data(0x28, Reg.EULER_H_LSB, 2) == [0xA0, 0x05]  # stale in CONFIG


def test_driver_refuses_a_chip_that_does_not_enter_ndof():
    bus = EmulatedSMBus()
    real = bus.write_byte_data

    def stuck(addr, reg, value):
        if reg == Reg.OPR_MODE and value == Mode.NDOF:
            return
        real(addr, reg, value)

    bus.write_byte_data = stuck
    with pytest.raises(HalError, match="mode NDOF"):
        tracker(bus)


def test_negative_retries_rejected():
    with pytest.raises(ValueError, match="retries"):
        BNO055Tracker(EmulatedSMBus(), retries=-1)


def test_a_chip_left_in_radians_is_put_back_into_degrees():
    pose = Orientation(heading=100.0, roll=3.0, pitch=-60.0)
    bus = EmulatedSMBus(orientation_source=lambda: pose)
    bus.regs[Reg.UNIT_SEL] = 0x84  # an earlier program chose radians (and kept the orientation bit)
    t, _ = tracker(bus)
    assert bus.regs[Reg.UNIT_SEL] == 0x80
    assert t.orientation() == pose


def test_a_chip_that_keeps_radians_is_refused():
    bus = EmulatedSMBus()
    bus.regs[Reg.UNIT_SEL] = 0x04
    real = bus.write_byte_data

    def stuck(addr, reg, value):
        if reg != Reg.UNIT_SEL:
            real(addr, reg, value)

    bus.write_byte_data = stuck
    with pytest.raises(HalError, match="radians"):
        tracker(bus)
