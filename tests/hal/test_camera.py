"""Camera drivers: the OpenCV path through an image sequence, stale-buffer draining,
the picamera2 adapter, and the fakes' faults and history."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from hal.camera import OpenCVCamera, PiCamera2Camera
from hal.emulators.camera import SequenceCamera, write_sequence
from hal.fakes import Faults
from hal.fakes.camera import FakeCamera
from hal.fakes.tracker import FakeTracker
from hal.interfaces import Camera, HalError, NotGranted, OrientationTracker, ViewAngles, view_from_orientation
from tests.support.v4l2 import QueueingCapture


def frames(n: int, h: int = 24, w: int = 32) -> list[np.ndarray]:
    rng = np.random.default_rng(5)
    return [rng.integers(0, 256, (h, w, 3), dtype=np.uint8) for _ in range(n)]


def test_sequence_camera_replays_rgb_frames_through_opencv_in_order(tmp_path):
    shot = frames(3)
    write_sequence(tmp_path, shot)
    cam = SequenceCamera(tmp_path)
    assert isinstance(cam, Camera)
    cam.open(32, 24)
    got = [cam.capture() for _ in range(5)]
    cam.close()
    for i, g in enumerate(got):  # RGB in, RGB out, and it loops
        assert g.dtype == np.uint8 and np.array_equal(g, shot[i % 3])


def test_sequence_camera_16_bit_band(tmp_path):
    band = np.random.default_rng(1).integers(0, 65536, (24, 32), dtype=np.uint16)
    write_sequence(tmp_path, [band])
    cam = SequenceCamera(tmp_path)
    cam.open(32, 24, "Y16 ")
    got = cam.capture()
    assert got.shape == (24, 32, 1) and got.dtype == np.uint16 and np.array_equal(got[..., 0], band)


def test_sequence_camera_rejects_wrong_size_saying_what_it_has(tmp_path):
    write_sequence(tmp_path, frames(1))
    with pytest.raises(HalError, match="asked for 64x48, the images are 32x24"):
        SequenceCamera(tmp_path).open(64, 48)


def test_sequence_camera_needs_frames(tmp_path):
    with pytest.raises(HalError, match="no frame_0000.png"):
        SequenceCamera(tmp_path)
    with pytest.raises(ValueError, match="PNG holds"):
        write_sequence(tmp_path, [np.zeros((4, 4, 6), np.uint8)])


def camera_on(cap: QueueingCapture, **kw) -> OpenCVCamera:
    return OpenCVCamera(0, capture_factory=lambda dev, api: cap, **kw)


@pytest.mark.parametrize("granted", [1, 4])
def test_capture_never_returns_a_stale_frame(granted):
    cap = QueueingCapture(queued=granted, granted_buffers=granted)
    cam = camera_on(cap)
    cam.open(8, 6)
    cap.queue.extend(range(50, 60))  # frames queued while the robot moved
    for _ in range(3):
        frame = cam.capture()
        assert frame[0, 0, 2] >= 100  # fresh; and RGB order (blue is last)
        cap.queue.extend(range(60, 70))


def test_open_sets_fourcc_before_size_and_asks_for_one_buffer():
    cap = QueueingCapture(queued=0, granted_buffers=1)
    camera_on(cap).open(8, 6, "MJPG")
    props = [c[1] for c in cap.calls]
    assert props.index(cv2.CAP_PROP_FOURCC) < props.index(cv2.CAP_PROP_FRAME_WIDTH)
    assert ("set", cv2.CAP_PROP_BUFFERSIZE, 1) in cap.calls
    assert cap.props[cv2.CAP_PROP_FOURCC] == cv2.VideoWriter_fourcc(*"MJPG")


def test_open_reports_what_the_driver_granted():
    cap = QueueingCapture(queued=0, granted_buffers=1, grant=(320, 240), fourcc="YUYV")
    cam = camera_on(cap)
    with pytest.raises(NotGranted, match=r"asked for 640x480 'MJPG', driver granted 320x240 'YUYV'; set hal.size"):
        cam.open(640, 480, "MJPG")
    assert cap.released
    with pytest.raises(HalError, match="four-character"):
        cam.open(640, 480, "RGB")


def test_sixteen_bit_format_must_be_granted():
    cap = QueueingCapture(queued=0, granted_buffers=1, fourcc="YUYV")
    with pytest.raises(HalError, match="'Y16 '"):
        camera_on(cap).open(8, 6, "Y16 ")


def test_dropped_frames_are_retried_then_a_clear_error():
    cap = QueueingCapture(queued=0, granted_buffers=1)
    cam = camera_on(cap, retries=3)
    cam.open(8, 6)
    cap.drops = 3
    assert cam.capture()[0, 0, 2] >= 100
    assert cam.dropped == 3
    cap.drops = 10
    with pytest.raises(HalError, match="camera 0: no frame after 4 tries"):
        cam.capture()


def test_capture_before_open_is_an_error():
    with pytest.raises(HalError, match="before open"):
        OpenCVCamera(0, capture_factory=lambda d, a: QueueingCapture(0, 1)).capture()


class StandInPicamera2:
    """The slice of picamera2.Picamera2 the adapter uses; like picamera2, `configure` works on
    a copy and may adjust the size, so only `camera_configuration()` tells what was granted."""

    def __init__(self, grant=None):
        self.grant = grant
        self.started = self.closed = False
        self.config = None

    def create_still_configuration(self, main):
        return {"main": dict(main)}

    def configure(self, config):
        self.config = {"main": dict(config["main"], size=self.grant or config["main"]["size"])}

    def camera_configuration(self):
        return self.config

    def start(self):
        self.started = True

    def capture_array(self):
        w, h = self.config["main"]["size"]
        f = np.zeros((h, w, 3), np.uint8)
        f[..., 0] = 10  # memory order B, G, R for "RGB888"
        f[..., 2] = 200
        return f

    def stop(self):
        self.started = False

    def close(self):
        self.closed = True


def test_picamera2_adapter_configures_starts_and_returns_rgb():
    stand_in = StandInPicamera2()
    cam = PiCamera2Camera(factory=lambda: stand_in)
    cam.open(16, 12)
    assert stand_in.started and stand_in.config["main"] == {"size": (16, 12), "format": "RGB888"}
    frame = cam.capture()
    assert frame.shape == (12, 16, 3) and frame[0, 0, 0] == 200 and frame[0, 0, 2] == 10
    cam.close()
    assert stand_in.closed and not stand_in.started


def test_picamera2_adapter_errors():
    cam = PiCamera2Camera(factory=lambda: StandInPicamera2(grant=(8, 6)))
    with pytest.raises(HalError, match="asked for 16x12, granted 8x6"):
        cam.open(16, 12)
    with pytest.raises(HalError, match="unsupported"):
        cam.open(16, 12, "YUYV")
    with pytest.raises(HalError, match="picamera2 is not installed"):
        PiCamera2Camera()


def test_fake_tracker_reports_true_view_with_bias_and_noise():
    view = ViewAngles(30.0, 120.0)
    t = FakeTracker(lambda: view, noise_deg=0.3, bias_deg=0.5, seed=2)
    assert isinstance(t, OrientationTracker)
    seen = [view_from_orientation(t.orientation()) for _ in range(400)]
    mean_el = sum(v.elevation for v in seen) / len(seen)
    assert mean_el == pytest.approx(30.5, abs=0.1)
    assert max(abs(v.azimuth - 120.5) for v in seen) < 2.0
    assert len({round(v.elevation, 6) for v in seen}) > 100
    assert [c.outcome for c in t.history] == ["ok"] * 400


def test_fake_tracker_nacks_retry_then_fail():
    faults = Faults(force={"nack"}, remaining=2)
    t = FakeTracker(lambda: ViewAngles(90.0), faults=faults, retries=3)
    t.orientation()
    assert [c.outcome for c in t.history] == ["nack", "nack", "ok"]
    t.faults = Faults(force={"nack"})
    with pytest.raises(HalError, match="no answer after 4 tries"):
        t.calibration()


def test_fake_camera_renders_the_current_view_and_drops_frames():
    pose = [ViewAngles(90.0)]
    faults = Faults(force={"drop"}, remaining=1)
    cam = FakeCamera("black", lambda: pose[0], size=(24, 32), faults=faults)
    cam.open(32, 24)
    a = cam.capture()
    pose[0] = ViewAngles(30.0)
    b = cam.capture()
    assert a.shape == b.shape == (24, 32, 3) and a.dtype == np.uint8
    assert not np.array_equal(a, b)
    assert [c.outcome for c in cam.history] == ["ok", "drop", "ok", "ok"]
    assert cam.history[-1].args == (ViewAngles(30.0),)
    cam.faults = Faults(force={"drop"})
    with pytest.raises(HalError, match="dropped"):
        cam.capture()


def test_fake_camera_multispectral_and_bad_input():
    cam = FakeCamera("field", lambda: ViewAngles(60.0), size=(24, 32), bands="multispectral")
    with pytest.raises(HalError, match="does not fit bands"):
        cam.open(32, 24, "BGR3")
    cam.open(32, 24, "MSP6")
    assert cam.capture().shape == (24, 32, 6)
    with pytest.raises(HalError, match="unknown scene"):
        FakeCamera("moon", lambda: ViewAngles(90.0))


class UnconvertedCapture(QueueingCapture):
    """A driver that hands YUYV through as two channels per pixel."""

    def retrieve(self):
        return True, np.zeros((6, 8, 2), np.uint8)


def test_an_unconverted_two_channel_frame_is_a_clear_error():
    cam = camera_on(UnconvertedCapture(queued=0, granted_buffers=1))
    cam.open(8, 6)
    with pytest.raises(HalError, match=r"camera 0: frame \(6, 8, 2\) uint8 is not BGR or gray"):
        cam.capture()
