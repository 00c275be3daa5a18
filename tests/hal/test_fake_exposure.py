"""The fake camera renders at its exposure, gain and white balance, imitates a lagging auto
exposure when unlocked, and the scenes can hold a grey reference card."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from hal.factory import build_hal
from hal.fakes.camera import AE_TARGET_DN, REFERENCE_EXPOSURE_US, FakeCamera
from hal.interfaces import CameraControls, ViewAngles
from hal.scene import GREY_REFERENCE_REFLECTANCE, LABEL_NAMES, Label, render, scene_radiance
from hal.scene.light import AMBIENT, SUN

SIZE = (120, 160)
SWEEP = (90.0, 80.0, 70.0, 60.0, 50.0, 40.0, 30.0)


def camera_at(pose: list, scene="black", **kw) -> FakeCamera:
    cam = FakeCamera(scene, lambda: pose[0], seed=1, size=SIZE, **kw)
    cam.open(SIZE[1], SIZE[0])
    return cam


def test_the_fake_boots_locked_at_the_reference_and_draws_exactly_the_renderers_frames():
    pose = [ViewAngles(45.0, 30.0)]
    cam = camera_at(pose, "field")
    assert cam.settings().locked
    assert np.array_equal(cam.capture(), render("field", pose[0], SIZE, seed=1).image)


def test_more_exposure_is_brighter_and_saturates_sooner():
    pose = [ViewAngles(60.0)]
    cam = camera_at(pose, "white")
    means, saturated = [], []
    for exposure in (5_000.0, 10_000.0, 20_000.0, 40_000.0):
        cam.set_controls(CameraControls(exposure, 1.0, 5500.0))
        frame = cam.capture().astype(float)
        means.append(frame.mean())
        saturated.append((frame == 255).mean())
    assert means == sorted(means) and means[1] == pytest.approx(2 * means[0], rel=0.02)  # linear below clipping
    assert saturated[0] == saturated[1] == 0.0 and 0.0 < saturated[2] < saturated[3]
    assert means[3] < 4 * means[1]  # the clipped part stops growing


def test_gain_amplifies_signal_and_read_noise_alike():
    pose = [ViewAngles(90.0)]
    cam = camera_at(pose, "black")
    noise_free = scene_radiance("black", pose[0], SIZE, seed=1).radiance * 255.0
    cam.set_controls(CameraControls(10_000.0, 1.0, 5500.0))
    base = cam.capture().astype(float)
    cam.set_controls(CameraControls(5_000.0, 2.0, 5500.0))  # same total: same mean, twice the read noise
    amplified = cam.capture().astype(float)
    assert amplified.mean() == pytest.approx(base.mean(), rel=0.02)
    assert (amplified - noise_free).std() > 1.7 * (base - noise_free).std()


def test_white_balance_below_daylight_turns_the_scene_blue():
    pose = [ViewAngles(70.0)]
    cam = camera_at(pose, "white")
    cam.set_controls(CameraControls(8_000.0, 1.0, 3200.0))
    warm = cam.capture().reshape(-1, 3).astype(float).mean(axis=0)
    cam.set_controls(CameraControls(8_000.0, 1.0, white_balance_gains=(1.0, 1.0)))
    neutral = cam.capture().reshape(-1, 3).astype(float).mean(axis=0)
    assert warm[2] > neutral[2] * 1.3 and warm[0] < neutral[0] * 0.8
    assert warm[1] == pytest.approx(neutral[1], rel=0.01)


def sweep(controls: CameraControls | None, scene: str = "black") -> dict[float, float]:
    """Mean level per elevation of a sweep through the fake HAL (arm moves, camera captures)."""
    hal = build_hal({"body": "fake", "scene": scene, "size": SIZE, "seed": 1}, env={})
    try:
        hal.arm.enable()
        hal.camera.open(SIZE[1], SIZE[0])
        if controls is not None:
            hal.camera.set_controls(controls)
        means = {}
        for elevation in SWEEP:
            hal.arm.move_to(ViewAngles(elevation, 0.0), timeout_s=5.0)
            means[elevation] = float(hal.camera.capture().astype(float).mean())
        return means
    finally:
        hal.close()


def view_dependence(means: dict[float, float]) -> float:
    """The black plate's change from straight down to 30 degrees, relative to straight down."""
    return (means[30.0] - means[90.0]) / means[90.0]


def test_an_unlocked_sweep_loses_the_view_dependence_a_locked_sweep_keeps():
    truth = view_dependence({e: float(render("black", ViewAngles(e), SIZE, seed=1).image.astype(float).mean())
                             for e in (90.0, 30.0)})
    assert truth > 0.2  # grazing views of black sand see fewer shadowed gaps
    locked = view_dependence(sweep(CameraControls(2 * REFERENCE_EXPOSURE_US, 1.0, 5500.0)))
    unlocked_means = sweep(CameraControls())
    unlocked = view_dependence(unlocked_means)
    assert locked == pytest.approx(truth, rel=0.05)  # the bar: within 5% of the locked truth
    assert abs(unlocked) < locked / 3  # the bar: under a third of the locked difference
    assert all(m == pytest.approx(AE_TARGET_DN, rel=0.05) for m in unlocked_means.values())


def test_auto_exposure_lags_after_a_jump_then_settles():
    pose = [ViewAngles(90.0)]
    cam = camera_at(pose, "white")
    cam.set_controls(CameraControls())
    settled = cam.capture().astype(float).mean()
    pose[0] = ViewAngles(30.0, 45.0)  # looking at the sunlit faces: much brighter
    means = [cam.capture().astype(float).mean() for _ in range(4)]
    errors = [abs(m - AE_TARGET_DN) for m in means]
    assert settled == pytest.approx(AE_TARGET_DN, rel=0.03)
    assert errors[0] > 3 * errors[-1] and errors == sorted(errors, reverse=True)
    assert cam.settings().auto_exposure and not cam.settings().locked


def test_a_camera_that_does_not_honour_the_lock_keeps_normalising():
    pose = [ViewAngles(90.0)]
    cam = camera_at(pose, "black", honours_lock=False)
    s = cam.set_controls(CameraControls(10_000.0, 1.0, 5500.0))
    assert not s.lock_held and s.auto_exposure
    assert cam.capture().astype(float).mean() == pytest.approx(AE_TARGET_DN, rel=0.05)


@pytest.mark.parametrize("view", [ViewAngles(90.0), ViewAngles(30.0), ViewAngles(45.0, 200.0)])
def test_the_grey_reference_card_is_in_every_view_at_a_level_set_by_light_and_exposure(view):
    flat = AMBIENT + (1.0 - AMBIENT) * np.sin(np.radians(SUN.elevation))  # irradiance of a level facet
    for exposure in (1.0, 2.0):
        r = render("mixed", view, SIZE, seed=2, reference=True, exposure=exposure)
        card = r.mask == Label.GREY_REFERENCE
        assert 0.005 < card.mean() < 0.05
        assert card[SIZE[0] // 2 - 3:SIZE[0] // 2 + 3, SIZE[1] // 2 - 3:SIZE[1] // 2 + 3].all()  # at the centre
        inner = cv2.erode(card.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)  # edges blend
        level = r.image[inner].astype(float).mean(axis=0)
        assert level == pytest.approx([GREY_REFERENCE_REFLECTANCE * flat * 255 * exposure] * 3, abs=1.0)
    plain = render("mixed", view, SIZE, seed=2)
    assert Label.GREY_REFERENCE not in plain.mask
    assert LABEL_NAMES[int(Label.GREY_REFERENCE)] == "grey_reference"


def test_the_reference_card_undoes_auto_exposure_where_nothing_clips():
    """Plate over card in each frame cancels whatever exposure the camera chose."""
    pose = [ViewAngles(90.0)]
    cam = camera_at(pose, "white", reference=True)
    ratios = {}
    views = (ViewAngles(90.0), ViewAngles(30.0, 45.0))  # straight down; low, with the sun behind
    for name, controls in (("locked", CameraControls(10_000.0, 1.0, 5500.0)), ("auto", CameraControls())):
        cam.set_controls(controls)
        for view in views:
            pose[0] = view
            frame = cam.capture().astype(float)
            assert (frame == 255).mean() < 0.001
            card = cam.last_mask == Label.GREY_REFERENCE
            ratios[name, view] = frame[~card].mean() / frame[card].mean()
    locked = ratios["locked", views[1]] / ratios["locked", views[0]]
    auto = ratios["auto", views[1]] / ratios["auto", views[0]]
    assert locked > 1.1 and auto == pytest.approx(locked, rel=0.02)
