"""The arm: a view pose over the sample becomes servo angles, and back.

Kinematics: a yaw joint turns the arm about the vertical axis through the sample
(joint angle = azimuth, wrapped to [-180°, 180°)); a tilt joint swings the camera on an
arc over the sample (joint angle 0° = straight down = elevation 90°, so tilt = 90° -
elevation). Each joint's calibration maps the joint angle to the servo angle:
servo = sign · joint + offset + correction(joint), the correction interpolated from a
table of measured errors. The yaw servo turns a full circle, so its angle is wrapped
into its travel. `btf-robot calibrate arm` measures each joint's offset and sign against
the tracker (`ArmFit`, stored in the state dir); `ArmCalibration.with_fit` applies it.
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from hal.interfaces import DeviceTimeout, HalError, LimitError, ServoBus, ViewAngles
from hal.state_file import read_state, write_state


@dataclass(frozen=True, slots=True)
class JointCalibration:
    servo_id: int
    min_deg: float
    max_deg: float
    offset_deg: float = 0.0
    sign: float = 1.0
    corrections: tuple[tuple[float, float], ...] = ()  # (joint °, measured correction °), sorted

    def __post_init__(self) -> None:
        if self.sign not in (1.0, -1.0):
            raise ValueError(f"joint sign must be +1 or -1, got {self.sign}")
        if not self.min_deg < self.max_deg:
            raise ValueError(f"servo {self.servo_id}: joint limits [{self.min_deg}, {self.max_deg}] are empty")
        xs = [x for x, _ in self.corrections]
        if xs != sorted(set(xs)):
            raise ValueError(f"servo {self.servo_id}: correction table must be sorted by joint angle")

    def correction(self, joint_deg: float) -> float:
        if not self.corrections:
            return 0.0
        xs, ys = zip(*self.corrections)
        return float(np.interp(joint_deg, xs, ys))

    def servo_deg(self, joint_deg: float) -> float:
        return self.sign * joint_deg + self.offset_deg + self.correction(joint_deg)

    def joint_deg(self, servo_deg: float) -> float:
        # The correction is a small function of the joint angle: a few fixed-point steps invert it.
        joint = self.sign * (servo_deg - self.offset_deg)
        for _ in range(8):
            joint = self.sign * (servo_deg - self.offset_deg - self.correction(joint))
        return joint


@dataclass(frozen=True, slots=True)
class ArmCalibration:
    yaw: JointCalibration = field(default_factory=lambda: JointCalibration(1, -180.0, 179.9))
    tilt: JointCalibration = field(default_factory=lambda: JointCalibration(2, 0.0, 80.0))
    tolerance_deg: float = 1.0  # a settled joint must be this close to its goal
    poll_s: float = 0.01

    @property
    def servo_ids(self) -> list[int]:
        return [self.yaw.servo_id, self.tilt.servo_id]

    def with_fit(self, fit: ArmFit) -> ArmCalibration:
        """This calibration with each joint's offset and sign as measured by `fit`."""
        return dataclasses.replace(
            self, yaw=dataclasses.replace(self.yaw, offset_deg=fit.yaw.offset_deg, sign=fit.yaw.sign),
            tilt=dataclasses.replace(self.tilt, offset_deg=fit.tilt.offset_deg, sign=fit.tilt.sign))


@dataclass(frozen=True, slots=True)
class JointFit:
    """One joint measured against the tracker: servo = sign · joint + offset, and how well it fits."""

    offset_deg: float
    sign: float
    residual_deg: float  # root mean square of what the fit leaves
    poses: int

    def __post_init__(self) -> None:
        if self.sign not in (1.0, -1.0) or not all(math.isfinite(v) for v in (self.offset_deg, self.residual_deg)):
            raise ValueError(f"joint fit needs a finite offset and residual and a sign of +1 or -1, got {self}")


@dataclass(frozen=True, slots=True)
class ArmFit:
    yaw: JointFit
    tilt: JointFit


ARM_FIT_FILE = "arm_calibration.json"


def save_arm_fit(state_dir: str | Path, fit: ArmFit) -> Path:
    """Write `fit` to `state_dir/arm_calibration.json` (whole or not at all)."""
    return write_state(Path(state_dir) / ARM_FIT_FILE, {"version": 1, "yaw": dataclasses.asdict(fit.yaw),
                                                        "tilt": dataclasses.asdict(fit.tilt)})


def load_arm_fit(state_dir: str | Path) -> ArmFit | None:
    """The stored fit, None when the arm was never calibrated; HalError naming the file when it is damaged."""
    path = Path(state_dir) / ARM_FIT_FILE
    try:
        raw = read_state(path)
        if raw is None:
            return None
        return ArmFit(**{name: JointFit(**{k: (int if k == "poses" else float)(raw[name][k])
                                            for k in ("offset_deg", "sign", "residual_deg", "poses")})
                         for name in ("yaw", "tilt")})
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise HalError(f"arm calibration {path}: {exc}; run 'btf-robot calibrate arm' again or remove the file") from None


def _wrap(deg: float) -> float:
    return (deg + 180.0) % 360.0 - 180.0


class Arm:
    def __init__(
        self,
        bus: ServoBus,
        joints: ArmCalibration | None = None,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self.bus = bus
        self.joints = joints or ArmCalibration()
        self.clock = clock
        self.sleep = sleep
        self._goals: dict[int, float] = {}

    def joints_for(self, view: ViewAngles) -> dict[int, float]:
        """Servo angles for a view; LimitError if a joint would leave its range."""
        if not (np.isfinite(view.elevation) and np.isfinite(view.azimuth)):
            raise LimitError(f"view {view} is not finite")
        yaw, tilt = _wrap(view.azimuth), 90.0 - view.elevation
        out = {}
        for cal, angle, name in ((self.joints.yaw, yaw, "azimuth"), (self.joints.tilt, tilt, "elevation")):
            if not cal.min_deg <= angle <= cal.max_deg:
                raise LimitError(
                    f"{name} of {view} needs servo {cal.servo_id} at joint {angle:.1f}°, "
                    f"outside its limits [{cal.min_deg}°, {cal.max_deg}°]"
                )
            servo = cal.servo_deg(angle)
            if cal is self.joints.yaw:
                servo = _wrap(servo)  # a full-turn joint: an offset never costs azimuths
            if not -180.0 <= servo < 180.0:
                raise LimitError(f"{name} of {view} needs servo {cal.servo_id} at {servo:.1f}°, beyond its travel")
            out[cal.servo_id] = servo
        return out

    def view_for(self, servo_deg: dict[int, float]) -> ViewAngles:
        """The view the camera has with the servos at these angles (forward kinematics)."""
        yaw = self.joints.yaw.joint_deg(servo_deg[self.joints.yaw.servo_id])
        tilt = self.joints.tilt.joint_deg(servo_deg[self.joints.tilt.servo_id])
        return ViewAngles(elevation=90.0 - tilt, azimuth=yaw % 360.0)

    def enable(self) -> None:
        self.bus.set_torque(self.joints.servo_ids, True)

    def move_to(self, view: ViewAngles, timeout_s: float = 10.0) -> dict[int, float]:
        """Move to a view and wait until settled; returns the servo angles reached."""
        goals = self.joints_for(view)  # limits checked before anything moves
        self.bus.move(goals)
        self._goals = goals  # only goals the bus took are waited for
        return self.wait_until_stopped(timeout_s)

    def wait_until_stopped(self, timeout_s: float) -> dict[int, float]:
        """Poll until no joint moves; DeviceTimeout if it takes longer than `timeout_s`."""
        ids = self.joints.servo_ids
        deadline = self.clock() + timeout_s
        while self.bus.is_moving(ids):
            if self.clock() >= deadline:
                raise DeviceTimeout(f"arm did not stop within {timeout_s:.1f} s (servos {ids})")
            self.sleep(self.joints.poll_s)
        reached = self.bus.positions(ids)
        for sid, goal in self._goals.items():
            if abs(reached[sid] - goal) > self.joints.tolerance_deg:
                raise HalError(f"servo {sid} stopped at {reached[sid]:.1f}°, short of its goal {goal:.1f}°")
        return reached

    def stop_and_hold(self) -> None:
        """Failsafe: hold every joint where it is now."""
        here = self.bus.positions(self.joints.servo_ids)
        self.bus.move(here)
        self._goals = here

    def torque_off(self) -> None:
        self._goals = {}
        self.bus.set_torque(self.joints.servo_ids, False)
