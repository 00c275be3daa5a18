"""Camera controls: parsing, the V4L2 and picamera2 paths with read-back, the lock check,
and selftest failing for a camera that keeps its automatics on."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from hal.camera import PiCamera2Camera
from hal.controls import describe, parse_controls
from hal.emulators.camera import SequenceCamera, V4L2Controls, write_sequence
from hal.factory import build_hal
from hal.interfaces import Camera, CameraControls, CameraSettings, HalError
from onboard.cli import main

LOCK = CameraControls(exposure_us=8000.0, gain=12.0, white_balance_kelvin=5000.0)


@pytest.mark.parametrize(("args", "expected"), [
    (("auto", "auto", "auto"), CameraControls()),
    (("8000", "2.5", "5500K"), CameraControls(8000.0, 2.5, 5500.0)),
    ((8000, 1, "4000"), CameraControls(8000.0, 1.0, 4000.0)),
    (("AUTO", "0", "1.8, 1.4"), CameraControls(None, 0.0, None, (1.8, 1.4))),
])
def test_controls_parse_from_text(args, expected):
    assert parse_controls(*args) == expected
    assert parse_controls(*args).locked == (expected.exposure_us is not None and expected.gain is not None
                                             and expected.manual_white_balance)


@pytest.mark.parametrize(("args", "message"), [
    (("fast", "auto", "auto"), "exposure must be a number or 'auto'"),
    (("-5", "auto", "auto"), "exposure_us must be a positive number"),
    (("nan", "auto", "auto"), "exposure_us must be a positive number"),
    (("auto", "-1", "auto"), "gain must be a positive number"),
    (("auto", "auto", "1.8,x"), "gains must be 'RED,BLUE'"),
    (("auto", "auto", "0,1"), "two positive numbers"),
    (("auto", "auto", "warm"), "white balance must be a number"),
])
def test_bad_controls_are_named(args, message):
    with pytest.raises(ValueError, match=message):
        parse_controls(*args)


def test_a_colour_temperature_and_gains_together_are_refused():
    with pytest.raises(ValueError, match="not both"):
        CameraControls(white_balance_kelvin=5000.0, white_balance_gains=(1.0, 1.0))


@pytest.fixture
def sequence(tmp_path):
    write_sequence(tmp_path, [np.full((24, 32, 3), 90, np.uint8)])
    return tmp_path


def test_v4l2_lock_is_granted_and_read_back_in_the_drivers_units(sequence):
    cam = SequenceCamera(sequence)
    assert isinstance(cam, Camera)
    cam.open(32, 24)
    before = cam.settings()
    assert before.auto_exposure and before.auto_white_balance and not before.locked
    got = cam.set_controls(LOCK)
    assert got.locked and got.problems == ()
    assert (got.exposure_us, got.gain, got.white_balance_kelvin) == (8000.0, 12.0, 5000.0)
    assert cam.controls.exposure == 80  # exposure_time_absolute counts 100 µs
    # the automatic is switched off before its manual value is written (drivers refuse it otherwise)
    props = [p for p, _, _ in cam.controls.writes]
    assert props.index(cv2.CAP_PROP_AUTO_EXPOSURE) < props.index(cv2.CAP_PROP_EXPOSURE)
    assert props.index(cv2.CAP_PROP_AUTO_WB) < props.index(cv2.CAP_PROP_WB_TEMPERATURE)
    assert all(ok for _, _, ok in cam.controls.writes)
    for _ in range(3):  # the sequence restarts (a reopen of the capture): the controls stay
        cam.capture()
    assert cam.settings().locked
    assert "exposure 8000 us, gain 12, white balance 5000 K; locked" in describe(cam.settings())


def test_v4l2_value_outside_the_drivers_range_is_named_not_silently_accepted(sequence):
    cam = SequenceCamera(sequence)
    cam.open(32, 24)
    got = cam.set_controls(CameraControls(300_000.0, 12.0, 5000.0))
    assert not got.locked and not got.lock_held
    assert got.problems == ("exposure asked 300000 us, granted 204700 us",)


def test_v4l2_camera_without_red_blue_balance_says_so(sequence):
    cam = SequenceCamera(sequence)
    cam.open(32, 24)
    got = cam.set_controls(CameraControls(8000.0, 12.0, white_balance_gains=(1.6, 1.3)))
    assert not got.locked
    assert "the driver refused red balance 1.6" in got.problems


def test_v4l2_camera_that_keeps_auto_exposure_is_detected(sequence):
    cam = SequenceCamera(sequence, controls=V4L2Controls(honours_lock=False))
    cam.open(32, 24)
    got = cam.set_controls(LOCK)
    assert got.auto_exposure and not got.lock_held
    assert "exposure asked manual 8000 us, the device still runs auto exposure" in got.problems
    assert "the driver refused exposure 8000 us" in got.problems


def test_v4l2_back_to_auto(sequence):
    cam = SequenceCamera(sequence)
    cam.open(32, 24)
    cam.set_controls(LOCK)
    got = cam.set_controls(CameraControls())
    assert got.auto_exposure and got.auto_white_balance and got.lock_held and not got.locked
    assert cam.controls.auto_exposure == 3


def test_controls_before_open_are_an_error(sequence):
    with pytest.raises(HalError, match="after open"):
        SequenceCamera(sequence).set_controls(LOCK)


class StandInPicamera2:
    """picamera2's control surface: `set_controls` reaches the sensor `delay` frames later, and
    `capture_metadata` reports each frame's values. `stubborn` cameras keep their AGC."""

    def __init__(self, delay=2, temperature=41.5, kelvin_control=True, stubborn=False):
        self.delay, self.stubborn = delay, stubborn
        self.camera_controls = {"ExposureTime": (1, 1_000_000, 1000)}
        if kelvin_control:
            self.camera_controls["ColourTemperature"] = (100, 100_000, 0)
        self.current = {"ExposureTime": 16_421, "AnalogueGain": 2.37, "ColourGains": (1.9, 1.5),
                        "ColourTemperature": 4800, "SensorTemperature": temperature}
        self.pending: list = []
        self.sent: list[dict] = []
        self.config = None

    def create_still_configuration(self, main):
        return {"main": dict(main)}

    def configure(self, config):
        self.config = config

    def camera_configuration(self):
        return self.config

    def start(self):
        pass

    def stop(self):
        pass

    def close(self):
        pass

    def set_controls(self, controls):
        self.sent.append(dict(controls))
        self.pending.append([self.delay, controls])

    def capture_metadata(self):
        for entry in self.pending:
            entry[0] -= 1
            if entry[0] <= 0 and not self.stubborn:
                c = entry[1]
                for key in ("ExposureTime", "AnalogueGain", "ColourGains", "ColourTemperature"):
                    if c.get(key):
                        self.current[key] = c[key]
        self.pending = [e for e in self.pending if e[0] > 0]
        if self.current["SensorTemperature"] is None:
            return {k: v for k, v in self.current.items() if k != "SensorTemperature"}
        return dict(self.current)


def test_picamera2_lock_waits_for_the_sensor_and_reports_its_temperature():
    stand_in = StandInPicamera2(delay=3)
    cam = PiCamera2Camera(factory=lambda: stand_in)
    cam.open(16, 12)
    got = cam.set_controls(CameraControls(8000.0, 2.0, 5000.0))
    assert stand_in.sent == [{"AeEnable": False, "ExposureTime": 8000, "AnalogueGain": 2.0, "AwbEnable": False,
                              "ColourTemperature": 5000}]
    assert got.locked and (got.exposure_us, got.gain, got.white_balance_kelvin) == (8000.0, 2.0, 5000.0)
    assert got.sensor_temperature_c == 41.5


def test_picamera2_one_automatic_left_on_keeps_the_agc_for_it():
    stand_in = StandInPicamera2(temperature=None)
    cam = PiCamera2Camera(factory=lambda: stand_in)
    cam.open(16, 12)
    got = cam.set_controls(CameraControls(exposure_us=8000.0, white_balance_gains=(1.7, 1.4)))
    assert stand_in.sent[-1] == {"AeEnable": True, "ExposureTime": 8000, "AnalogueGain": 0.0, "AwbEnable": False,
                                 "ColourGains": (1.7, 1.4)}
    assert got.lock_held and got.auto_gain and not got.locked
    assert got.sensor_temperature_c is None


def test_picamera2_without_a_colour_temperature_control_names_the_way_out():
    cam = PiCamera2Camera(factory=lambda: StandInPicamera2(kelvin_control=False))
    cam.open(16, 12)
    got = cam.set_controls(CameraControls(8000.0, 2.0, 5000.0))
    assert not got.locked and "give white balance as red,blue gains" in got.problems[0]


def test_picamera2_that_does_not_take_the_controls_is_detected():
    cam = PiCamera2Camera(factory=lambda: StandInPicamera2(stubborn=True))
    cam.open(16, 12)
    got = cam.set_controls(CameraControls(8000.0, 2.0, 5000.0))
    assert not got.lock_held
    assert got.problems[0] == "exposure asked 8000 us, granted 16421 us"


@pytest.mark.parametrize("body", ["fake", "emulated"])
def test_selftest_fails_loudly_for_a_camera_that_keeps_its_automatics(body, capsys, monkeypatch):
    import onboard.cli.selftest

    build = onboard.cli.selftest.build_hal
    monkeypatch.setattr(onboard.cli.selftest, "build_hal",
                        lambda options, **kw: build({**options, "camera_honours_lock": False}, **kw))
    monkeypatch.delenv("BTF_HAL", raising=False)
    code = main(["selftest", "--hal", body])
    out, err = capsys.readouterr()
    assert code == 1
    camera = [line for line in out.splitlines() if '"camera"' in line][0]
    assert '"ok": false' in camera and "does not honour a manual exposure/gain/white balance lock" in camera
    assert "still runs auto exposure" in camera
    assert "btf-robot selftest: FAILED camera:" in err
    assert err.count("FAILED") == 1  # the other devices pass


def test_fake_hal_camera_reports_settings_record():
    hal = build_hal({"body": "fake", "size": (24, 32)}, env={})
    try:
        hal.camera.open(32, 24)
        s = hal.camera.settings()
        assert isinstance(s, CameraSettings) and s.locked
        assert (s.exposure_us, s.gain, s.white_balance_kelvin) == (10_000.0, 1.0, 5500.0)
        first = s.sensor_temperature_c
        for _ in range(20):
            hal.camera.capture()
        assert hal.camera.settings().sensor_temperature_c > first  # the sensor warms while it streams
    finally:
        hal.close()
