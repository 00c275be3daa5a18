"""The fake servo bus behaves like servos on a clock, and the shared fault helper is seeded."""
from __future__ import annotations

import pytest

from hal.fakes import Call, Faults
from hal.fakes.servo import FakeClock, FakeServoBus
from hal.interfaces import DeviceTimeout, HalError, LimitError, ServoBus, ServoRecovery


def make(**kw) -> tuple[FakeServoBus, FakeClock]:
    clock = FakeClock()
    return FakeServoBus((1, 2), clock=clock, speed_deg_s=100.0, **kw), clock


def test_faults_never_fire_at_rate_zero_and_always_at_rate_one():
    assert not any(Faults().hit("timeout") for _ in range(100))
    assert all(Faults(rate=1.0).hit("timeout") for _ in range(100))


def test_faults_are_reproducible_per_seed_and_filtered_by_kind():
    def draw(seed: int) -> list[bool]:
        f = Faults(rate=0.5, seed=seed)
        return [f.hit("x") for _ in range(64)]

    draws = [draw(s) for s in (3, 3, 4)]
    assert 10 < sum(draws[0]) < 54
    assert draws[0] == draws[1] != draws[2]
    only = Faults(rate=1.0, kinds=frozenset({"drop"}))
    assert only.hit("drop") and not only.hit("corrupt")


def test_forced_faults_fire_until_the_budget_runs_out():
    f = Faults(force={"alert"}, remaining=2)
    assert [f.hit("alert") for _ in range(4)] == [True, True, False, False]


def test_fault_rate_outside_unit_interval_is_refused():
    with pytest.raises(ValueError, match="rate"):
        Faults(rate=1.5)


def test_clock_refuses_to_run_backwards():
    with pytest.raises(ValueError):
        FakeClock().advance(-1.0)


def test_fake_is_a_servo_bus():
    assert isinstance(make()[0], ServoBus)


def test_positions_move_toward_goals_at_the_set_speed():
    bus, clock = make()
    bus.set_torque([1, 2], True)
    bus.move({1: 50.0, 2: -20.0})
    clock.advance(0.1)
    assert bus.positions([1, 2]) == pytest.approx({1: 10.0, 2: -10.0})
    assert bus.is_moving([1, 2])
    clock.advance(0.45)
    assert bus.positions([1, 2]) == pytest.approx({1: 50.0, 2: -20.0})
    assert not bus.is_moving([1, 2])


def test_without_torque_nothing_moves():
    bus, clock = make()
    bus.move({1: 50.0})
    clock.advance(5.0)
    assert bus.positions([1]) == {1: 0.0}
    assert not bus.is_moving([1])


def test_history_records_calls_and_outcomes():
    bus, _ = make()
    bus.set_torque([1], True)
    bus.move({1: 5.0})
    assert bus.history == [Call("set_torque", ((1,), True), "ok"), Call("move", ({1: 5.0},), "ok")]


def test_out_of_range_goal_is_refused_and_nothing_moves():
    bus, clock = make()
    bus.set_torque([1, 2], True)
    with pytest.raises(LimitError):
        bus.move({1: 30.0, 2: 181.0})
    clock.advance(1.0)
    assert bus.positions([1, 2]) == {1: 0.0, 2: 0.0}


def test_unknown_servo_times_out_and_does_not_ping():
    bus, _ = make()
    assert not bus.ping(9)
    with pytest.raises(DeviceTimeout, match="servo 9"):
        bus.positions([9])


def test_timeout_fault_raises_and_is_recorded():
    bus, _ = make(faults=Faults(force={"timeout"}, remaining=1))
    with pytest.raises(DeviceTimeout, match="servo 1"):
        bus.positions([1, 2])
    assert bus.history[-1].outcome == "timeout"
    assert bus.positions([1, 2]) == {1: 0.0, 2: 0.0}


def test_alert_is_recovered_and_the_move_completes():
    bus, clock = make(faults=Faults(rate=1.0, kinds=frozenset({"alert"})))
    bus.set_torque([1, 2], True)
    bus.move({2: 30.0})
    clock.advance(1.0)
    assert bus.positions([2]) == {2: 30.0}
    assert ServoRecovery(1, 0x20) in bus.recoveries and ServoRecovery(2, 0x20) in bus.recoveries
    assert bus.hardware_error(1) == 0


def test_stalled_servo_keeps_moving_short_of_its_goal_until_rebooted():
    bus, clock = make(faults=Faults(force={"stall"}, remaining=1))
    bus.set_torque([1], True)
    bus.move({1: 30.0})
    clock.advance(2.0)
    assert bus.is_moving([1]) and bus.positions([1]) == {1: 0.0}
    bus.reboot(1)
    clock.advance(1.0)
    assert bus.positions([1]) == {1: 30.0} and not bus.is_moving([1])


def test_closed_bus_refuses_calls():
    bus, _ = make()
    bus.close()
    with pytest.raises(HalError, match="closed"):
        bus.positions([1])


def test_ping_is_false_on_a_timeout_and_records_it():
    bus, _ = make(faults=Faults(force={"timeout"}, remaining=1))
    assert not bus.ping(1)
    assert bus.ping(1)
    assert [c.outcome for c in bus.history] == ["timeout", "ok"]
