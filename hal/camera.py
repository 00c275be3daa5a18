"""Camera drivers: OpenCV VideoCapture (V4L2) and a picamera2-shaped adapter.

Both hand out RGB: H x W x 3 uint8, or H x W x 1 uint16 for the 16-bit "Y16 " format.
Both take `CameraControls` (exposure, gain, white balance, each manual or auto), read back
what the device granted and say whether the lock held (`hal.controls`).
"""
from __future__ import annotations

from collections.abc import Callable
from typing import Any

import cv2
import numpy as np

from hal.controls import Tolerance, with_lock_check
from hal.interfaces import CameraControls, CameraSettings, HalError, NotGranted

SIXTEEN_BIT = frozenset({"Y16 "})
V4L2_DEFAULT_BUFFERS = 4  # what V4L2 queues when a driver will not say
# V4L2 control values as OpenCV's V4L2 backend passes them through (no range normalisation).
V4L2_EXPOSURE_MANUAL = 1
V4L2_EXPOSURE_APERTURE_PRIORITY = 3  # the automatic mode UVC cameras offer
V4L2_EXPOSURE_UNIT_US = 100.0  # exposure_time_absolute counts 100 µs
# A granted V4L2 value is an integer of the driver's step: one exposure unit, one gain step.
V4L2_TOLERANCE = Tolerance(exposure_us=V4L2_EXPOSURE_UNIT_US, gain=1.0, kelvin=50.0, relative=0.02)


def fourcc_text(code: float) -> str:
    c = int(code)
    return "".join(chr((c >> (8 * i)) & 0xFF) for i in range(4)) if c > 0 else "?"


def _check_format(pixel_format: str) -> str:
    if len(pixel_format) != 4 or not pixel_format.isascii():
        raise HalError(f"pixel format must be a four-character code such as 'BGR3', 'MJPG' or 'Y16 ', "
                       f"got {pixel_format!r}")
    return pixel_format


class OpenCVCamera:
    """A V4L2 device through cv2.VideoCapture that never hands out a stale frame.

    V4L2 fills a queue of buffers while nobody reads; `capture` grabs past every buffer
    the driver may have queued (it asks for one) so the frame it retrieves is fresh.
    """

    def __init__(self, device: int | str, api: int = cv2.CAP_V4L2, retries: int = 3,
                 capture_factory: Callable[[Any, int], Any] = cv2.VideoCapture) -> None:
        self.device = device
        self.api = api
        self.retries = retries
        self._factory = capture_factory
        self._cap: Any = None
        self.size: tuple[int, int] = (0, 0)  # granted (height, width)
        self.pixel_format = ""
        self.stale_buffers = 0
        self.dropped = 0
        self._asked: CameraControls | None = None
        self._refused: list[str] = []

    def _where(self) -> str:
        return f"camera {self.device!r}"

    def open(self, width: int, height: int, pixel_format: str = "BGR3") -> None:
        fmt = _check_format(pixel_format)
        if width <= 0 or height <= 0:
            raise HalError(f"{self._where()}: frame size must be positive, got {width}x{height}")
        self.close()
        cap = self._factory(self.device, self.api)
        if not cap.isOpened():
            raise HalError(f"{self._where()}: cannot open the device")
        self._cap = cap
        try:
            self._configure(cap, width, height, fmt)
            if self._asked is not None:  # a reopened device gets the lock it had
                self._apply(cap, self._asked)
        except BaseException:
            self.close()
            raise

    def _configure(self, cap: Any, width: int, height: int, fmt: str) -> None:
        # FOURCC first: many drivers reset the frame size when the format changes.
        cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*fmt))
        if fmt in SIXTEEN_BIT:
            cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, width)
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, height)
        cap.set(cv2.CAP_PROP_BUFFERSIZE, 1)
        got_w, got_h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        got_fmt = fourcc_text(cap.get(cv2.CAP_PROP_FOURCC))
        if (got_w, got_h) != (width, height) or (fmt in SIXTEEN_BIT and got_fmt != fmt):
            raise NotGranted(f"{self._where()}: asked for {width}x{height} {fmt!r}, driver granted "
                             f"{got_w}x{got_h} {got_fmt!r}; set hal.size and hal.pixel_format to a mode "
                             "it offers (v4l2-ctl --list-formats-ext)")
        buffers = int(cap.get(cv2.CAP_PROP_BUFFERSIZE))
        self.stale_buffers = buffers if buffers > 0 else V4L2_DEFAULT_BUFFERS
        self.size, self.pixel_format = (height, width), fmt
        for _ in range(self.stale_buffers):  # drop what queued up while we configured
            cap.grab()

    def _read(self) -> np.ndarray | None:
        """One fresh frame, or None when the device dropped it."""
        for _ in range(self.stale_buffers):
            if not self._cap.grab():
                return None
        if not self._cap.grab():
            return None
        ok, frame = self._cap.retrieve()
        return frame if ok and frame is not None else None

    def capture(self) -> np.ndarray:
        if self._cap is None:
            raise HalError(f"{self._where()}: capture before open")
        for _ in range(self.retries + 1):
            frame = self._read()
            if frame is not None:
                return self._to_output(frame)
            self.dropped += 1
        raise HalError(f"{self._where()}: no frame after {self.retries + 1} tries (frames dropped)")

    def _to_output(self, frame: np.ndarray) -> np.ndarray:
        h, w = self.size
        if self.pixel_format in SIXTEEN_BIT:
            frame = frame.reshape(frame.shape[0], frame.shape[1], -1)[..., :1]
            want = np.uint16
        else:
            try:
                frame = cv2.cvtColor(frame, cv2.COLOR_GRAY2RGB if frame.ndim == 2 else cv2.COLOR_BGR2RGB)
            except cv2.error:  # e.g. two-channel YUYV handed through unconverted
                raise HalError(f"{self._where()}: frame {frame.shape} {frame.dtype} is not BGR or gray") from None
            want = np.uint8
        if frame.shape[:2] != (h, w) or frame.dtype != want:
            raise HalError(f"{self._where()}: frame is {frame.shape} {frame.dtype}, expected {h}x{w} {want.__name__}")
        return np.ascontiguousarray(frame)

    def set_controls(self, controls: CameraControls) -> CameraSettings:
        """Ask the V4L2 driver for `controls` (auto off before a manual value: drivers ignore
        a value while their automatic runs) and return what it granted."""
        if self._cap is None:
            raise HalError(f"{self._where()}: set controls after open")
        self._asked = controls
        self._apply(self._cap, controls)
        return self.settings()

    def _apply(self, cap: Any, c: CameraControls) -> None:
        refused = []

        def put(prop: int, value: float, what: str) -> None:
            if not cap.set(prop, value):
                refused.append(f"the driver refused {what}")

        if c.exposure_us is None:
            put(cv2.CAP_PROP_AUTO_EXPOSURE, V4L2_EXPOSURE_APERTURE_PRIORITY, "auto exposure")
        else:
            put(cv2.CAP_PROP_AUTO_EXPOSURE, V4L2_EXPOSURE_MANUAL, "manual exposure")
            put(cv2.CAP_PROP_EXPOSURE, round(c.exposure_us / V4L2_EXPOSURE_UNIT_US), f"exposure {c.exposure_us:g} us")
        if c.gain is not None:
            put(cv2.CAP_PROP_GAIN, c.gain, f"gain {c.gain:g}")
        if c.manual_white_balance:
            put(cv2.CAP_PROP_AUTO_WB, 0, "manual white balance")
            if c.white_balance_kelvin is not None:
                put(cv2.CAP_PROP_WB_TEMPERATURE, c.white_balance_kelvin, f"white balance {c.white_balance_kelvin:g} K")
            else:
                red, blue = c.white_balance_gains or (0.0, 0.0)
                put(cv2.CAP_PROP_WHITE_BALANCE_RED_V, red, f"red balance {red:g}")
                put(cv2.CAP_PROP_WHITE_BALANCE_BLUE_U, blue, f"blue balance {blue:g}")
        else:
            put(cv2.CAP_PROP_AUTO_WB, 1, "auto white balance")
        self._refused = refused

    def settings(self) -> CameraSettings:
        """What the driver reports now; V4L2 has no standard sensor temperature (None)."""
        if self._cap is None:
            raise HalError(f"{self._where()}: read settings after open")

        def get(prop: int) -> float | None:
            value = float(self._cap.get(prop))
            return value if value >= 0 else None  # OpenCV answers -1 for a control the driver lacks

        mode = get(cv2.CAP_PROP_AUTO_EXPOSURE)
        auto_exposure = mode is not None and round(mode) != V4L2_EXPOSURE_MANUAL
        exposure = get(cv2.CAP_PROP_EXPOSURE)
        red, blue = get(cv2.CAP_PROP_WHITE_BALANCE_RED_V), get(cv2.CAP_PROP_WHITE_BALANCE_BLUE_U)
        kelvin = get(cv2.CAP_PROP_WB_TEMPERATURE)
        got = CameraSettings(
            exposure_us=None if exposure is None else exposure * V4L2_EXPOSURE_UNIT_US,
            gain=get(cv2.CAP_PROP_GAIN),
            white_balance_kelvin=kelvin or None,
            white_balance_gains=None if red is None or blue is None else (red, blue),
            auto_exposure=auto_exposure,
            auto_gain=auto_exposure,  # UVC cameras drive their gain from the auto exposure
            auto_white_balance=bool(get(cv2.CAP_PROP_AUTO_WB)),
            problems=tuple(self._refused))
        return got if self._asked is None else with_lock_check(self._asked, got, V4L2_TOLERANCE)

    def close(self) -> None:
        if self._cap is not None:
            self._cap.release()
            self._cap = None


PICAMERA2_FORMATS = {"BGR3": "RGB888", "RGB3": "BGR888"}  # picamera2 names the memory order reversed
# libcamera quantises exposure to sensor lines and gain to the sensor's gain codes.
PICAMERA2_TOLERANCE = Tolerance(exposure_us=50.0, gain=0.0, kelvin=100.0, relative=0.02)
PICAMERA2_SETTLE_FRAMES = 8  # controls reach the sensor a few frames after they are set


class PiCamera2Camera:
    """The Raspberry Pi camera stack through a picamera2-shaped object."""

    def __init__(self, factory: Callable[[], Any] | None = None) -> None:
        if factory is None:
            try:
                from picamera2 import Picamera2  # only on a Raspberry Pi
            except ImportError as exc:
                raise HalError("picamera2 is not installed; use an OpenCV camera device instead") from exc
            factory = Picamera2
        self._factory = factory
        self._cam: Any = None
        self.size: tuple[int, int] = (0, 0)
        self.pixel_format = ""
        self._asked: CameraControls | None = None
        self._refused: tuple[str, ...] = ()

    def open(self, width: int, height: int, pixel_format: str = "BGR3") -> None:
        if pixel_format not in PICAMERA2_FORMATS:
            raise HalError(f"picamera2: pixel format {pixel_format!r} unsupported; use one of "
                           f"{', '.join(PICAMERA2_FORMATS)}")
        self.close()
        cam = self._factory()
        try:
            config = cam.create_still_configuration(main={"size": (width, height),
                                                          "format": PICAMERA2_FORMATS[pixel_format]})
            cam.configure(config)
            # picamera2 configures a copy: what the camera granted is in its live configuration.
            granted = tuple(cam.camera_configuration()["main"]["size"])
            if granted != (width, height):
                raise NotGranted(f"picamera2: asked for {width}x{height}, granted {granted[0]}x{granted[1]}; "
                                 "set hal.size to a mode the sensor offers")
            cam.start()
        except BaseException:
            cam.close()
            raise
        self._cam, self.size, self.pixel_format = cam, (height, width), pixel_format
        if self._asked is not None:
            self.set_controls(self._asked)

    def capture(self) -> np.ndarray:
        if self._cam is None:
            raise HalError("picamera2: capture before open")
        frame = np.asarray(self._cam.capture_array())  # waits for the next completed request
        h, w = self.size
        if frame.ndim != 3 or frame.shape[:2] != (h, w) or frame.shape[2] < 3 or frame.dtype != np.uint8:
            raise HalError(f"picamera2: frame is {frame.shape} {frame.dtype}, expected {h}x{w}x3 uint8")
        rgb = frame[..., 2::-1] if self.pixel_format == "BGR3" else frame[..., :3]
        return np.ascontiguousarray(rgb)

    def set_controls(self, controls: CameraControls) -> CameraSettings:
        """Ask libcamera for `controls`; waits a few frames for them to reach the sensor."""
        if self._cam is None:
            raise HalError("picamera2: set controls after open")
        wanted, refused = picamera2_controls(controls, getattr(self._cam, "camera_controls", {}))
        self._cam.set_controls(wanted)
        self._asked, self._refused = controls, refused
        settings = self.settings()
        for _ in range(PICAMERA2_SETTLE_FRAMES):
            if settings.lock_held:
                break
            settings = self.settings()
        return settings

    def settings(self) -> CameraSettings:
        """From the next frame's metadata; the automatic modes are the ones asked for
        (libcamera's metadata reports values, not modes)."""
        if self._cam is None:
            raise HalError("picamera2: read settings after open")
        md = self._cam.capture_metadata()
        asked = self._asked or CameraControls()
        gains = md.get("ColourGains")
        temperature = md.get("SensorTemperature")
        got = CameraSettings(
            exposure_us=_float_or_none(md.get("ExposureTime")),
            gain=_float_or_none(md.get("AnalogueGain")),
            white_balance_kelvin=_float_or_none(md.get("ColourTemperature")),
            white_balance_gains=None if gains is None else (float(gains[0]), float(gains[1])),
            sensor_temperature_c=_float_or_none(temperature),
            auto_exposure=asked.exposure_us is None, auto_gain=asked.gain is None,
            auto_white_balance=not asked.manual_white_balance, problems=self._refused)
        return got if self._asked is None else with_lock_check(self._asked, got, PICAMERA2_TOLERANCE)

    def close(self) -> None:
        if self._cam is not None:
            try:
                self._cam.stop()
            finally:
                self._cam.close()
                self._cam = None


def _float_or_none(value: Any) -> float | None:
    return None if value is None else float(value)


def picamera2_controls(c: CameraControls, available: Any) -> tuple[dict[str, Any], tuple[str, ...]]:
    """libcamera controls for `c`, and what this camera cannot do. An ExposureTime or
    AnalogueGain of 0 hands that control back to the AGC; with only one of them fixed the
    AGC keeps running and varies the other."""
    wanted: dict[str, Any] = {
        "AeEnable": c.exposure_us is None or c.gain is None,
        "ExposureTime": 0 if c.exposure_us is None else int(round(c.exposure_us)),
        "AnalogueGain": 0.0 if c.gain is None else float(c.gain),
        "AwbEnable": not c.manual_white_balance,
    }
    refused: tuple[str, ...] = ()
    if c.white_balance_gains is not None:
        wanted["ColourGains"] = c.white_balance_gains
    elif c.white_balance_kelvin is not None:
        if "ColourTemperature" in available:
            wanted["ColourTemperature"] = int(round(c.white_balance_kelvin))
        else:
            refused = ("this libcamera has no ColourTemperature control: give white balance as red,blue gains",)
    return wanted, refused
