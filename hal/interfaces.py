"""The hardware seams. Code above `hal/` sees only these; the factory picks the body.

Angles are degrees at every interface; device units (servo ticks, 1/16° Euler
registers) stay inside the drivers.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum
from typing import Protocol, runtime_checkable

import numpy as np


class HalError(RuntimeError):
    """A device failed after its bounded retries; the message names the device and why."""


class NotGranted(HalError):
    """The device is there but will not give what the configuration asks (a frame size or a
    pixel format its driver does not offer): no restart can mend it, the configuration must change."""


class DeviceTimeout(HalError):
    """A device did not answer (or did not settle) within its time limit."""


class LimitError(HalError):
    """A requested move lies outside a joint's limits; nothing was moved."""


class DeviceGone(HalError):
    """The device is not there (unplugged, its port vanished, powered off): every call fails
    until it returns. No retry can help now; the robot pauses and asks again until it answers."""


class DeviceSpent(HalError):
    """A device with nothing more to give (a replay that played its last file): trying again,
    now or later, cannot help."""


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
    recoveries: list[ServoRecovery]  # alerts the bus cleared by rebooting a servo

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


@dataclass(frozen=True, slots=True)
class CameraControls:
    """What a camera is asked for; None is `auto` for that control.

    Exposure in microseconds; analogue gain as a multiple (picamera2 and the fakes) or in the
    V4L2 driver's own units (`v4l2-ctl --list-ctrls` shows its range); white balance either
    as a colour temperature in kelvin or as (red, blue) gains, never both.
    """

    exposure_us: float | None = None
    gain: float | None = None
    white_balance_kelvin: float | None = None
    white_balance_gains: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        for name in ("exposure_us", "gain", "white_balance_kelvin"):
            value = getattr(self, name)
            least = 0.0 if name == "gain" else math.ulp(0.0)  # a V4L2 gain of 0 is the driver's lowest
            if value is not None and not (math.isfinite(value) and value >= least):
                raise ValueError(f"camera {name} must be a positive number or auto, got {value!r}")
        if self.white_balance_gains is not None:
            gains = tuple(self.white_balance_gains)
            if len(gains) != 2 or not all(math.isfinite(g) and g > 0 for g in gains):
                raise ValueError(f"camera white balance gains must be two positive numbers (red, blue), got {gains!r}")
            object.__setattr__(self, "white_balance_gains", (float(gains[0]), float(gains[1])))
            if self.white_balance_kelvin is not None:
                raise ValueError("camera white balance is a colour temperature or (red, blue) gains, not both")

    @property
    def manual_white_balance(self) -> bool:
        return self.white_balance_kelvin is not None or self.white_balance_gains is not None

    @property
    def locked(self) -> bool:
        """Every control manual: nothing the camera decides changes between views."""
        return self.exposure_us is not None and self.gain is not None and self.manual_white_balance


@dataclass(frozen=True, slots=True)
class CameraSettings:
    """What the camera reports it captures with, read back from the device (None: not reported).

    `lock_held` is False when a manual control asked for was not granted, or the device
    still reports the automatic mode for it; `problems` says which, one line each. `source`
    names the file the last frame was read from, for a camera that plays files.
    """

    exposure_us: float | None
    gain: float | None
    white_balance_kelvin: float | None = None
    white_balance_gains: tuple[float, float] | None = None
    sensor_temperature_c: float | None = None
    auto_exposure: bool = False
    auto_gain: bool = False
    auto_white_balance: bool = False
    lock_held: bool = True
    problems: tuple[str, ...] = field(default=())
    source: str | None = None

    @property
    def locked(self) -> bool:
        """The lock held and nothing is left to the camera's automatics."""
        return self.lock_held and not (self.auto_exposure or self.auto_gain or self.auto_white_balance)


@runtime_checkable
class Camera(Protocol):
    def open(self, width: int, height: int, pixel_format: str = "BGR3") -> None: ...
    def capture(self) -> np.ndarray: ...
    def set_controls(self, controls: CameraControls) -> CameraSettings: ...
    def settings(self) -> CameraSettings: ...
    def close(self) -> None: ...


@runtime_checkable
class GroundTruth(Protocol):
    """An optional capability, of the fake camera only: the true label map of the frame it
    last returned. Only `segment.method = "scene"` (tests and the demo) reads it."""

    def true_labels(self) -> np.ndarray | None: ...


class Body(str, Enum):
    REAL = "real"
    EMULATED = "emulated"
    FAKE = "fake"


def view_from_orientation(o: Orientation) -> ViewAngles:
    """The camera's view over the sample from the tracker mounted on it.

    The tracker sits on the camera with pitch -90° when the camera looks straight down,
    so the view elevation is -pitch; the azimuth is the heading.
    """
    return ViewAngles(elevation=-o.pitch, azimuth=o.heading % 360.0)
