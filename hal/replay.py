"""A camera that plays image files as its frames: a folder or a glob of PNG, JPEG and TIFF files.

Chosen with `hal.camera = "replay:DIR_OR_GLOB"` under the fake and emulated bodies: the arm
and the tracker stay the body's own, only the frames come from the files. A folder plays
its .png, .jpg, .jpeg, .tif and .tiff files, a glob the files it matches with those endings, in
natural order (frame_2 before frame_10). Each file is read as it is stored: 8 or 16 bits,
colour in RGB order (an alpha channel dropped), one band kept one band (H x W x 1), and a
TIFF's bands as stored (a multi-spectral camera's five or six: `features.space = "raw"`).

Frames are played at their own size, never resized or cropped: `hal.size` must be the first
file's size (the robot refuses to start otherwise), and a later file of another size, or one
that does not decode, is a camera error naming it (the retry plays the next file). After the
last file the camera starts over when it loops, else every capture is `ReplayEnded`, a camera
error: the robot skips the pose with that reason. `last_source`, and the `source` of the
settings it reports after a frame, name the file the frame came from.

The files were taken with whatever settings they were taken with, so the controls change
nothing; the camera grants what it is asked (auto where asked auto), as a device would.
"""
from __future__ import annotations

import dataclasses
import glob
import re
from pathlib import Path

import cv2
import numpy as np

from hal.controls import EXACT, with_lock_check
from hal.image_files import TIFF_SUFFIXES, ImageFileError, opencv_bands, tiff_bands
from hal.interfaces import CameraControls, CameraSettings, DeviceSpent, HalError

SUFFIXES = (".png", ".jpg", ".jpeg") + TIFF_SUFFIXES
STANDING = CameraSettings(10_000.0, 1.0, white_balance_kelvin=5500.0)  # what it reports before any controls


class ReplayEnded(DeviceSpent):
    """Every file was played and the camera does not loop."""


def _natural(path: Path) -> list:
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", str(path))]


def replay_files(spec: str) -> list[Path]:
    """The image files `spec` (a folder, or a glob) names, in natural order; ValueError, one
    line, when it names none."""
    if not spec:
        raise ValueError("replay camera: name a folder or a glob of images, e.g. replay:frames/*.png")
    folder = Path(spec).expanduser()
    if folder.is_dir():
        found = [p for p in folder.iterdir() if p.is_file()]
    elif glob.has_magic(spec):
        found = [Path(p) for p in glob.glob(str(folder)) if Path(p).is_file()]
    else:
        raise ValueError(f"replay camera: {spec} is neither a folder nor a glob that matches files")
    files = sorted((p for p in found if p.suffix.lower() in SUFFIXES), key=_natural)
    if not files:
        raise ValueError(f"replay camera: no PNG, JPEG or TIFF files in {spec}")
    return files


def read_frame(path: Path) -> np.ndarray:
    """The image in `path` as H x W x C: RGB (C = 3), one band (C = 1), or a TIFF's bands as
    stored (a multi-spectral camera's, C of any count), uint8 or uint16; alpha left out."""
    if path.suffix.lower() in TIFF_SUFFIXES:
        try:
            stored, _ = tiff_bands(path)
        except ImageFileError as exc:
            raise HalError(f"replay camera: {exc}") from None
        if stored is not None and stored.size:  # bands as stored, never reordered
            stored = _depth_checked(stored, path)
            return stored if stored.ndim == 3 else stored[..., None]
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None or image.size == 0:
        raise HalError(f"replay camera: cannot read {path} as an image")
    return opencv_bands(_depth_checked(image, path), path)


def _depth_checked(image: np.ndarray, path: Path) -> np.ndarray:
    if image.dtype not in (np.uint8, np.uint16):
        raise HalError(f"replay camera: {path} holds {image.dtype} pixels; frames are 8 or 16 bits")
    return image


class ReplayCamera:
    """Plays `files` in order as frames, starting over after the last one when `loop`."""

    def __init__(self, files: list[Path], loop: bool = False) -> None:
        if not files:
            raise HalError("replay camera: no files to play")
        self.files = list(files)
        self.loop = loop
        first = read_frame(self.files[0])
        self.size: tuple[int, int] = (first.shape[0], first.shape[1])  # (height, width) of every frame
        self.position = 0  # index of the next file
        self.played = 0
        self.last_source: Path | None = None
        self.is_open = False
        self.controls = CameraControls(STANDING.exposure_us, STANDING.gain, STANDING.white_balance_kelvin)

    def open(self, width: int, height: int, pixel_format: str = "BGR3") -> None:
        """Start from the first file; only at the files' own size."""
        if (height, width) != self.size:
            raise HalError(f"replay camera: asked for {width}x{height}, the files are {self.size[1]}x{self.size[0]} "
                           f"(first: {self.files[0]}); set hal.size = [{self.size[0]}, {self.size[1]}]")
        self.position, self.is_open = 0, True

    def capture(self) -> np.ndarray:
        if not self.is_open:
            raise HalError("replay camera: capture before open")
        if self.position >= len(self.files):
            if not self.loop:
                raise ReplayEnded(f"replay camera: all {len(self.files)} files played; "
                                  "hal.replay_loop = true starts them over")
            self.position = 0
        path = self.files[self.position]
        self.position += 1  # a file that fails is passed over by the next try
        frame = read_frame(path)
        if frame.shape[:2] != self.size:
            raise HalError(f"replay camera: {path} is {frame.shape[1]}x{frame.shape[0]}, the frames "
                           f"are {self.size[1]}x{self.size[0]}")
        self.last_source = path
        self.played += 1
        return frame

    def set_controls(self, controls: CameraControls) -> CameraSettings:
        self.controls = controls
        return self.settings()

    def settings(self) -> CameraSettings:
        """The controls as asked (the files do not change with them) and the last frame's file."""
        c = self.controls
        got = dataclasses.replace(
            STANDING,
            exposure_us=STANDING.exposure_us if c.exposure_us is None else c.exposure_us,
            gain=STANDING.gain if c.gain is None else c.gain,
            white_balance_kelvin=(c.white_balance_kelvin if c.white_balance_kelvin is not None
                                  else None if c.white_balance_gains is not None else STANDING.white_balance_kelvin),
            white_balance_gains=c.white_balance_gains,
            auto_exposure=c.exposure_us is None, auto_gain=c.gain is None,
            auto_white_balance=not c.manual_white_balance,
            source=None if self.last_source is None else str(self.last_source))
        return with_lock_check(c, got, EXACT)

    def close(self) -> None:
        self.is_open = False
