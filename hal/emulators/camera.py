"""A camera source through OpenCV itself: an image sequence replayed by VideoCapture(CAP_IMAGES).

The scene renderer's frames are written as PNG files; `SequenceCamera` reads them with
the same code as `OpenCVCamera`, so the OpenCV capture path runs without a device. The
V4L2 controls a UVC camera has (exposure with its auto mode, gain, white balance
temperature with its auto mode) are emulated beside it, with a UVC driver's rules:
integer values in the driver's units and ranges, a manual value refused while its
automatic runs, no red/blue balance controls. The images do not change with them.
"""
from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from hal.camera import V4L2_EXPOSURE_APERTURE_PRIORITY, V4L2_EXPOSURE_MANUAL, OpenCVCamera
from hal.interfaces import HalError

PATTERN = "frame_%04d.png"


def write_sequence(directory: str | Path, frames: Iterable[np.ndarray]) -> list[Path]:
    """Write RGB (H x W x 3 uint8) or 16-bit single-band frames as PNG files `frame_0000.png`, ..."""
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for i, frame in enumerate(frames):
        f = np.asarray(frame)
        if f.dtype not in (np.uint8, np.uint16) or not (f.ndim == 2 or (f.ndim == 3 and f.shape[2] in (1, 3))):
            raise ValueError(f"frame {i}: PNG holds H x W x 3 or single-band uint8/uint16, got {f.shape} {f.dtype}")
        path = out / (PATTERN % i)
        data = cv2.cvtColor(f, cv2.COLOR_RGB2BGR) if f.ndim == 3 and f.shape[2] == 3 else f
        if not cv2.imwrite(str(path), data):
            raise ValueError(f"cannot write {path}")
        paths.append(path)
    if not paths:
        raise ValueError("no frames to write")
    return paths


@dataclass
class V4L2Controls:
    """The controls of an emulated UVC camera; they outlive an open, as a device's do.

    `honours_lock=False` is a camera that accepts the manual mode and stays in auto.
    `writes` records every (property, value, accepted).
    """

    auto_exposure: int = V4L2_EXPOSURE_APERTURE_PRIORITY
    exposure: int = 156  # 100 µs units, where the auto exposure settled
    gain: int = 0
    auto_white_balance: int = 1
    white_balance_temperature: int = 4600
    honours_lock: bool = True
    writes: list[tuple[int, float, bool]] = field(default_factory=list)

    RANGES = {cv2.CAP_PROP_EXPOSURE: (3, 2047), cv2.CAP_PROP_GAIN: (0, 255),
              cv2.CAP_PROP_WB_TEMPERATURE: (2800, 6500)}

    def get(self, prop: int) -> float | None:
        """The control's value, or None when `prop` is not a control of this camera."""
        values = {cv2.CAP_PROP_AUTO_EXPOSURE: self.auto_exposure, cv2.CAP_PROP_EXPOSURE: self.exposure,
                  cv2.CAP_PROP_GAIN: self.gain, cv2.CAP_PROP_AUTO_WB: self.auto_white_balance,
                  cv2.CAP_PROP_WB_TEMPERATURE: self.white_balance_temperature}
        return None if prop not in values else float(values[prop])

    def set(self, prop: int, value: float) -> bool:
        accepted = self._set(prop, round(value))  # the V4L2 backend rounds to the control's integer
        self.writes.append((prop, value, accepted))
        return accepted

    def _set(self, prop: int, v: int) -> bool:
        if prop == cv2.CAP_PROP_AUTO_EXPOSURE:
            if v not in (V4L2_EXPOSURE_MANUAL, V4L2_EXPOSURE_APERTURE_PRIORITY):
                return False  # a menu entry UVC cameras do not offer
            self.auto_exposure = v if self.honours_lock else V4L2_EXPOSURE_APERTURE_PRIORITY
            return True
        if prop == cv2.CAP_PROP_AUTO_WB:
            self.auto_white_balance = 1 if v or not self.honours_lock else 0
            return v in (0, 1)
        if prop not in self.RANGES:
            return False  # e.g. red and blue balance: UVC cameras rarely have them
        if prop == cv2.CAP_PROP_EXPOSURE and self.auto_exposure != V4L2_EXPOSURE_MANUAL:
            return False  # inactive while the auto exposure runs (uvcvideo answers EACCES)
        if prop == cv2.CAP_PROP_WB_TEMPERATURE and self.auto_white_balance:
            return False
        lo, hi = self.RANGES[prop]
        clamped = min(max(v, lo), hi)  # the driver clamps; only the read-back tells
        if prop == cv2.CAP_PROP_EXPOSURE:
            self.exposure = clamped
        elif prop == cv2.CAP_PROP_GAIN:
            self.gain = clamped
        else:
            self.white_balance_temperature = clamped - clamped % 10  # a 10 K step
        return True


class EmulatedV4L2Capture:
    """A VideoCapture whose camera controls are `controls`; everything else is OpenCV's own."""

    def __init__(self, capture: Any, controls: V4L2Controls) -> None:
        self._capture, self.controls = capture, controls

    def get(self, prop: int) -> float:
        if prop in _CONTROL_PROPS:
            value = self.controls.get(prop)
            return -1.0 if value is None else value  # OpenCV's answer for a control the driver lacks
        return self._capture.get(prop)

    def set(self, prop: int, value: float) -> bool:
        if prop in _CONTROL_PROPS:
            return self.controls.set(prop, value)
        return bool(self._capture.set(prop, value))

    def __getattr__(self, name: str) -> Any:
        return getattr(self._capture, name)


_CONTROL_PROPS = frozenset({cv2.CAP_PROP_AUTO_EXPOSURE, cv2.CAP_PROP_EXPOSURE, cv2.CAP_PROP_GAIN, cv2.CAP_PROP_AUTO_WB,
                            cv2.CAP_PROP_WB_TEMPERATURE, cv2.CAP_PROP_WHITE_BALANCE_RED_V,
                            cv2.CAP_PROP_WHITE_BALANCE_BLUE_U})


class SequenceCamera(OpenCVCamera):
    """Replays `directory/frame_%04d.png` in order, starting over at the end, with emulated
    V4L2 `controls` (a fresh `V4L2Controls` when not given)."""

    def __init__(self, directory: str | Path, retries: int = 3, controls: V4L2Controls | None = None) -> None:
        self.directory = Path(directory)
        if not (self.directory / (PATTERN % 0)).is_file():
            raise HalError(f"image sequence {self.directory}: no {PATTERN % 0}")
        self.length = 0
        while (self.directory / (PATTERN % self.length)).is_file():
            self.length += 1
        self.position = 0
        self.controls = controls if controls is not None else V4L2Controls()
        super().__init__(str(self.directory / PATTERN), cv2.CAP_IMAGES, retries=retries,
                         capture_factory=lambda device, api: EmulatedV4L2Capture(cv2.VideoCapture(device, api),
                                                                                 self.controls))

    def _configure(self, cap: Any, width: int, height: int, fmt: str) -> None:
        # Image files cannot be asked for a size or format: check what the files hold.
        got_w, got_h = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
        if (got_w, got_h) != (width, height):
            raise HalError(f"{self._where()}: asked for {width}x{height}, the images are {got_w}x{got_h}")
        self.size, self.pixel_format, self.stale_buffers = (height, width), fmt, 0  # files never go stale
        self.position = 0

    def _read(self) -> np.ndarray | None:
        if self.position >= self.length:  # end of the sequence: start over
            self._cap.release()
            self._cap = self._factory(self.device, self.api)
            self.position = 0
        self.position += 1
        return super()._read()
