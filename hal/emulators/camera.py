"""A camera source through OpenCV itself: an image sequence replayed by VideoCapture(CAP_IMAGES).

The scene renderer's frames are written as PNG files; `SequenceCamera` reads them with
the same code as `OpenCVCamera`, so the OpenCV capture path runs without a device.
"""
from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from hal.camera import OpenCVCamera
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


class SequenceCamera(OpenCVCamera):
    """Replays `directory/frame_%04d.png` in order, starting over at the end."""

    def __init__(self, directory: str | Path, retries: int = 3) -> None:
        self.directory = Path(directory)
        if not (self.directory / (PATTERN % 0)).is_file():
            raise HalError(f"image sequence {self.directory}: no {PATTERN % 0}")
        self.length = 0
        while (self.directory / (PATTERN % self.length)).is_file():
            self.length += 1
        self.position = 0
        super().__init__(str(self.directory / PATTERN), cv2.CAP_IMAGES, retries=retries)

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
