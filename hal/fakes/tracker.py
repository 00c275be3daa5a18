"""A behavioural orientation tracker: the arm's true view plus bias and noise, with NACKs.

It can be mounted wrongly on the camera (`mount`, a rotation from hal.orientation.MOUNTS)
and be given an axis remap (hal.bno055.AxisRemap) as the BNO055 is: it then reports what
a chip so mounted and remapped would. `unplug()` takes it off the bus (every read raises
DeviceGone, as the driver does for a chip answering EIO) until `replug()`.
"""
from __future__ import annotations

import random
from collections.abc import Callable

import numpy as np

from hal.bno055 import AxisRemap
from hal.fakes import Call, Faults
from hal.interfaces import Calibration, DeviceGone, HalError, Orientation, ViewAngles
from hal.orientation import camera_frame, euler_angles


class FakeTracker:
    """Reports the true view as a BNO055 on the camera would (pitch = -elevation)."""

    def __init__(self, true_view: Callable[[], ViewAngles], noise_deg: float = 0.3, bias_deg: float = 0.5,
                 faults: Faults | None = None, seed: int = 0, retries: int = 3, mount: np.ndarray | None = None,
                 remap: AxisRemap | None = None) -> None:
        if noise_deg < 0:
            raise ValueError(f"noise_deg must be >= 0, got {noise_deg}")
        self.true_view = true_view
        self.noise_deg = noise_deg
        self.bias_deg = bias_deg
        self.faults = faults or Faults()
        self.retries = retries
        self.history: list[Call] = []
        self._rng = random.Random(seed)
        self.mount = None if mount is None else np.asarray(mount, float)
        self.remap = remap or AxisRemap()
        self.unplugged = False

    def unplug(self) -> None:
        """Off the bus: every read raises DeviceGone until `replug`."""
        self.unplugged = True

    def replug(self) -> None:
        self.unplugged = False

    def _answer(self, call: str) -> None:
        """Raise HalError when every try NACKs, as the real driver does after its retries."""
        if self.unplugged:
            self.history.append(Call(call, (), "gone"))
            raise DeviceGone("fake tracker: no answer on the I2C bus (EIO): unplugged")
        for _ in range(self.retries + 1):
            if not self.faults.hit("nack"):
                return
            self.history.append(Call(call, (), "nack"))
        raise HalError(f"fake tracker: no answer after {self.retries + 1} tries (NACK)")

    def _noise(self) -> float:
        return self._rng.gauss(0.0, self.noise_deg) if self.noise_deg > 0 else 0.0

    def orientation(self) -> Orientation:
        self._answer("orientation")
        view = self.true_view()
        if self.mount is None and self.remap == AxisRemap():
            o = Orientation(heading=(view.azimuth + self.bias_deg + self._noise()) % 360.0,
                            roll=self._noise(),
                            pitch=-(view.elevation + self.bias_deg + self._noise()))
        else:
            mount = np.eye(3) if self.mount is None else self.mount
            chip = euler_angles(camera_frame(view) @ mount @ self.remap.matrix.T)
            o = Orientation(heading=(chip.heading + self.bias_deg + self._noise()) % 360.0,
                            roll=chip.roll + self._noise(),
                            pitch=chip.pitch - self.bias_deg + self._noise())
        self.history.append(Call("orientation", (view,), "ok"))
        return o

    def calibration(self) -> Calibration:
        self._answer("calibration")
        self.history.append(Call("calibration", (), "ok"))
        return Calibration(3, 3, 3, 3)

    def close(self) -> None:
        self.history.append(Call("close", (), "ok"))
