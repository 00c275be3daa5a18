"""Geometry calibration: joint offsets and signs against the tracker, the BNO055 axis remap,
and `btf-robot calibrate` on the fake and emulated bodies."""
from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from hal.arm import ARM_FIT_FILE, ArmFit, JointFit, load_arm_fit, save_arm_fit
from hal.bno055 import PLACEMENTS, AxisRemap, BNO055Tracker, Reg
from hal.emulators.bno055 import EmulatedSMBus
from hal.factory import HalConfigError, build_hal, world_calibration, world_view
from hal.geometry import calibrate_arm, calibrate_tracker
from hal.interfaces import HalError, Orientation, ViewAngles, view_from_orientation
from hal.orientation import MOUNTS, camera_frame, euler_angles, euler_matrix
from onboard.cli import main
from tests.support.robots import robot_toml


def hal_with(body: str, **options):
    return build_hal({"body": body, "size": (16, 16), **options}, env={})


@given(st.floats(0, 359.9), st.floats(-89.0, 89.0), st.floats(-179.0, 179.0))
def test_euler_angles_invert_euler_matrix(heading, roll, pitch):
    back = euler_angles(euler_matrix(Orientation(heading, roll, pitch)))
    assert back.roll == pytest.approx(roll, abs=1e-6) and back.pitch == pytest.approx(pitch, abs=1e-6)
    assert (back.heading - heading + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=1e-6)


@given(st.floats(5.0, 90.0), st.floats(0.0, 359.9))
def test_upright_tracker_reads_the_view_the_runtime_expects(elevation, azimuth):
    seen = view_from_orientation(euler_angles(camera_frame(ViewAngles(elevation, azimuth))))
    assert seen.elevation == pytest.approx(elevation, abs=1e-6)
    assert (seen.azimuth - azimuth + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=1e-6)


def test_upside_down_tracker_reads_pitch_plus_90_looking_straight_down():
    o = euler_angles(camera_frame(ViewAngles(90.0)) @ MOUNTS["upside_down"])
    assert o.pitch == pytest.approx(90.0) and o.roll == pytest.approx(0.0, abs=1e-9)


def test_the_datasheet_placements_are_rotations_and_round_trip():
    for name, regs in PLACEMENTS.items():
        remap = AxisRemap.parse(name)
        assert (remap.config, remap.sign) == regs and remap.placement == name
        assert np.linalg.det(remap.matrix) == pytest.approx(1.0)
        assert AxisRemap.from_matrix(remap.matrix) == remap
    assert AxisRemap.parse(" 0x24 / 0x03 ") == AxisRemap.parse("p4")
    assert str(AxisRemap.parse("P4")) == "P4 (AXIS_MAP_CONFIG 0x24, AXIS_MAP_SIGN 0x03)"


@pytest.mark.parametrize(("text", "message"), [("P9", "placement P0..P7"), ("0x00/0x00", "is not a remap"),
                                               ("0x24/0x08", "bits 0..2"), ("sideways", "placement P0..P7")])
def test_bad_remaps_are_named(text, message):
    with pytest.raises(ValueError, match=message):
        AxisRemap.parse(text)


def test_driver_writes_the_remap_in_config_mode_and_the_emulated_chip_reports_through_it():
    nadir = lambda: Orientation(0.0, 0.0, -90.0)  # noqa: E731 - the camera looks straight down
    upside_down = EmulatedSMBus(orientation_source=nadir, mount=MOUNTS["upside_down"])
    assert BNO055Tracker(upside_down, sleep=lambda s: None).orientation().pitch == pytest.approx(90.0)
    bus = EmulatedSMBus(orientation_source=nadir, mount=MOUNTS["upside_down"])
    t = BNO055Tracker(bus, sleep=lambda s: None, remap=AxisRemap.parse("P4"))
    assert t.remap == AxisRemap.parse("P4")
    assert t.orientation().pitch == pytest.approx(-90.0)
    writes = [(a.register, a.value) for a in bus.history if a.op == "write"]
    mode_at = {r: i for i, (r, _) in enumerate(writes)}
    assert (Reg.AXIS_MAP_SIGN, 0x03) in writes and mode_at[Reg.AXIS_MAP_SIGN] < len(writes) - 1
    assert writes[-1] == (Reg.OPR_MODE, 0x0C)  # NDOF only after the remap: it is writable in CONFIG mode only


def test_a_tilt_past_straight_down_looks_from_the_other_side():
    world = world_calibration(build_hal({"body": "fake", "size": (16, 16)}, env={}).arm.joints,
                              {"fake_joint_offsets": {"tilt": 3.0}})
    view = world_view(world, {1: 10.0, 2: 0.0})  # servo 0 is joint -3 on this arm
    assert view.elevation == pytest.approx(87.0) and view.azimuth == pytest.approx(190.0)


@pytest.mark.parametrize("body", ["fake", "emulated"])
def test_arm_calibration_recovers_a_3_degree_joint_offset(body):
    hal = hal_with(body, fake_joint_offsets={"tilt": 3.0}, fake_tracker_bias_deg=0.0)
    try:
        report = calibrate_arm(hal)
    finally:
        hal.close()
    assert report.fit.tilt.offset_deg == pytest.approx(3.0, abs=0.2)  # the bar
    assert report.fit.yaw.offset_deg == pytest.approx(0.0, abs=0.2)
    assert report.fit.tilt.sign == report.fit.yaw.sign == 1.0
    assert report.ok and report.check_error_deg < 0.5


def test_arm_calibration_finds_a_reversed_yaw_servo_and_fits_the_tracker_bias_too():
    hal = hal_with("fake", fake_joint_offsets={"yaw": -7.0}, fake_joint_reversed=["yaw"])  # tracker bias 0.5
    try:
        report = calibrate_arm(hal)
    finally:
        hal.close()
    assert report.fit.yaw.sign == -1.0 and report.fit.yaw.offset_deg == pytest.approx(-7.0 + 0.5, abs=0.2)
    assert report.fit.tilt.offset_deg == pytest.approx(0.5, abs=0.2)  # the arm is made to match its tracker
    assert report.ok


def test_the_stored_fit_makes_commanded_views_match_the_tracker(tmp_path):
    options = {"body": "fake", "size": (16, 16), "fake_joint_offsets": {"tilt": 3.0}, "fake_tracker_bias_deg": 0.0}

    def miss(state_dir) -> float:
        hal = build_hal(options, env={}, state_dir=state_dir)
        try:
            hal.arm.enable()
            hal.arm.move_to(ViewAngles(50.0, 0.0), timeout_s=5.0)
            return abs(view_from_orientation(hal.tracker.orientation()).elevation - 50.0)
        finally:
            hal.close()

    assert miss(tmp_path) > 2.0  # nothing stored yet: the joint's 3 degrees show
    hal = build_hal(options, env={}, state_dir=tmp_path)
    try:
        fit = calibrate_arm(hal).fit
    finally:
        hal.close()
    save_arm_fit(tmp_path, fit)
    assert load_arm_fit(tmp_path) == fit
    assert miss(tmp_path) < 1.0


def test_a_damaged_stored_fit_is_one_clear_error(tmp_path):
    (tmp_path / ARM_FIT_FILE).write_text('{"version": 1, "yaw": {"offset_deg": "x"}}')
    with pytest.raises(HalError, match=f"{ARM_FIT_FILE}: .*calibrate arm"):
        load_arm_fit(tmp_path)
    with pytest.raises(HalConfigError, match=ARM_FIT_FILE):
        build_hal({"body": "fake"}, env={}, state_dir=tmp_path)
    assert load_arm_fit(tmp_path / "nowhere") is None
    with pytest.raises(ValueError, match="sign of"):
        ArmFit(JointFit(0.0, 2.0, 0.0, 4), JointFit(0.0, 1.0, 0.0, 4))


@pytest.mark.parametrize("body", ["fake", "emulated"])
def test_tracker_calibration_names_p4_for_a_tracker_mounted_upside_down(body):
    hal = hal_with(body, fake_tracker_mount="upside_down")
    try:
        report = calibrate_tracker(hal)
    finally:
        hal.close()
    assert report.nadir.pitch == pytest.approx(90.0, abs=2.0) and not report.nadir_ok
    assert report.needed == AxisRemap.parse("P4") and report.current == AxisRemap()  # the bar
    assert not report.ok


@pytest.mark.parametrize("mount", ["turned_90", "turned_180", "turned_270", "upside_down_turned_180", "P5"])
def test_tracker_calibration_names_the_remap_for_other_mountings(mount):
    expected = {"turned_90": "P0", "turned_180": "P2", "turned_270": "P3", "upside_down_turned_180": "P7", "P5": "P5"}
    hal = hal_with("fake", fake_tracker_mount=mount)
    try:
        report = calibrate_tracker(hal)
    finally:
        hal.close()
    assert report.needed.placement == expected[mount] and not report.ok


@pytest.mark.parametrize("body", ["fake", "emulated"])
def test_with_the_named_remap_set_the_tracker_reads_right(body):
    hal = hal_with(body, fake_tracker_mount="upside_down", tracker_remap="P4")
    try:
        report = calibrate_tracker(hal)
    finally:
        hal.close()
    assert report.ok and report.nadir.pitch == pytest.approx(-90.0, abs=2.0)


def run(argv, capsys, monkeypatch, tmp_path):
    monkeypatch.delenv("BTF_HAL", raising=False)
    monkeypatch.chdir(tmp_path)
    code = main(argv)
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_calibrate_arm_stores_the_fit_in_the_state_dir(tmp_path, capsys, monkeypatch):
    code, out, _ = run(["calibrate", "arm", "--hal", "emulated", "--fake-joint-offset", "tilt=3", "--json"],
                       capsys, monkeypatch, tmp_path)
    result = json.loads(out)
    assert code == 0 and result["ok"] and result["tilt"]["offset_deg"] == pytest.approx(3.0, abs=0.2)
    assert json.loads((tmp_path / "state" / ARM_FIT_FILE).read_text())["tilt"]["offset_deg"] == result["tilt"][
        "offset_deg"]


def test_cli_calibrate_tracker_tells_the_operator_what_to_set(tmp_path, capsys, monkeypatch):
    code, out, _ = run(["calibrate", "tracker", "--hal", "fake", "--fake-tracker-mount", "upside_down"],
                       capsys, monkeypatch, tmp_path)
    assert code == 1
    assert "pitch 89" in out and 'set tracker_remap = "P4" in [hal]' in out
    code, out, _ = run(["calibrate", "tracker", "--hal", "fake", "--fake-tracker-mount", "upside_down",
                        "--tracker-remap", "P4"], capsys, monkeypatch, tmp_path)
    assert code == 0 and "nothing to do" in out


def test_cli_tracker_remap_from_the_config(tmp_path, capsys, monkeypatch):
    cfg = tmp_path / "robot.toml"
    cfg.write_text(robot_toml({"hal": {"body": "emulated", "size": [16, 16], "scene": None, "tracker_remap": "P2"},
                               "segment": None, "skip": None}))
    code, out, _ = run(["calibrate", "tracker", "--config", str(cfg), "--json"], capsys, monkeypatch, tmp_path)
    result = json.loads(out)  # an upright tracker remapped as if turned: the check names P1 back
    assert code == 1 and result["current"].startswith("P2") and result["needed_placement"] == "P1"


@pytest.mark.parametrize(("argv", "message"), [
    (["calibrate", "arm", "--hal", "fake", "--fake-joint-offset", "tilt"], "JOINT=DEG"),
    (["calibrate", "arm", "--hal", "fake", "--fake-joint-offset", "wrist=3"], "unknown joint 'wrist'"),
    (["calibrate", "arm", "--hal", "real", "--fake-tracker-mount", "upside_down"], "only fake and emulated"),
    (["calibrate", "tracker", "--hal", "fake", "--tracker-remap", "P9"], "tracker_remap"),
    (["calibrate", "tracker", "--hal", "fake", "--fake-tracker-mount", "sideways"], "unknown fake_tracker_mount"),
    (["calibrate", "arm", "--hal", "fake", "--fake-joint-offset", "tilt=nan"], "in -180..180"),
    # checked before the arm moves: it stores what it finds there
    (["calibrate", "arm", "--hal", "fake", "--state-dir", "/proc/no/such"], "state dir /proc/no/such: cannot create"),
])
def test_cli_bad_usage_is_one_line_and_exit_2(argv, message, tmp_path, capsys, monkeypatch):
    code, out, err = run(argv, capsys, monkeypatch, tmp_path)
    assert code == 2 and out == "" and err.count("\n") == 1 and message in err
