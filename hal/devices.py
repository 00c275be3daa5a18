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

    def close(self) -> None:
        for closer in (self.camera.close, self.tracker.close, self.servo_bus.close, *self._cleanup):
            try:
                closer()
            except Exception:  # noqa: BLE001 - closing must release everything it can
                pass
