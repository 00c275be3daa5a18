"""`btf-robot selftest`: exercise every device once and print one JSON line per device.

Exit status 0 when every device passes, 1 when any fails, 2 for bad usage.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from hal.controls import describe, hold
from hal.devices import Hal
from hal.factory import HalConfigError, build_hal
from hal.interfaces import ViewAngles, view_from_orientation
from onboard.cli.runner import CliError
from onboard.config import ConfigError, load

POSES = (ViewAngles(60.0, 0.0), ViewAngles(90.0, 0.0))
POSE_TOLERANCE_DEG = 2.0
SERVO_NUDGE_DEG = 5.0
TRACKER_TOLERANCE_DEG = 3.0
SETTLE_TIMEOUT_S = 10.0
LOCK_FRAMES = 3  # frames the exposure lock must survive


@dataclass(frozen=True, slots=True)
class DeviceResult:
    device: str
    ok: bool
    detail: str

    def json(self) -> str:
        return json.dumps({"device": self.device, "ok": self.ok, "detail": self.detail})


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--hal", choices=("fake", "emulated", "real"), help="device body (default: config or BTF_HAL)")
    p.add_argument("--config", metavar="FILE", help="robot TOML config; its [hal] section is used")


def _hal_options(args: argparse.Namespace) -> dict[str, Any] | None:
    """The [hal] section of --config (if given), its body overridden by --hal."""
    options: dict[str, Any] | None = None
    if args.config:
        try:
            cfg = load(args.config)
        except ConfigError as exc:
            raise CliError(str(exc)) from None
        options = {k: getattr(cfg.hal, k) for k in cfg.hal.__slots__}
    if args.hal:
        options = {**(options or {}), "body": args.hal}
    return options


def run(args: argparse.Namespace) -> int:
    options = _hal_options(args)
    state_dir = None
    if args.config:  # the robot's own state: its arm calibration applies

        state_dir = load(args.config).state_dir
    try:
        hal = build_hal(options, state_dir=state_dir)
    except HalConfigError as exc:
        raise CliError(str(exc)) from None
    except Exception as exc:  # noqa: BLE001 - a device that cannot even be built fails the test
        print(DeviceResult("hal", False, f"{type(exc).__name__}: {exc}").json(), flush=True)
        return 1
    try:
        results = [_check(name, fn, hal) for name, fn in CHECKS]
    finally:
        hal.close()
    for r in results:
        print(r.json(), flush=True)
    for r in results:
        if not r.ok:
            print(f"btf-robot selftest: FAILED {r.device}: {r.detail}", file=sys.stderr)
    return 0 if all(r.ok for r in results) else 1


def _check(name: str, fn: Callable[[Any], str], hal: Hal) -> DeviceResult:
    try:
        return DeviceResult(name, True, fn(hal))
    except Exception as exc:  # noqa: BLE001 - every failure is reported, none escapes
        return DeviceResult(name, False, f"{type(exc).__name__}: {exc}")


def _servo_bus(hal: Hal) -> str:
    bus, ids = hal.servo_bus, hal.arm.joints.servo_ids
    missing = [i for i in ids if not bus.ping(i)]
    if missing:
        raise RuntimeError(f"servos {missing} do not answer a ping")
    bus.set_torque(ids, True)
    start = bus.positions(ids)
    joints = {j.servo_id: j for j in (hal.arm.joints.yaw, hal.arm.joints.tilt)}
    goals = {i: _nudge(joints[i], start[i]) for i in ids}
    bus.move(goals)
    hal.arm.wait_until_stopped(SETTLE_TIMEOUT_S)
    reached = bus.positions(ids)
    off = {i: round(reached[i] - goals[i], 2) for i in ids if abs(reached[i] - goals[i]) > POSE_TOLERANCE_DEG}
    if off:
        raise RuntimeError(f"servos missed their goals by {off} degrees")
    if bus.is_moving(ids):
        raise RuntimeError("servos report moving after they settled")
    errors = {i: bus.hardware_error(i) for i in ids}
    if any(errors.values()):
        raise RuntimeError(f"hardware error status {errors}")
    recovered = len(bus.recoveries)
    return f"servos {ids} ping, torque, move {SERVO_NUDGE_DEG} deg, settle, no hardware error; {recovered} recoveries"


def _nudge(joint: Any, servo_deg: float) -> float:
    """A servo angle one nudge away, toward the middle of the joint's limits (never into a stop)."""
    here = joint.joint_deg(servo_deg)
    toward = 1.0 if here < (joint.min_deg + joint.max_deg) / 2.0 else -1.0
    return joint.servo_deg(here + toward * SERVO_NUDGE_DEG)


def _arm(hal: Hal) -> str:
    arm = hal.arm
    arm.enable()
    seen = []
    for pose in POSES:
        reached = arm.view_for(arm.move_to(pose, SETTLE_TIMEOUT_S))
        if abs(reached.elevation - pose.elevation) > POSE_TOLERANCE_DEG:
            raise RuntimeError(f"asked for {pose}, reached {reached}")
        seen.append(f"{reached.elevation:.1f} deg")
    return "reached elevations " + ", ".join(seen)


def _tracker(hal: Hal) -> str:
    o = hal.tracker.orientation()
    values = (o.heading, o.roll, o.pitch)
    if not all(math.isfinite(v) for v in values):
        raise RuntimeError(f"non-finite orientation {o}")
    seen = view_from_orientation(o)
    arm = hal.arm.view_for(hal.servo_bus.positions(hal.arm.joints.servo_ids))  # where the servos say it looks
    if abs(seen.elevation - arm.elevation) > TRACKER_TOLERANCE_DEG:
        raise RuntimeError(f"tracker sees elevation {seen.elevation:.1f} deg, the arm is at {arm.elevation:.1f}")
    cal = hal.tracker.calibration()
    return f"heading {o.heading:.1f} deg roll {o.roll:.1f} deg pitch {o.pitch:.1f} deg; calibration {cal}"


def _camera(hal: Hal) -> str:
    """A frame of the right shape, and a manual lock of exposure, gain and white balance at
    the values the camera stands at that holds for a few frames: a camera that keeps its
    automatics running would flatten the change with the view that a sweep measures."""
    cam = hal.camera
    h, w = hal.size
    hal.open_camera()
    try:
        granted = cam.set_controls(hold(cam.settings()))
        frames = [cam.capture() for _ in range(LOCK_FRAMES)]
        held = cam.settings()
    finally:
        cam.close()
    frame = frames[-1]
    if not isinstance(frame, np.ndarray) or frame.ndim != 3 or frame.shape[:2] != (h, w):
        raise RuntimeError(f"frame shape {getattr(frame, 'shape', None)}, expected ({h}, {w}, C)")
    if frame.dtype not in (np.uint8, np.uint16):
        raise RuntimeError(f"frame dtype {frame.dtype}, expected uint8 or uint16")
    if not (granted.locked and held.locked):
        problems = dict.fromkeys(granted.problems + held.problems) or ("the device reports its automatics on",)
        raise RuntimeError("the camera does not honour a manual exposure/gain/white balance lock: "
                           + "; ".join(problems) + " (captures would follow its automatics, not the view)")
    return f"frame {frame.shape} {frame.dtype}; {describe(held)}"


CHECKS: tuple[tuple[str, Callable[[Any], str]], ...] = (
    ("servo_bus", _servo_bus),
    ("arm", _arm),
    ("tracker", _tracker),
    ("camera", _camera),
)
