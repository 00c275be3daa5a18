"""The hardware seams. Code above `hal/` sees only these; the factory picks the body.

Angles are degrees at every interface; device units (servo ticks, 1/16° Euler
registers) stay inside the drivers.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np


class HalError(RuntimeError):
    """A device failed after its bounded retries; the message names the device and why."""


class DeviceTimeout(HalError):
    """A device did not answer (or did not settle) within its time limit."""


class LimitError(HalError):
    """A requested move lies outside a joint's limits; nothing was moved."""


@dataclass(frozen=True, slots=True)
class ViewAngles:
    """Where the camera looks from, over the sample: elevation 90° is straight down."""

    elevation: float
    azimuth: float = 0.0


@dataclass(frozen=True, slots=True)
class Orientation:
    heading: float
    roll: float
    pitch: float


@dataclass(frozen=True, slots=True)
class Calibration:
    """BNO055-style calibration status, each 0 (uncalibrated) to 3 (fully calibrated)."""

    system: int
    gyro: int
    accel: int
    mag: int

    @property
    def ok(self) -> bool:
        return min(self.system, self.gyro, self.accel, self.mag) >= 1


@dataclass(frozen=True, slots=True)
class ServoRecovery:
    """A servo raised its alert bit; the bus read `hardware_error`, rebooted and restored it."""

    servo_id: int
    hardware_error: int


@runtime_checkable
class ServoBus(Protocol):
    def ping(self, servo_id: int) -> bool: ...
    def set_torque(self, servo_ids: list[int], enabled: bool) -> None: ...
    def move(self, goals_deg: dict[int, float]) -> None: ...
    def positions(self, servo_ids: list[int]) -> dict[int, float]: ...
    def is_moving(self, servo_ids: list[int]) -> bool: ...
    def hardware_error(self, servo_id: int) -> int: ...
    def reboot(self, servo_id: int) -> None: ...
    def close(self) -> None: ...


@runtime_checkable
class OrientationTracker(Protocol):
    def orientation(self) -> Orientation: ...
    def calibration(self) -> Calibration: ...
    def close(self) -> None: ...


@runtime_checkable
class Camera(Protocol):
    def open(self, width: int, height: int, pixel_format: str = "BGR3") -> None: ...
    def capture(self) -> np.ndarray: ...
    def close(self) -> None: ...


def view_from_orientation(o: Orientation) -> ViewAngles:
    """The camera's view over the sample from the tracker mounted on it.

    The tracker sits on the camera with pitch -90° when the camera looks straight down,
    so the view elevation is -pitch; the azimuth is the heading.
    """
    return ViewAngles(elevation=-o.pitch, azimuth=o.heading % 360.0)
