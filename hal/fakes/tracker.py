"""A behavioural orientation tracker: the arm's true view plus bias and noise, with NACKs."""
from __future__ import annotations

import random
from collections.abc import Callable

from hal.fakes import Call, Faults
from hal.interfaces import Calibration, HalError, Orientation, ViewAngles


class FakeTracker:
    """Reports the true view as a BNO055 on the camera would (pitch = -elevation)."""

    def __init__(self, true_view: Callable[[], ViewAngles], noise_deg: float = 0.3, bias_deg: float = 0.5,
                 faults: Faults | None = None, seed: int = 0, retries: int = 3) -> None:
        if noise_deg < 0:
            raise ValueError(f"noise_deg must be >= 0, got {noise_deg}")
        self.true_view = true_view
        self.noise_deg = noise_deg
        self.bias_deg = bias_deg
        self.faults = faults or Faults()
        self.retries = retries
        self.history: list[Call] = []
        self._rng = random.Random(seed)

    def _answer(self, call: str) -> None:
        """Raise HalError when every try NACKs, as the real driver does after its retries."""
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
        o = Orientation(heading=(view.azimuth + self.bias_deg + self._noise()) % 360.0,
                        roll=self._noise(),
                        pitch=-(view.elevation + self.bias_deg + self._noise()))
        self.history.append(Call("orientation", (view,), "ok"))
        return o

    def calibration(self) -> Calibration:
        self._answer("calibration")
        self.history.append(Call("calibration", (), "ok"))
        return Calibration(3, 3, 3, 3)

    def close(self) -> None:
        self.history.append(Call("close", (), "ok"))
