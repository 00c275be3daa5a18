"""A behavioural camera: renders the scene as seen from the arm's true view, drops frames on request."""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

from hal.fakes import Call, Faults
from hal.interfaces import HalError, ViewAngles
from hal.scene import SCENES, render

FORMATS = {"rgb": ("BGR3", "RGB3"), "multispectral": ("MSP6",)}


class FakeCamera:
    """`capture` renders `scene` from `true_view()`; bands "rgb" or "multispectral" as in hal.scene.

    `last_mask` is the scene's true label map of the last frame returned (None before the
    first), so ground-truth segmentation never renders the view a second time.
    """

    def __init__(self, scene: str, true_view: Callable[[], ViewAngles], seed: int = 0,
                 size: tuple[int, int] = (480, 640), bands: str = "rgb", faults: Faults | None = None,
                 retries: int = 3) -> None:
        if scene not in SCENES:
            raise HalError(f"fake camera: unknown scene {scene!r}; choose from {', '.join(SCENES)}")
        if bands not in FORMATS:
            raise HalError(f"fake camera: unknown bands {bands!r}; choose from {', '.join(FORMATS)}")
        self.scene, self.true_view, self.seed, self.bands = scene, true_view, seed, bands
        self.size = (int(size[0]), int(size[1]))
        self.faults = faults or Faults()
        self.retries = retries
        self.history: list[Call] = []
        self.is_open = False
        self.last_mask: np.ndarray | None = None

    def open(self, width: int, height: int, pixel_format: str = "BGR3") -> None:
        if pixel_format not in FORMATS[self.bands]:
            raise HalError(f"fake camera: pixel format {pixel_format!r} does not fit bands {self.bands!r}; "
                           f"use {', '.join(FORMATS[self.bands])}")
        if not (8 <= width <= 8192 and 8 <= height <= 8192):
            raise HalError(f"fake camera: frame size {width}x{height} outside 8..8192")
        self.size = (height, width)
        self.is_open = True
        self.history.append(Call("open", (width, height, pixel_format), "ok"))

    def capture(self) -> np.ndarray:
        if not self.is_open:
            raise HalError("fake camera: capture before open")
        for _ in range(self.retries + 1):
            if self.faults.hit("drop"):
                self.history.append(Call("capture", (), "drop"))
                continue
            view = self.true_view()
            rendered = render(self.scene, view, size=self.size, seed=self.seed, bands=self.bands)
            self.history.append(Call("capture", (view,), "ok"))
            self.last_mask = rendered.mask
            return rendered.image
        raise HalError(f"fake camera: no frame after {self.retries + 1} tries (frames dropped)")

    def close(self) -> None:
        self.is_open = False
        self.history.append(Call("close", (), "ok"))
