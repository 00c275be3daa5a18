"""One body's devices together: what `hal.factory.build_hal` builds and the runtime turns."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

from hal.arm import Arm
from hal.interfaces import Body, Camera, GroundTruth, OrientationTracker, ServoBus


@dataclass(frozen=True)
class Hal:
    """Every device of the robot, built for one body by `hal.factory.build_hal`; `close()`
    releases them all. `ground_truth` is None except on the fake body."""

    body: Body
    servo_bus: ServoBus
    arm: Arm
    tracker: OrientationTracker
    camera: Camera
    size: tuple[int, int]
    _cleanup: tuple[Callable[[], None], ...] = field(default=(), repr=False)
    ground_truth: GroundTruth | None = None
    pixel_format: str = "BGR3"  # what `open_camera` asks the camera for

    def open_camera(self) -> None:
        """Open the camera at the configured size and pixel format."""
        self.camera.open(self.size[1], self.size[0], self.pixel_format)

    def close(self) -> None:
        for closer in (self.camera.close, self.tracker.close, self.servo_bus.close, *self._cleanup):
            try:
                closer()
            except Exception:  # noqa: BLE001 - closing must release everything it can
                pass
