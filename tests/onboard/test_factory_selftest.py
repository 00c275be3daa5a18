"""The HAL factory picks one body for every device, never a silent fake; selftest reports per device."""
from __future__ import annotations

import json
import sys
import threading

import numpy as np
import pytest

from hal.arm import ArmCalibration
from hal.camera import OpenCVCamera
from hal.factory import Body, HalConfigError, arm_calibration, build_hal
from hal.interfaces import ViewAngles, view_from_orientation
from onboard.cli import main
from tests.support.robots import robot_toml
from tests.support.v4l2 import QueueingCapture


def run_cli(argv, capsys, monkeypatch, env_body=None):
    if env_body is None:
        monkeypatch.delenv("BTF_HAL", raising=False)
    else:
        monkeypatch.setenv("BTF_HAL", env_body)
    code = main(argv)
    out, err = capsys.readouterr()
    return code, [json.loads(line) for line in out.splitlines()], err


def test_no_config_and_no_env_is_refused():
    with pytest.raises(HalConfigError, match="BTF_HAL"):
        build_hal(None, env={})


@pytest.mark.parametrize("options, match", [
    ({"body": "simulated"}, "unknown HAL body"),
    ({"body": "real"}, "servo_port"),
    ({"body": "fake", "size": (4, 4)}, "at least 8"),
    ({"body": "fake", "scene": "moon"}, "moon"),
    ({"body": "fake", "arm": {"yaw": {"servo_id": 1}}}, "arm calibration"),
    ({"body": "fake", "pixel_format": "Y16 "}, r"fake camera gives BGR3, RGB3, MSP6"),
    ({"body": "fake", "pixel_format": "MSP"}, "four-character code"),
    ({"body": "emulated", "pixel_format": "MSP6"}, "emulated camera replays 8-bit RGB renders"),
])
def test_bad_options_are_one_clear_error(options, match):
    with pytest.raises(HalConfigError, match=match):
        build_hal(options, env={})


def test_env_chooses_the_body_when_the_config_does_not():
    hal = build_hal({"size": (16, 16)}, env={"BTF_HAL": "fake"})
    try:
        assert hal.body is Body.FAKE
    finally:
        hal.close()


def test_the_configured_pixel_format_chooses_the_fake_cameras_bands_and_opens_the_camera():
    multispectral = build_hal({"body": "fake", "size": (24, 32), "pixel_format": "MSP6"}, env={})
    rgb = build_hal({"body": "fake", "size": (24, 32)}, env={})
    try:
        for hal, channels, dtype in ((multispectral, 6, np.uint16), (rgb, 3, np.uint8)):
            hal.open_camera()
            frame = hal.camera.capture()
            assert frame.shape == (24, 32, channels) and frame.dtype == dtype
    finally:
        multispectral.close()
        rgb.close()


def test_arm_calibration_comes_from_the_config():
    cal = arm_calibration({"arm": {"yaw": {"servo_id": 3, "min_deg": -90, "max_deg": 90},
                                   "tilt": {"servo_id": 4, "min_deg": 0, "max_deg": 70, "sign": -1.0,
                                            "corrections": [[0, 0.5], [70, -0.5]]},
                                   "tolerance_deg": 0.5}})
    assert cal.servo_ids == [3, 4] and cal.tilt.corrections == ((0.0, 0.5), (70.0, -0.5))
    assert arm_calibration({}) == ArmCalibration()


def test_fake_devices_share_one_world():
    hal = build_hal({"body": "fake", "size": (48, 64), "seed": 3}, env={})
    try:
        hal.arm.enable()
        hal.camera.open(64, 48)
        frames = {}
        for elevation in (90.0, 30.0):
            hal.arm.move_to(ViewAngles(elevation, 0.0), timeout_s=5.0)
            seen = view_from_orientation(hal.tracker.orientation())
            assert seen.elevation == pytest.approx(elevation, abs=3.0)
            frames[elevation] = hal.camera.capture()
        assert frames[90.0].shape == (48, 64, 3)
        assert not np.array_equal(frames[90.0], frames[30.0])
    finally:
        hal.close()


def test_emulated_hal_runs_the_real_drivers_and_closes_cleanly():
    before = threading.active_count()
    hal = build_hal({"body": "emulated", "size": (32, 32)}, env={})
    try:
        assert type(hal.servo_bus).__name__ == "DynamixelServoBus"
        hal.arm.enable()
        hal.arm.move_to(ViewAngles(70.0, 20.0), timeout_s=5.0)
        seen = view_from_orientation(hal.tracker.orientation())
        assert seen.elevation == pytest.approx(70.0, abs=3.0)
    finally:
        hal.close()
    assert threading.active_count() <= before


@pytest.mark.parametrize("body", ["fake", "emulated"])
def test_selftest_passes_on_every_device(body, capsys, monkeypatch):
    code, lines, _ = run_cli(["selftest", "--hal", body], capsys, monkeypatch)
    assert code == 0
    assert [line["device"] for line in lines] == ["servo_bus", "arm", "tracker", "camera"]
    assert all(line["ok"] for line in lines)


def test_selftest_takes_the_body_from_the_environment(capsys, monkeypatch):
    code, lines, _ = run_cli(["selftest"], capsys, monkeypatch, env_body="fake")
    assert code == 0 and len(lines) == 4


def test_selftest_without_a_body_is_a_usage_error(capsys, monkeypatch):
    code, lines, err = run_cli(["selftest"], capsys, monkeypatch)
    assert code == 2 and lines == []
    assert err.count("\n") == 1 and "BTF_HAL" in err


def test_selftest_reports_failing_devices_and_exits_1(tmp_path, capsys, monkeypatch):
    cfg = tmp_path / "robot.toml"
    cfg.write_text(robot_toml({"hal": {"size": [16, 16], "scene": None, "fault_rate": 1.0}}))
    code, lines, _ = run_cli(["selftest", "--config", str(cfg)], capsys, monkeypatch)
    assert code == 1
    assert len(lines) == 4 and not any(line["ok"] for line in lines)
    assert all("Timeout" in line["detail"] or "Error" in line["detail"] for line in lines)


def test_selftest_bad_config_file_is_a_usage_error(tmp_path, capsys, monkeypatch):
    cfg = tmp_path / "robot.toml"
    cfg.write_text("[hal]\nbody = 3\n")
    code, lines, err = run_cli(["selftest", "--config", str(cfg)], capsys, monkeypatch)
    assert code == 2 and lines == [] and "robot.toml" in err


class StandInPicamera2Module:
    """Stands for the picamera2 package: the adapter only needs its Picamera2 class."""

    class Picamera2:
        pass


def test_real_camera_is_picamera2_when_importable_and_opencv_otherwise(monkeypatch):
    from hal.camera import OpenCVCamera, PiCamera2Camera
    from hal.factory import _real_camera

    monkeypatch.setitem(sys.modules, "picamera2", StandInPicamera2Module)
    assert isinstance(_real_camera(""), PiCamera2Camera)
    assert isinstance(_real_camera("picamera2"), PiCamera2Camera)
    with pytest.raises(HalConfigError, match="'Y16 ': picamera2 gives BGR3, RGB3"):
        _real_camera("", "Y16 ")  # refused at start, not retried as a camera not there yet
    assert isinstance(_real_camera("/dev/video0", "Y16 "), OpenCVCamera)
    named = _real_camera("/dev/video2")
    assert isinstance(named, OpenCVCamera) and named.device == "/dev/video2"
    monkeypatch.setitem(sys.modules, "picamera2", None)  # not installed: import fails
    default = _real_camera("")
    assert isinstance(default, OpenCVCamera) and default.device == 0
    assert _real_camera("1").device == 1


def test_selftest_servo_nudge_stays_inside_the_joint_limits():
    from onboard.cli.selftest import _servo_bus

    # A tilt servo mounted reversed and parked at its lower limit: a blind +5 degree nudge
    # of the servo would drive the joint to -5 degrees, into the stop.
    arm = {"yaw": {"servo_id": 1, "min_deg": -180.0, "max_deg": 179.9},
           "tilt": {"servo_id": 2, "min_deg": 0.0, "max_deg": 80.0, "sign": -1.0}}
    hal = build_hal({"body": "fake", "size": (16, 16), "arm": arm}, env={})
    try:
        _servo_bus(hal)
        moves = [c.args[0] for c in hal.servo_bus.history if c.call == "move"]
        assert moves
        for goals in moves:
            for joint in (hal.arm.joints.yaw, hal.arm.joints.tilt):
                assert joint.min_deg <= joint.joint_deg(goals[joint.servo_id]) <= joint.max_deg
    finally:
        hal.close()


def test_selftest_tracker_check_compares_with_where_the_servos_are():
    from onboard.cli.selftest import _tracker

    hal = build_hal({"body": "fake", "size": (16, 16)}, env={})
    try:
        hal.arm.enable()
        hal.arm.move_to(ViewAngles(40.0, 0.0), timeout_s=5.0)  # not the selftest's last pose
        assert "calibration" in _tracker(hal)
    finally:
        hal.close()


def test_emulated_fault_rate_reaches_the_tracker_bus_too():
    hal = build_hal({"body": "emulated", "size": (16, 16), "fault_rate": 0.2, "fault_seed": 5}, env={})
    try:
        for _ in range(20):
            o = hal.tracker.orientation()
            assert view_from_orientation(o).elevation == pytest.approx(90.0, abs=0.1)  # parked straight down
        assert hal.tracker.retried > 0  # NACKs were injected and absorbed by the driver's retries
    finally:
        hal.close()


class _RigWithAThermalCameraThatOffersYUYV:
    """A real body whose V4L2 driver (at the seam: the capture it hands OpenCV) grants YUYV
    whatever format is asked."""

    body = Body.REAL

    def __init__(self, *args, **kwargs) -> None:
        self.closed = False

    def open_camera(self) -> None:
        OpenCVCamera(0, capture_factory=lambda dev, api: QueueingCapture(0, 1, fourcc="YUYV")).open(160, 120, "Y16 ")

    def close(self) -> None:
        self.closed = True


def test_a_camera_that_cannot_give_the_configured_format_is_a_configuration_error_not_a_retry(
        tmp_path, capsys, monkeypatch):
    """Exit 1 would have a supervisor restart the robot for ever on a camera that will never
    give 'Y16 '; exit 2 and one line saying what to change."""
    import onboard.cli.run as run_module  # its build_hal is replaced by the rig above

    (tmp_path / "robot.key").write_text("00" * 32)
    (tmp_path / "robot.key").chmod(0o600)
    cfg = tmp_path / "robot.toml"
    cfg.write_text(robot_toml({"hal": {"body": "real", "servo_port": "/dev/ttyUSB0", "size": [120, 160],
                                       "pixel_format": "Y16 ", "scene": None},
                               "segment": {"method": "isodata"}, "link": {"key_file": "robot.key"}},
                              state_dir=str(tmp_path / "state")))
    monkeypatch.setattr(run_module, "build_hal", _RigWithAThermalCameraThatOffersYUYV)
    code, _, err = run_cli(["run", "--config", str(cfg)], capsys, monkeypatch)
    assert code == 2, err
    assert err.count("\n") == 1 and "Traceback" not in err
    assert "driver granted 160x120 'YUYV'" in err and "hal.pixel_format" in err
