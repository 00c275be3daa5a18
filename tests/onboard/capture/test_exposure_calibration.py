"""`btf-robot calibrate exposure`: the plan's extremes measured, one exposure kept for the sweep."""
import json

import numpy as np
import pytest

from hal.interfaces import ViewAngles
from hal.scene import render
from onboard import config
from onboard.capture.exposure import EXPOSURE_FILE, calibrate_exposure, load_exposure, plan_extremes
from onboard.cli import main as robot
from onboard.cli.run import _calibrated_exposure
from onboard.sweep.plan import SweepPlan
from tests.support.robots import robot_toml

FIELD = ({"hal": {"scene": "field", "size": [120, 160]}, "segment": None, "skip": None,
          "sweep": {"start": 90, "stop": 30, "step": 10, "azimuths": [0, 90, 180, 270]}},)


def saturated(image: np.ndarray) -> float:
    return float(np.mean((image == 255).any(axis=2)))


def test_the_plan_extremes_are_its_first_and_last_elevation_at_each_azimuth():
    views = plan_extremes(SweepPlan(90, 30, 10, (0.0, 180.0)))
    assert views == [ViewAngles(90, 0), ViewAngles(30, 0), ViewAngles(90, 180), ViewAngles(30, 180)]
    assert plan_extremes(SweepPlan(60, 60, 10)) == [ViewAngles(60, 0)]


def test_from_a_start_that_saturates_30_percent_every_view_of_the_field_ends_under_1_percent(tmp_path, capsys):
    (tmp_path / "robot.toml").write_text(robot_toml(*FIELD, state_dir="state"))
    start = 60_000.0
    first = render("field", ViewAngles(90.0), size=(120, 160), exposure=start / 10_000).image
    assert 0.28 <= saturated(first) <= 0.34  # the start: 30% of the straight-down view clips
    code = robot(["calibrate", "exposure", "--config", str(tmp_path / "robot.toml"),
                  "--start-exposure", str(start), "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert code == 0 and doc["ok"] and doc["stored"]
    assert {(r["elevation"], r["azimuth"]) for r in doc["readings"]} == {(e, a) for e in (90.0, 30.0)
                                                                         for a in (0.0, 90.0, 180.0, 270.0)}
    assert doc["readings"][0]["saturated"] == pytest.approx(saturated(first), abs=0.02)
    exposure = load_exposure(tmp_path / "state")
    assert exposure == pytest.approx(doc["exposure_us"], rel=1e-6) and exposure < start / 2
    plan = SweepPlan(90, 30, 10, (0.0, 90.0, 180.0, 270.0))
    worst = max(saturated(render("field", v, size=(120, 160), exposure=exposure / 10_000).image)
                for v in plan.poses())
    assert worst < 0.01
    # not so short that the brightest view wastes the sensor: its top sits near 1 - margin
    brightest = ViewAngles(doc["brightest"]["elevation"], doc["brightest"]["azimuth"])
    top = np.quantile(render("field", brightest, size=(120, 160), exposure=exposure / 10_000).image.max(axis=2), 0.999)
    assert top == pytest.approx(0.85 * 255, abs=8)


def test_run_applies_the_stored_exposure_over_the_config(tmp_path, capsys):
    (tmp_path / "robot.toml").write_text(robot_toml(*FIELD, {"camera": {"exposure": 10000}}, state_dir="state"))
    cfg = config.load(tmp_path / "robot.toml")
    assert _calibrated_exposure(cfg) is cfg  # nothing stored yet
    (tmp_path / "state").mkdir()
    (tmp_path / "state" / EXPOSURE_FILE).write_text(json.dumps({"version": 1, "exposure_us": 18500.0}))
    assert _calibrated_exposure(cfg).camera.exposure == "18500.0"
    assert "18500 us" in capsys.readouterr().err
    (tmp_path / "state" / EXPOSURE_FILE).write_text("{broken")
    with pytest.raises(Exception, match="not a stored exposure"):
        _calibrated_exposure(cfg)


def test_a_scene_too_bright_for_the_shortest_exposure_is_not_stored():
    views = [ViewAngles(90.0)]
    white = np.full((8, 8, 3), 255, np.uint8)
    report = calibrate_exposure(views, lambda v: None, lambda e: (white, e), 1000.0, 0.15, shortest_us=100.0)
    assert not report.ok and "too bright" in report.problem and report.exposure_us == 0.0
    dark = np.zeros((8, 8, 3), np.uint8)
    report = calibrate_exposure(views, lambda v: None, lambda e: (dark, e), 1000.0, 0.15)
    assert not report.ok and "black" in report.problem


def test_bad_usage_is_status_2(tmp_path, capsys):
    assert robot(["calibrate", "exposure", "--hal", "fake", "--start-exposure", "-5"]) == 2
    assert "--start-exposure" in capsys.readouterr().err


def test_a_camera_that_cannot_give_the_configured_format_is_exit_2_and_what_to_change(tmp_path, capsys, monkeypatch):
    """Not 'failed' with exit 1, which reads as a device to wait for."""
    import onboard.cli.calibrate as calibrate_module  # its build_hal is replaced by a rig that refuses
    from hal.factory import build_hal
    from hal.interfaces import NotGranted

    class RefusingCamera:  # the fake body, but its camera's driver grants another format
        def __init__(self, *args, **kwargs) -> None:
            self._hal = build_hal(*args, **kwargs)

        def __getattr__(self, name):
            return getattr(self._hal, name)

        def open_camera(self) -> None:
            raise NotGranted("camera 0: asked for 160x120 'Y16 ', driver granted 160x120 'YUYV'; "
                             "set hal.size and hal.pixel_format to a mode it offers")
    monkeypatch.setattr(calibrate_module, "build_hal", RefusingCamera)
    (tmp_path / "robot.toml").write_text(robot_toml(*FIELD, state_dir="state"))
    code = robot(["calibrate", "exposure", "--config", str(tmp_path / "robot.toml")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "hal.pixel_format" in err
    assert load_exposure(tmp_path / "state") is None
