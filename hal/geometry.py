"""Geometric calibration against the tracker: each joint's offset and sign, and the tracker's axis remap.

Both move the arm through a few poses and read the tracker there, so they run on any
body (fake, emulated, real). The arm fit is absolute: it relates the angles the servos
report to the view the tracker measures, so the calibration in force does not matter
and calibrating twice gives the same answer.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from hal.arm import Arm, ArmFit, JointCalibration, JointFit
from hal.bno055 import AxisRemap
from hal.devices import Hal
from hal.interfaces import HalError, Orientation, ViewAngles, view_from_orientation
from hal.orientation import fit_rotation, nearest_axis_rotation, up_in_camera, up_in_device

READINGS_PER_POSE = 5
YAW_POSES_DEG = (-90.0, -30.0, 30.0, 90.0)  # yaw joint, at `YAW_TILT_DEG`
YAW_TILT_DEG = 40.0  # tilted well away from straight down, where the heading means the azimuth
TILT_POSES_DEG = (10.0, 25.0, 40.0, 55.0)  # tilt joint, at yaw 0
GOOD_FIT_DEG = 1.0  # a joint whose residual is larger is not a rigid offset: something is loose
TRACKER_POSES = (ViewAngles(90.0, 0.0), ViewAngles(60.0, 0.0))
NADIR_TOLERANCE_DEG = 5.0
SQUARE_TOLERANCE_DEG = 10.0  # farther from a square mounting: remount rather than remap
SETTLE_TIMEOUT_S = 15.0


def _wrap(deg: float) -> float:
    return (deg + 180.0) % 360.0 - 180.0


def _circular_mean(deg: list[float]) -> float:
    rad = np.radians(deg)
    return math.degrees(math.atan2(float(np.sin(rad).mean()), float(np.cos(rad).mean())))


@dataclass(frozen=True, slots=True)
class Sample:
    """One pose: the servo angles reached and the view the tracker measured (averaged)."""

    servo_deg: dict[int, float]
    seen: ViewAngles


def measure(arm: Arm, tracker: Any, view: ViewAngles, readings: int = READINGS_PER_POSE) -> Sample:
    reached = arm.move_to(view, SETTLE_TIMEOUT_S)
    seen = [view_from_orientation(tracker.orientation()) for _ in range(readings)]
    return Sample(reached, ViewAngles(float(np.mean([v.elevation for v in seen])),
                                      _circular_mean([v.azimuth for v in seen]) % 360.0))


def fit_joint(servo: list[float], measured: list[float], joint: JointCalibration, circular: bool) -> JointFit:
    """servo ≈ sign · measured + offset (+ the joint's correction table), the sign with the smaller residual."""
    best: JointFit | None = None
    for sign in (1.0, -1.0):
        rest = [s - sign * m - joint.correction(m) for s, m in zip(servo, measured)]
        if circular:
            offset = _circular_mean(rest)
            errors = [_wrap(r - offset) for r in rest]
        else:
            offset = float(np.mean(rest))
            errors = [r - offset for r in rest]
        fit = JointFit(offset, sign, float(np.sqrt(np.mean(np.square(errors)))), len(servo))
        if best is None or fit.residual_deg < best.residual_deg:
            best = fit
    assert best is not None
    return best


@dataclass(frozen=True, slots=True)
class ArmReport:
    fit: ArmFit
    check_error_deg: float  # commanded against measured at a check pose, with the fit applied
    check_view: ViewAngles

    @property
    def ok(self) -> bool:
        return max(self.fit.yaw.residual_deg, self.fit.tilt.residual_deg, self.check_error_deg) <= GOOD_FIT_DEG


def calibrate_arm(hal: Hal) -> ArmReport:
    """Fit yaw from a turn at a fixed tilt, then tilt from a swing at a fixed yaw; check the result."""
    arm: Arm = hal.arm
    joints = arm.joints
    arm.enable()
    yaw_samples = [measure(arm, hal.tracker, ViewAngles(90.0 - YAW_TILT_DEG, a)) for a in YAW_POSES_DEG]
    yaw = fit_joint([s.servo_deg[joints.yaw.servo_id] for s in yaw_samples],
                    [s.seen.azimuth for s in yaw_samples], joints.yaw, circular=True)
    tilt_samples = [measure(arm, hal.tracker, ViewAngles(90.0 - t, 0.0)) for t in TILT_POSES_DEG]
    signed = []
    for s in tilt_samples:  # a tilt past straight down looks from the other side: negative
        azimuth = yaw.sign * (s.servo_deg[joints.yaw.servo_id] - yaw.offset_deg)
        behind = abs(_wrap(s.seen.azimuth - azimuth)) > 90.0
        signed.append(-(90.0 - s.seen.elevation) if behind else 90.0 - s.seen.elevation)
    tilt = fit_joint([s.servo_deg[joints.tilt.servo_id] for s in tilt_samples], signed, joints.tilt, circular=False)
    fit = ArmFit(yaw, tilt)
    checked = Arm(hal.servo_bus, joints.with_fit(fit), clock=arm.clock, sleep=arm.sleep)
    view = ViewAngles(50.0, 20.0)
    seen = measure(checked, hal.tracker, view).seen
    error = math.hypot(seen.elevation - view.elevation,
                       _wrap(seen.azimuth - view.azimuth) * math.cos(math.radians(view.elevation)))
    return ArmReport(fit, error, view)


@dataclass(frozen=True, slots=True)
class TrackerReport:
    nadir: Orientation  # what the tracker reads looking straight down (averaged)
    current: AxisRemap
    needed: AxisRemap
    off_square_deg: float  # how far the mounting is from the nearest square one

    @property
    def nadir_ok(self) -> bool:
        return abs(self.nadir.pitch + 90.0) <= NADIR_TOLERANCE_DEG and abs(self.nadir.roll) <= NADIR_TOLERANCE_DEG

    @property
    def ok(self) -> bool:
        return self.nadir_ok and self.needed == self.current and self.off_square_deg <= SQUARE_TOLERANCE_DEG


def calibrate_tracker(hal: Hal, readings: int = READINGS_PER_POSE) -> TrackerReport:
    """Read which way is up in the tracker's axes looking straight down and tilted; the
    rotation that carries the camera's up into them is the mounting the remap must undo.
    Up comes from roll and pitch only, so the compass plays no part."""
    arm: Arm = hal.arm
    arm.enable()
    ups, cameras, nadir = [], [], None
    for pose in TRACKER_POSES:
        arm.move_to(pose, SETTLE_TIMEOUT_S)
        seen = [hal.tracker.orientation() for _ in range(readings)]
        if pose.elevation == 90.0:
            nadir = Orientation(_circular_mean([o.heading for o in seen]) % 360.0,
                                float(np.mean([o.roll for o in seen])), _circular_mean([o.pitch for o in seen]))
        up = np.mean([up_in_device(o) for o in seen], axis=0)
        ups.append(up / np.linalg.norm(up))
        cameras.append(up_in_camera(pose.elevation))
    if nadir is None:
        raise HalError("tracker calibration needs the straight-down pose")
    current = getattr(hal.tracker, "remap", None) or AxisRemap()
    mounting, off = nearest_axis_rotation(fit_rotation(ups, cameras))
    needed = AxisRemap.from_matrix(mounting @ current.matrix)
    return TrackerReport(nadir, current, needed, off)
