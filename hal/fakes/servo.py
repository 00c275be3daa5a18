"""An in-process servo bus whose servos move toward their goals over a clock.

Fault kinds (drawn from `Faults`): "timeout" (the call raises DeviceTimeout naming the
servo), "alert" (a hardware error that the fake handles as the real driver does: logged
in `recoveries`, torque and goal restored, the call completes), "stall" (a servo stops
short of its goal and keeps reporting that it moves). `unplug()` takes the bus's port away
(its USB adapter pulled: the servos keep their power, goals and torque) until `replug()`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

from hal.fakes import Call, Faults
from hal.interfaces import DeviceGone, DeviceTimeout, HalError, LimitError, ServoRecovery

OVERLOAD = 0x20


class FakeClock:
    """A clock that moves only when told: `advance(dt)`, or `sleep(dt)` as a drop-in."""

    def __init__(self, start: float = 0.0) -> None:
        self.now = start

    def __call__(self) -> float:
        return self.now

    def advance(self, dt: float) -> None:
        if dt < 0:
            raise ValueError("a clock does not run backwards")
        self.now += dt

    sleep = advance


@dataclass
class _Servo:
    position: float = 0.0
    goal: float = 0.0
    torque: bool = False
    stalled: bool = False


@dataclass
class FakeServoBus:
    """A `ServoBus` of servos turning at `speed_deg_s` toward their goals while torque is on."""

    servo_ids: tuple[int, ...] = (1, 2)
    clock: Callable[[], float] = time.monotonic
    speed_deg_s: float = 120.0
    faults: Faults = field(default_factory=Faults)
    start_deg: dict[int, float] = field(default_factory=dict)
    history: list[Call] = field(default_factory=list)
    recoveries: list[ServoRecovery] = field(default_factory=list)

    def __post_init__(self) -> None:
        if self.speed_deg_s <= 0:
            raise ValueError("servo speed must be positive")
        self._servos = {i: _Servo(self.start_deg.get(i, 0.0), self.start_deg.get(i, 0.0)) for i in self.servo_ids}
        self._last = self.clock()
        self._closed = False
        self.unplugged = False

    # -- ServoBus -------------------------------------------------------------------
    def ping(self, servo_id: int) -> bool:
        return bool(self._enter("ping", (servo_id,), [servo_id], raise_timeout=False))

    def set_torque(self, servo_ids: list[int], enabled: bool) -> None:
        for servo in self._enter("set_torque", (tuple(servo_ids), enabled), servo_ids):
            servo.torque = enabled
            servo.goal = servo.position
            servo.stalled = False

    def move(self, goals_deg: dict[int, float]) -> None:
        for sid, deg in goals_deg.items():
            if not -180.0 <= deg < 180.0:
                raise LimitError(f"goal {deg:.2f}° for servo {sid} is outside [-180°, 180°)")
        servos = self._enter("move", (dict(goals_deg),), list(goals_deg))
        for sid, servo in zip(goals_deg, servos):
            servo.goal = goals_deg[sid]
            servo.stalled = self.faults.hit("stall")

    def positions(self, servo_ids: list[int]) -> dict[int, float]:
        servos = self._enter("positions", (tuple(servo_ids),), servo_ids)
        return {sid: s.position for sid, s in zip(servo_ids, servos)}

    def is_moving(self, servo_ids: list[int]) -> bool:
        servos = self._enter("is_moving", (tuple(servo_ids),), servo_ids)
        return any(s.torque and (s.stalled or s.position != s.goal) for s in servos)

    def hardware_error(self, servo_id: int) -> int:
        self._enter("hardware_error", (servo_id,), [servo_id])
        return 0  # an alert is always recovered within the call that saw it

    def reboot(self, servo_id: int) -> None:
        (servo,) = self._enter("reboot", (servo_id,), [servo_id])
        servo.stalled = False

    def close(self) -> None:
        self._closed = True
        self.history.append(Call("close", (), "ok"))

    # -- the world ------------------------------------------------------------------
    def unplug(self) -> None:
        """The bus's port vanishes: every call raises DeviceGone until `replug`."""
        self.unplugged = True

    def replug(self) -> None:
        self.unplugged = False

    def true_positions(self) -> dict[int, float]:
        """Where the servos really are now (no call recorded, no fault drawn)."""
        self._advance()
        return {sid: s.position for sid, s in self._servos.items()}

    def _advance(self) -> None:
        now = self.clock()
        step = self.speed_deg_s * max(0.0, now - self._last)
        self._last = now
        for s in self._servos.values():
            if not s.torque or s.stalled:
                continue
            delta = s.goal - s.position
            s.position = s.goal if abs(delta) <= step else s.position + (step if delta > 0 else -step)

    def _enter(self, call: str, args: tuple, servo_ids: list[int], raise_timeout: bool = True) -> list[_Servo]:
        """Advance the world, draw faults, record the call; return the addressed servos."""
        if self._closed:
            raise HalError("fake servo bus is closed")
        self._advance()
        if self.unplugged:
            self.history.append(Call(call, args, "gone"))
            if not raise_timeout:  # a ping, as the driver's: no answer
                return []
            raise DeviceGone("fake servo bus: its port is gone (unplugged)")
        unknown = [sid for sid in servo_ids if sid not in self._servos]
        if unknown and call != "ping":
            self.history.append(Call(call, args, "timeout"))
            raise DeviceTimeout(f"servo {unknown[0]} on fake bus: no status packet")
        if self.faults.hit("timeout"):
            self.history.append(Call(call, args, "timeout"))
            if raise_timeout:
                raise DeviceTimeout(f"servo {servo_ids[0] if servo_ids else '?'} on fake bus: no status packet")
            return []
        outcome = "ok"
        if servo_ids and call != "ping" and self.faults.hit("alert"):
            sid = servo_ids[0]
            self.recoveries.append(ServoRecovery(sid, OVERLOAD))
            outcome = "alert"  # the driver reboots and restores torque and goal: no visible move lost
        self.history.append(Call(call, args, outcome))
        return [self._servos[sid] for sid in servo_ids if sid in self._servos]
