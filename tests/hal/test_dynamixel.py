"""The real dynamixel-sdk driver against the Protocol 2.0 emulator on a pty, through every fault."""
from __future__ import annotations

import os
import time

import pytest
from dynamixel_sdk import PacketHandler
from hypothesis import given, settings
from hypothesis import strategies as st

from hal.dynamixel import DynamixelServoBus, deg_to_ticks, ticks_to_deg
from hal.dynamixel_table import ALERT, SIZE, TABLE_SIZE, TICKS_PER_TURN, VELOCITY_UNIT_RPM, Reg
from hal.emulators.dxl import DxlEmulator, crc16, instruction_packet, status_packet, stuff, unstuff
from hal.fakes import Faults
from hal.interfaces import DeviceGone, DeviceTimeout, HalError, LimitError, ServoBus, ServoRecovery

TICK_DEG = 360.0 / 4096
# The SDK's own USB latency: a reply's timeout of 34 ms, which a loaded machine's emulator thread meets
# (at 4 ms a busy scheduler made a present servo look silent).
LATENCY_MS = 16.0


def test_the_control_table_is_the_datasheets():
    # Driver and emulator share one table, so it is checked against the e-Manual's X-series
    # (XL430-W250) control table here: (address, bytes) of each entry used.
    datasheet = {"MODEL_NUMBER": (0, 2), "ID": (7, 1), "TORQUE_ENABLE": (64, 1), "HARDWARE_ERROR_STATUS": (70, 1),
                 "PROFILE_VELOCITY": (112, 4), "GOAL_POSITION": (116, 4), "MOVING": (122, 1),
                 "PRESENT_POSITION": (132, 4)}
    assert {r.name: (int(r), SIZE[r]) for r in Reg} == datasheet
    assert TABLE_SIZE == 146 + 1  # the last entry, Present Temperature, is one byte at 146
    assert (TICKS_PER_TURN, VELOCITY_UNIT_RPM, ALERT) == (4096, 0.229, 0x80)


@pytest.fixture
def emu():
    with DxlEmulator((1, 2)) as e:
        yield e


@pytest.fixture
def bus(emu):
    b = DynamixelServoBus(emu.port, latency_ms=LATENCY_MS, retries=3)
    yield b
    b.close()


def settle(bus: DynamixelServoBus, ids=(1, 2), polls: int = 5000) -> None:
    for _ in range(polls):
        if not bus.is_moving(list(ids)):
            return
    raise AssertionError("servos never settled")


@given(st.binary(max_size=64))
def test_crc_matches_the_sdk_table(data):
    assert crc16(data) == PacketHandler(2.0).updateCRC(0, list(data), len(data))


@given(st.lists(st.sampled_from([b"\xff", b"\xfd", b"\x00", b"\x07"]), max_size=40).map(b"".join))
def test_stuffing_round_trips_and_never_leaves_a_bare_header(body):
    stuffed = stuff(body)
    assert unstuff(stuffed) == body
    for i in range(len(stuffed) - 2):
        if stuffed[i:i + 3] == b"\xff\xff\xfd":
            assert stuffed[i + 3:i + 4] == b"\xfd"


def test_sdk_decodes_the_emulators_status_packets():
    ph = PacketHandler(2.0)
    pkt = list(status_packet(3, 0, b"\xff\xff\xfd\x07"))
    assert ph.updateCRC(0, pkt, len(pkt) - 2) == pkt[-2] | pkt[-1] << 8
    assert ph.removeStuffing(pkt)[9:13] == [0xFF, 0xFF, 0xFD, 0x07]


@settings(max_examples=50)
@given(st.floats(min_value=-180.0, max_value=179.9))
def test_degrees_ticks_round_trip_within_one_tick(deg):
    assert abs(ticks_to_deg(deg_to_ticks(deg)) - deg) <= TICK_DEG / 2 + 1e-9


def test_goal_outside_the_servo_range_is_refused_before_sending(bus, emu):
    with pytest.raises(LimitError, match="outside"):
        bus.move({1: 10.0, 2: 200.0})
    assert not [c for c in emu.history if c.call == "SYNC_WRITE"]


def test_bus_satisfies_the_servo_bus_protocol(bus):
    assert isinstance(bus, ServoBus)


def test_ping_answers_for_present_servos_only(bus):
    assert bus.ping(1) and bus.ping(2)
    assert not bus.ping(7)


def test_move_sync_writes_goals_and_positions_follow(bus, emu):
    bus.set_torque([1, 2], True)
    bus.move({1: 30.0, 2: -45.0})
    settle(bus)
    got = bus.positions([1, 2])
    assert got[1] == pytest.approx(30.0, abs=TICK_DEG) and got[2] == pytest.approx(-45.0, abs=TICK_DEG)
    assert got[1] == pytest.approx(emu.position_deg(1), abs=1e-9)
    assert bus.hardware_error(1) == 0


def test_slow_profile_velocity_reports_moving_on_the_way(emu):
    bus = DynamixelServoBus(emu.port, latency_ms=LATENCY_MS, profile_velocity=5)  # about 6.9 deg/s
    try:
        bus.set_torque([1], True)
        bus.move({1: 20.0})
        assert bus.is_moving([1])
        first = bus.positions([1])[1]
        time.sleep(0.1)
        before = emu.position_deg(1)
        second = bus.positions([1])[1]
        after = emu.position_deg(1)
        assert 0.0 <= first < second < 20.0 and bus.is_moving([1])
        assert before - TICK_DEG <= second <= after + TICK_DEG  # what the servo was at as it answered
    finally:
        bus.close()


def test_torque_off_servos_do_not_move(bus):
    bus.set_torque([1, 2], False)
    bus.move({1: 40.0})
    assert not bus.is_moving([1])
    assert bus.positions([1])[1] == pytest.approx(0.0, abs=TICK_DEG)


def test_dropped_reply_is_retried_and_the_value_is_right(bus, emu):
    emu.drop_next(1)
    assert bus.positions([1, 2]) == {1: 0.0, 2: 0.0}
    assert [c.outcome for c in emu.history if c.call == "reply"] == ["dropped"]
    emu.drop_next(1)
    assert bus.hardware_error(2) == 0


def test_persistent_silence_raises_a_timeout_naming_servo_and_port(bus, emu):
    emu.drop_next(100)
    with pytest.raises(DeviceTimeout, match=rf"servo 1 on {emu.port}.*3 times"):
        bus.positions([1, 2])
    emu.clear_faults()
    with pytest.raises(DeviceTimeout, match=rf"servo 2 on {emu.port}"):
        emu.drop_next(100)
        bus.hardware_error(2)


def test_corrupt_reply_is_retried_never_returned(bus, emu):
    bus.set_torque([1, 2], True)
    bus.move({1: 12.0, 2: -7.0})
    settle(bus)
    emu.corrupt_next(1)
    assert bus.positions([1, 2]) == pytest.approx({1: emu.position_deg(1), 2: emu.position_deg(2)})
    assert [c.outcome for c in emu.history if c.call == "reply"] == ["corrupted"]


def test_persistent_corruption_is_a_clear_error(bus, emu):
    emu.corrupt_next(100)
    with pytest.raises(HalError, match=rf"servo 1 on {emu.port}.*Incorrect status packet"):
        bus.hardware_error(1)


def test_alert_bit_reads_the_error_reboots_and_reinitialises(bus, emu):
    bus.set_torque([1, 2], True)
    bus.move({1: 5.0, 2: 5.0})
    settle(bus)
    emu.raise_alert(2, 0x20)  # overload: the servo drops torque
    bus.move({1: -20.0, 2: 25.0})
    settle(bus)  # the first status with the alert bit triggers the recovery
    assert bus.recoveries == [ServoRecovery(2, 0x20)]
    assert [c.args[0] for c in emu.history if c.call == "REBOOT"] == [2]
    assert bus.positions([1, 2]) == pytest.approx({1: -20.0, 2: 25.0}, abs=TICK_DEG)
    assert emu.servos[2].table[Reg.TORQUE_ENABLE] == 1 and bus.hardware_error(2) == 0


def test_random_faults_give_a_retry_or_a_clear_error_never_a_wrong_value(emu):
    bus = DynamixelServoBus(emu.port, latency_ms=LATENCY_MS, retries=3)
    emu.faults = Faults(rate=0.15, seed=7, kinds=frozenset({"drop", "corrupt"}))
    try:
        truth = {1: emu.position_deg(1), 2: emu.position_deg(2)}
        outcomes = {"ok": 0, "error": 0}
        for _ in range(40):
            try:
                assert bus.positions([1, 2]) == truth
                outcomes["ok"] += 1
            except HalError as exc:
                assert "servo" in str(exc) and emu.port in str(exc)
                outcomes["error"] += 1
        assert outcomes["ok"] >= 30  # most reads survive by retrying
        assert {c.outcome for c in emu.history if c.call == "reply"} == {"dropped", "corrupted"}
    finally:
        bus.close()


def test_emulator_ignores_a_packet_with_a_bad_crc(emu):
    bad = bytearray(instruction_packet(1, 0x01))
    bad[-1] ^= 0xFF
    fd = os.open(emu.port, os.O_RDWR | os.O_NOCTTY)
    try:
        os.write(fd, bytes(bad))
        for _ in range(400):
            if emu.history:
                break
            time.sleep(0.005)
    finally:
        os.close(fd)
    assert [c.call for c in emu.history] == ["bad_crc"]


def test_missing_port_is_a_clear_error():
    with pytest.raises(HalError, match="/dev/does-not-exist"):
        DynamixelServoBus("/dev/does-not-exist")


def test_empty_move_sends_nothing(bus, emu):
    bus.move({})
    assert bus.positions([1]) == {1: 0.0}
    assert not [c for c in emu.history if c.call == "SYNC_WRITE"]


def test_alerted_servo_refusing_torque_is_recovered_not_reported_as_refused(bus, emu):
    bus.set_torque([1, 2], True)
    bus.move({2: 15.0})
    settle(bus)
    emu.raise_alert(2, 0x04)  # overheating: the servo refuses torque until rebooted
    bus.set_torque([2], True)
    assert bus.recoveries == [ServoRecovery(2, 0x04)]
    assert emu.servos[2].table[Reg.TORQUE_ENABLE] == 1 and bus.hardware_error(2) == 0
    assert bus.positions([2])[2] == pytest.approx(15.0, abs=TICK_DEG)


def test_unplugged_or_closed_port_is_a_clear_error_never_a_traceback(emu):
    bus = DynamixelServoBus(emu.port, latency_ms=LATENCY_MS)
    bus.set_torque([1], True)
    emu.close()  # the adapter is gone: the pty reports I/O errors, then its node is gone
    with pytest.raises(DeviceGone, match=rf"on {emu.port}: .*port failed .*unplugged\?"):
        bus.positions([1])
    for call in (lambda: bus.hardware_error(1), lambda: bus.move({1: 3.0})):
        with pytest.raises(DeviceGone, match=rf"on {emu.port}: .*port not there \(No such file or directory\)"):
            call()
    assert not bus.ping(1)
    bus.close()
    with pytest.raises(HalError, match="port failed.*not open") as closed:
        bus.positions([1])
    assert not isinstance(closed.value, DeviceGone)  # closed on purpose: nothing to wait for


def test_a_bus_unplugged_mid_sweep_is_gone_until_replugged_then_goes_on_where_it_was(bus, emu):
    bus.set_torque([1, 2], True)
    bus.move({1: 20.0, 2: -10.0})
    settle(bus)
    emu.unplug()  # the USB adapter pulled: the servos keep their power and goals
    with pytest.raises(DeviceGone, match="port failed"):
        bus.positions([1, 2])
    with pytest.raises(DeviceGone, match="port not there"):
        bus.move({1: 30.0})
    assert not bus.ping(1) and [c.call for c in emu.history[-1:]] == ["unplug"]  # nothing reached the servos
    emu.servos[1].table[Reg.TORQUE_ENABLE] = 0  # as a servo that browned out meanwhile
    emu.replug()
    assert bus.positions([1, 2]) == pytest.approx({1: 20.0, 2: -10.0}, abs=TICK_DEG)
    assert emu.servos[1].table[Reg.TORQUE_ENABLE] == 1  # torque and goals restored on reopening
    bus.move({1: 30.0})
    settle(bus)
    assert bus.positions([1])[1] == pytest.approx(30.0, abs=TICK_DEG)


@pytest.mark.parametrize("goal", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_goal_is_a_limit_error_and_nothing_is_sent(bus, emu, goal):
    with pytest.raises(LimitError, match="not a finite angle"):
        bus.move({1: 10.0, 2: goal})
    assert not [c for c in emu.history if c.call == "SYNC_WRITE"]



@pytest.mark.parametrize("garbage", [b"\xff\xff\xfd\x00\x01\x00\x00", b"\xff\xff\xfd\x00\x01\x02\x00\x01",
                                     b"\xff\xff\xfd\x00\x01\xff\xff"])
def test_emulator_survives_a_false_header_and_answers_the_next_packet(emu, garbage):
    fd = os.open(emu.port, os.O_RDWR | os.O_NOCTTY)
    try:
        os.write(fd, garbage + instruction_packet(1, 0x01))
        for _ in range(400):
            if any(c.call == "PING" for c in emu.history):
                break
            time.sleep(0.005)
    finally:
        os.close(fd)
    assert [c.call for c in emu.history] == ["PING"]
