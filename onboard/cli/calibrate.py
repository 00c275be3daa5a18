"""`btf-robot calibrate arm | tracker | exposure`: the arm's joint offsets and signs, the
tracker's axis remap, and the exposure a sweep keeps.

`arm` and `tracker` move the arm and read the tracker. `arm` stores its fit in the state dir
(`arm_calibration.json`), which `run` and `selftest --config` apply; `tracker` names the
BNO055 axis remap to set (`[hal] tracker_remap`). `exposure` measures the extremes of the
config's sweep plan and stores the exposure that keeps its brightest view below saturation
by `[camera] calibrate_margin` (`camera_exposure.json`, which `run` applies). Exit 0 when the
result is good, 1 when the hardware needs a person (what to do is printed), 2 for bad usage.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hal.arm import save_arm_fit
from hal.controls import describe
from hal.factory import HalConfigError, build_hal
from hal.geometry import GOOD_FIT_DEG, NADIR_TOLERANCE_DEG, SQUARE_TOLERANCE_DEG, calibrate_arm, calibrate_tracker
from hal.interfaces import NotGranted
from onboard.capture.camera_lock import CameraLock
from onboard.capture.exposure import calibrate_exposure, plan_extremes, save_exposure
from onboard.cli.runner import CliError, HelpFormatter, bounded
from onboard.cli.selftest import _hal_options
from onboard.config import Config, SweepConfig, load
from onboard.sweep.plan import SweepPlan

if TYPE_CHECKING:
    from hal.devices import Hal


# Each target: one line for the list of targets, what its own --help says it does, and an example.
TARGETS = {
    "arm": ("fit the arm's joint offsets and signs against the tracker, and store them",
            ("Move the arm through several poses, fit each joint's offset and sign (servo = sign * joint + offset) "
             "against the tracker, and store the fit in the state dir (arm_calibration.json), which run and "
             "selftest --config apply. Exit status 0 when the fit is good and stored, 1 when the hardware needs a "
             "person (what to do is printed)."),
            "calibrate arm --config robot.toml"),
    "tracker": ("name the axis remap the tracker's mounting needs (nothing stored)",
                ("Point the camera straight down, read the tracker, and name the BNO055 axis remap its mounting "
                 "needs ([hal] tracker_remap); nothing is stored. Exit status 0 when the remap in force is right, "
                 "1 when it is not (the setting to make is printed)."),
                "calibrate tracker --config robot.toml"),
    "exposure": ("store the exposure that keeps the sweep's brightest view below saturation",
                 ("Measure the extremes of the config's sweep plan and store the exposure that keeps the brightest "
                  "view below saturation by [camera] calibrate_margin (camera_exposure.json in the state dir, "
                  "which run applies). Exit status 0 when stored, 1 when no exposure fits (what to do is printed)."),
                 "calibrate exposure --config robot.toml"),
}


def add_arguments(p: argparse.ArgumentParser) -> None:
    targets = p.add_subparsers(dest="what", required=True, metavar="TARGET",
                               help="what to calibrate (each has its own --help)")
    for name, (summary, description, example) in TARGETS.items():
        t = targets.add_parser(name, help=summary, description=description, epilog=f"example:\n  btf-robot {example}",
                               formatter_class=HelpFormatter)
        _common_options(t)
        if name == "exposure":
            t.add_argument("--start-exposure", type=bounded(float, 1, 1e8, "microseconds"), metavar="US",
                           help="the first exposure tried, in microseconds (default: where the camera stands)")
        else:
            t.add_argument("--tracker-remap", metavar="P", help="try this BNO055 remap (P0..P7 or CONFIG/SIGN) "
                                                                "instead of the config's")
            _fault_options(t)


def _common_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--hal", choices=("fake", "emulated", "real"), help="device body (default: config or BTF_HAL)")
    p.add_argument("--config", metavar="FILE", help="robot TOML config: its [hal] section and state_dir")
    p.add_argument("--state-dir", metavar="DIR", help="where the calibration is kept (default: the config's, "
                                                      "else ./state)")
    p.add_argument("--json", action="store_true", help="one JSON object instead of text")


def _fault_options(p: argparse.ArgumentParser) -> None:
    fake = p.add_argument_group("deliberate faults of the fake and emulated bodies")
    fake.add_argument("--fake-joint-offset", action="append", default=[], metavar="JOINT=DEG",
                      help="build the arm with this joint off by DEG (yaw or tilt; repeatable)")
    fake.add_argument("--fake-joint-reversed", action="append", default=[], metavar="JOINT",
                      help="build the arm with this joint's servo turning the other way")
    fake.add_argument("--fake-tracker-mount", metavar="NAME",
                      help="mount the tracker wrongly: upside_down, turned_90, turned_180, turned_270, ...")
    fake.add_argument("--fake-tracker-bias", type=bounded(float, -180, 180, "degrees"), metavar="DEG",
                      help="tracker bias (default 0.5)")


def _options(args: argparse.Namespace) -> tuple[dict[str, Any], Path]:
    options = _hal_options(args) or {}
    state_dir = Path("state")
    if args.config:
        state_dir = load(args.config).state_dir  # _hal_options already refused a bad file
    if args.state_dir:
        state_dir = Path(args.state_dir)
    offsets = {}
    for item in getattr(args, "fake_joint_offset", []):
        joint, _, deg = item.partition("=")
        try:
            offsets[joint.strip()] = float(deg)
        except ValueError:
            raise CliError(f"--fake-joint-offset wants JOINT=DEG such as tilt=3, got {item!r}") from None
        if not -180.0 <= offsets[joint.strip()] <= 180.0:  # nan too
            raise CliError(f"--fake-joint-offset {item}: DEG must be a number of degrees in -180..180")
    given = vars(args)  # the faults and the remap are options of arm and tracker only
    faults = {"fake_joint_offsets": offsets or None, "fake_joint_reversed": given.get("fake_joint_reversed") or None,
              "fake_tracker_mount": given.get("fake_tracker_mount"),
              "fake_tracker_bias_deg": given.get("fake_tracker_bias")}
    options.update({k: v for k, v in faults.items() if v is not None})
    if given.get("tracker_remap"):
        options["tracker_remap"] = given["tracker_remap"]
    return options, state_dir


def run(args: argparse.Namespace) -> int:
    options, state_dir = _options(args)
    if args.what in ("arm", "exposure"):  # they store what they find: the folder is checked before the arm moves
        _writable(state_dir)
    try:
        hal = build_hal(options, state_dir=state_dir)
    except HalConfigError as exc:
        raise CliError(str(exc)) from None
    real = hal.body.value == "real"
    try:
        if real:
            _say(args, "calibrate: the arm moves through several poses: clear its travel and keep hands away")
            if not hal.tracker.calibration().ok:
                _say(args, "calibrate: the tracker reports itself uncalibrated: turn the rig slowly through a "
                           "figure eight until its calibration status is at least 1, then run this again")
        if args.what == "exposure":
            result = _exposure(args, hal, state_dir)
        else:
            result = _arm(args, hal, state_dir) if args.what == "arm" else _tracker(args, hal)
    except NotGranted as exc:  # the configuration asks what the camera never gives: change it, not retry
        raise CliError(f"calibrate {args.what}: {exc}") from None
    except Exception as exc:  # noqa: BLE001 - a device that fails mid-way is one clear line
        print(f"btf-robot calibrate {args.what}: failed: {type(exc).__name__}: {exc}", file=sys.stderr)
        return 1
    finally:
        hal.close()
    return result


def _writable(state_dir: Path) -> None:
    try:
        state_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CliError(f"state dir {state_dir}: cannot create it ({exc.strerror or exc}); give --state-dir a "
                       "folder this user can write") from None
    if not os.access(state_dir, os.W_OK | os.X_OK):
        raise CliError(f"state dir {state_dir}: cannot write in it; give --state-dir a folder this user can write")


def _say(args: argparse.Namespace, text: str) -> None:
    print(text, file=sys.stderr if args.json else sys.stdout)


def _arm(args: argparse.Namespace, hal: Hal, state_dir: Path) -> int:
    report = calibrate_arm(hal)
    stored = str(save_arm_fit(state_dir, report.fit)) if report.ok else None
    if args.json:
        print(json.dumps({"what": "arm", "body": hal.body.value, "ok": report.ok, "stored": stored,
                          "yaw": dataclasses.asdict(report.fit.yaw), "tilt": dataclasses.asdict(report.fit.tilt),
                          "check_error_deg": report.check_error_deg}))
        return 0 if report.ok else 1
    print(f"calibrate arm ({hal.body.value} HAL): servo = sign * joint + offset, fitted to the tracker")
    for name in ("yaw", "tilt"):
        j = getattr(report.fit, name)
        print(f"  {name:4s}: offset {j.offset_deg:+.2f} deg, sign {j.sign:+.0f}, residual {j.residual_deg:.2f} deg "
              f"over {j.poses} poses")
    v = report.check_view
    print(f"  check: asked elevation {v.elevation:g} azimuth {v.azimuth:g}, the tracker agrees within "
          f"{report.check_error_deg:.2f} deg")
    if not report.ok:
        print(f"NOT stored: a residual above {GOOD_FIT_DEG:g} deg is no rigid offset. On real hardware: tighten the "
              "servo horns and the tracker's mount, check 'btf-robot calibrate tracker', then run this again.")
        return 1
    print(f"stored in {stored}; 'btf-robot run' applies it at start (remove the file to go back to the arm "
          "uncalibrated)")
    for name in ("yaw", "tilt"):
        if getattr(report.fit, name).sign < 0:
            print(f"  note: the {name} servo turns against its joint; the calibration handles it, "
                  "but on real hardware check that the servo horn is mounted as intended")
    return 0


def _tracker(args: argparse.Namespace, hal: Hal) -> int:
    r = calibrate_tracker(hal)
    if args.json:
        print(json.dumps({"what": "tracker", "body": hal.body.value, "ok": r.ok,
                          "nadir": dataclasses.asdict(r.nadir), "current": str(r.current), "needed": str(r.needed),
                          "needed_placement": r.needed.placement, "needed_registers": [r.needed.config, r.needed.sign],
                          "off_square_deg": r.off_square_deg}))
        return 0 if r.ok else 1
    n = r.nadir
    print(f"calibrate tracker ({hal.body.value} HAL): looking straight down it reads heading {n.heading:.1f} "
          f"roll {n.roll:.1f} pitch {n.pitch:.1f} deg (must be pitch -90, roll 0, within {NADIR_TOLERANCE_DEG:g})")
    print(f"  axis remap now {r.current}; the mounting needs {r.needed}")
    if r.off_square_deg > SQUARE_TOLERANCE_DEG:
        print(f"the tracker sits {r.off_square_deg:.0f} deg off any square mounting: no remap fixes that. "
              "Mount it flat and square on the camera body, then run this again.")
        return 1
    if r.ok:
        print("  the remap is right: nothing to do")
        return 0
    setting = r.needed.placement or f"0x{r.needed.config:02X}/0x{r.needed.sign:02X}"
    print(f'set tracker_remap = "{setting}" in [hal] of the robot config (the driver writes it at every start; '
          "the BNO055 forgets it at power-off), or remount the tracker upright; then run "
          "'btf-robot calibrate tracker' again (try it now with --tracker-remap " + setting + ")")
    return 1


def _exposure(args: argparse.Namespace, hal: Hal, state_dir: Path) -> int:
    cfg = load(args.config) if args.config else Config()
    s: SweepConfig = cfg.sweep
    views = plan_extremes(SweepPlan(s.start, s.stop, s.step, s.azimuths))
    hal.open_camera()
    lock = CameraLock(hal.camera, cfg.camera)
    granted = lock.apply(cfg.camera)
    if args.start_exposure is not None:
        granted = lock.set_exposure(args.start_exposure)
    if not granted.locked:
        print(f"calibrate exposure: the camera does not hold a manual exposure ({describe(granted)}); lock it "
              "first ('btf-robot selftest' names what it refuses)", file=sys.stderr)
        return 1
    hal.arm.enable()

    def shoot(exposure_us: float) -> tuple[Any, float]:
        lock.set_exposure(exposure_us)
        frame = hal.camera.capture()
        return frame, hal.camera.settings().exposure_us or exposure_us

    report = calibrate_exposure(views, lambda v: hal.arm.move_to(v), shoot, granted.exposure_us or 10_000.0,
                                cfg.camera.calibrate_margin)
    stored = None
    if report.ok:
        final = lock.set_exposure(report.exposure_us)
        stored = str(save_exposure(state_dir, report, final.exposure_us or report.exposure_us))
    return _exposure_said(args, hal, report, stored)


def _exposure_said(args: argparse.Namespace, hal: Hal, report: Any, stored: str | None) -> int:
    if args.json:
        print(json.dumps({"what": "exposure", "body": hal.body.value, "ok": report.ok, "stored": stored,
                          "exposure_us": report.exposure_us, "margin": report.margin, "problem": report.problem,
                          "brightest": None if report.brightest is None else dataclasses.asdict(report.brightest),
                          "readings": [dataclasses.asdict(r) for r in report.readings]}))
        return 0 if report.ok else 1
    print(f"calibrate exposure ({hal.body.value} HAL): the plan's extremes, halving the exposure while more than "
          "0.1% of a frame clips")
    for r in report.readings:
        print(f"  elevation {r.elevation:5.1f} azimuth {r.azimuth:5.1f}: {r.exposure_us:9.0f} us, "
              f"{100 * r.saturated:5.1f}% saturated, top {r.top:.0f}")
    if not report.ok:
        print(f"NOT stored: {report.problem}. On real hardware: close the aperture, add a neutral density filter "
              "or lower [camera] gain, then run this again.")
        return 1
    b = report.brightest
    print(f"  chosen: {report.exposure_us:.0f} us, the brightest view (elevation {b.elevation:g}, azimuth "
          f"{b.azimuth:g}) topping at {100 * (1 - report.margin):.0f}% of full scale")
    print(f"stored in {stored}; 'btf-robot run' applies it over [camera] exposure (remove the file to go back to "
          "the config's)")
    return 0
