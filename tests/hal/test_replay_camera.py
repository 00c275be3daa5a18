"""The replay camera: image files played as frames through the robot's own pipeline, looping or
stopping at the end, each capture knowing the file it came from."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile
from PIL import Image

from hal.factory import HalConfigError, build_hal
from hal.interfaces import CameraControls, HalError, ViewAngles
from hal.replay import ReplayCamera, ReplayEnded, read_frame, replay_files
from hal.scene import render
from onboard import config
from radio import packets as pk
from tests.support.replay import ELEVATIONS, H, W, models, rgb_frame, robot_text, run_sweep, write_rgb, write_shots


@pytest.fixture
def shots(tmp_path) -> Path:
    """shot_1.png, shot_2.jpg, shot_10.png: 8-bit RGB; a text file the camera leaves alone."""
    return write_shots(tmp_path / "shots")


def test_a_looping_sweep_plays_the_folder_in_natural_order_and_each_capture_knows_its_file(fake_robot, shots):
    packets, sources = run_sweep(fake_robot, robot_text(f"replay:{shots}", loop=True))
    order = ["shot_1.png", "shot_2.jpg", "shot_10.png"]
    assert [sources[e] for e in ELEVATIONS] == (order * 3)[:7]  # started over after the last file
    measured = models(packets)
    assert [round(p.commanded[0]) for p in measured] == ELEVATIONS
    assert all(p.bands == ("R", "G", "B") and p.levels == 256 for p in measured)
    assert all(len({lab.label for lab in p.labels}) == 2 for p in measured)  # both colours found


def test_without_loop_the_poses_after_the_last_file_are_skipped_with_the_reason(fake_robot, shots):
    packets, sources = run_sweep(fake_robot, robot_text(f"replay:{shots}", loop=False))
    assert [round(p.commanded[0]) for p in models(packets)] == [90, 80, 70]
    assert list(sources.values()) == ["shot_1.png", "shot_2.jpg", "shot_10.png"]
    skipped = [p for p in packets if isinstance(p, pk.StatusPacket) and p.report.sweep and p.report.sweep.skipped]
    assert [p.report.sweep.skipped.items[0].elevation for p in skipped] == [60, 50, 40, 30]
    assert all("ReplayEnded" in p.text and "all 3 files played" in p.text for p in skipped)


def test_sixteen_bit_one_band_files_stay_one_band_under_the_emulated_body(fake_robot, tmp_path):
    folder = tmp_path / "thermal"
    folder.mkdir()
    rng = np.random.default_rng(4)
    for i in range(3):
        band = np.where(np.arange(W) < W // 2, 20_000, 45_000) + rng.normal(0, 300, (H, W))
        assert cv2.imwrite(str(folder / f"t{i}.png"), band.astype(np.uint16))
    raw = {"features": {"space": "raw"}, "sweep": {"start": 90, "stop": 70}}
    packets, sources = run_sweep(fake_robot, robot_text(f"replay:{folder}/t*.png", False, "emulated", raw))
    measured = models(packets)
    assert [round(p.commanded[0]) for p in measured] == [90, 80, 70]
    assert list(sources.values()) == ["t0.png", "t1.png", "t2.png"]
    assert all(p.bands == ("B0",) and p.levels == 65536 for p in measured)
    assert all({b for _, b in p.models} == {0} for p in measured)


def test_a_multi_spectral_camera_s_tiffs_are_replayed_as_their_six_bands(fake_robot, tmp_path):
    folder = tmp_path / "spectral"
    folder.mkdir()
    for i, elevation in enumerate((90.0, 80.0, 70.0)):  # the scene model's five spectral bands and thermal
        view = render("mixed", ViewAngles(elevation, 0.0), (H, W), seed=i, bands="multispectral")
        tifffile.imwrite(folder / f"v{i}.tif", view.image, photometric="minisblack", planarconfig="contig")
    raw = {"features": {"space": "raw"}, "sweep": {"start": 90, "stop": 70}}
    packets, sources = run_sweep(fake_robot, robot_text(f"replay:{folder}", False, "fake", raw))
    measured = models(packets)
    assert [round(p.commanded[0]) for p in measured] == [90, 80, 70]
    assert list(sources.values()) == ["v0.tif", "v1.tif", "v2.tif"]
    assert all(p.bands == tuple(f"B{k}" for k in range(6)) and p.levels == 65536 for p in measured)
    thermal = [m for p in measured for (_, b), m in p.models.items() if b == 5]
    assert all(28_000 < float(m.ppf(0.5)) < 32_000 for m in thermal)  # centikelvin, band 5 kept where it was


def test_frames_are_rgb_in_order_and_one_band_stays_one_band(tmp_path):
    rgb = rgb_frame(7)
    assert np.array_equal(read_frame(write_rgb(tmp_path / "c.png", rgb)), rgb)
    rgba = cv2.cvtColor(cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), cv2.COLOR_BGR2BGRA)
    rgba[..., 3] = 17
    cv2.imwrite(str(tmp_path / "a.png"), rgba)
    assert np.array_equal(read_frame(tmp_path / "a.png"), rgb)  # the alpha channel is not a band of light
    deep = (np.arange(H * W, dtype=np.uint16) * 61).reshape(H, W)
    cv2.imwrite(str(tmp_path / "d.png"), deep)
    got = read_frame(tmp_path / "d.png")
    assert got.shape == (H, W, 1) and got.dtype == np.uint16 and np.array_equal(got[..., 0], deep)
    gray = rgb[..., 0]
    Image.fromarray(np.dstack([gray, np.full_like(gray, 200)]), "LA").save(tmp_path / "la.png")
    assert np.array_equal(read_frame(tmp_path / "la.png"), gray[..., None])  # gray and alpha: one band
    write_rgb(tmp_path / "j.jpg", rgb)
    jpeg = read_frame(tmp_path / "j.jpg").astype(float)
    assert jpeg.shape == (H, W, 3) and np.abs(jpeg - rgb).mean() < 8  # lossy, but red stays red
    assert jpeg[:, : W // 2, 0].mean() > jpeg[:, : W // 2, 2].mean() + 100


def test_a_folder_or_a_glob_names_the_files(shots):
    assert [p.name for p in replay_files(str(shots))] == ["shot_1.png", "shot_2.jpg", "shot_10.png"]
    assert [p.name for p in replay_files(f"{shots}/*.png")] == ["shot_1.png", "shot_10.png"]


@pytest.mark.parametrize(("camera", "message"), [
    ("replay:", "name a folder or a glob"),
    ("replay:{shots}/missing", "neither a folder nor a glob"),
    ("replay:{shots}/*.txt", "no PNG, JPEG or TIFF files"),
    ("replay:{shots}/../", "no PNG, JPEG or TIFF files"),
])
def test_bad_paths_are_one_line_naming_the_key(shots, camera, message):
    with pytest.raises(HalConfigError, match=message) as err:
        build_hal({"body": "fake", "size": (H, W), "camera": camera.format(shots=shots)}, env={})
    assert "\n" not in str(err.value) and "hal.camera" in str(err.value)


def test_the_robot_refuses_files_of_another_size_than_hal_size_and_a_real_body(shots):
    with pytest.raises(HalConfigError, match=rf"files are {W}x{H}.*set hal.size = \[{H}, {W}\]"):
        build_hal({"body": "fake", "size": (120, 160), "camera": f"replay:{shots}"}, env={})
    with pytest.raises(HalConfigError, match="fake and emulated bodies only"):
        build_hal({"body": "real", "servo_port": "/dev/null", "camera": f"replay:{shots}"}, env={})
    with pytest.raises(HalConfigError, match="replay_loop must be true or false"):
        build_hal({"body": "fake", "size": (H, W), "camera": f"replay:{shots}", "replay_loop": "yes"}, env={})


def test_a_file_of_another_size_is_a_camera_error_and_the_next_try_plays_on(shots):
    write_rgb(shots / "shot_3.png", np.zeros((H + 2, W, 3), np.uint8))
    (shots / "shot_4.png").write_bytes(b"not a png")
    camera = ReplayCamera(replay_files(str(shots)), loop=False)
    with pytest.raises(HalError, match="asked for 64x48"):
        camera.open(64, 48)
    camera.open(W, H)
    camera.capture()
    camera.capture()
    with pytest.raises(HalError, match=rf"shot_3.png is {W}x{H + 2}"):
        camera.capture()
    with pytest.raises(HalError, match="cannot read .*shot_4.png"):
        camera.capture()
    camera.capture()
    assert camera.last_source.name == "shot_10.png" and camera.played == 3
    with pytest.raises(ReplayEnded):
        camera.capture()


def test_controls_are_granted_as_asked_and_the_settings_name_the_file(shots):
    camera = ReplayCamera(replay_files(str(shots)))
    assert camera.settings().locked and camera.settings().source is None
    camera.open(W, H)
    camera.capture()
    granted = camera.set_controls(CameraControls(4_000.0, 2.0, white_balance_gains=(1.5, 0.8)))
    assert granted.locked and granted.exposure_us == 4_000.0 and granted.white_balance_gains == (1.5, 0.8)
    assert Path(granted.source).name == "shot_1.png"
    auto = camera.set_controls(CameraControls())
    assert auto.auto_exposure and auto.auto_white_balance and not auto.locked


def test_a_relative_replay_path_is_against_the_config_file_and_scene_labels_are_refused(tmp_path, shots):
    where = tmp_path / "robot"
    where.mkdir()
    (where / "robot.toml").write_text(robot_text("replay:../shots/*.jpg", loop=False))
    cfg = config.load(where / "robot.toml")
    assert cfg.hal.camera == f"replay:{shots}/*.jpg"
    assert [p.name for p in build_hal(cfg.hal).camera.files] == ["shot_2.jpg"]
    (where / "robot.toml").write_text(robot_text("replay:../shots", False, "fake", {"segment": {"method": "scene"}}))
    with pytest.raises(config.ConfigError, match="replay camera has no ground truth"):
        config.load(where / "robot.toml")
