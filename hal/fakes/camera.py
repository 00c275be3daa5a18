"""A behavioural camera: renders the scene as seen from the arm's true view, drops frames on request.

It honours camera controls as a real one does: the frame is rendered at the exposure,
analogue gain and white balance it runs with (more exposure: a brighter image that
saturates sooner). What is left on `auto` is chosen by imitations of a camera's
automatics, which meter the view and correct part of the error per frame, so they lag:
auto exposure steers the mean level toward `AE_TARGET_DN`, auto white balance makes the
view grey on average. It boots locked at the renderer's reference (10 ms, gain 1, 5500 K),
so until it is told otherwise its frames are exactly `hal.scene.render`'s.
"""
from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from hal.controls import EXACT, with_lock_check
from hal.fakes import Call, Faults
from hal.interfaces import CameraControls, CameraSettings, HalError, ViewAngles
from hal.scene import SCENES, SceneRadiance, scene_radiance

FORMATS = {"rgb": ("BGR3", "RGB3"), "multispectral": ("MSP6",)}
REFERENCE_EXPOSURE_US = 10_000.0  # the renderer's unit exposure
REFERENCE_KELVIN = 5500.0  # the renderer's colours are daylight-balanced
KELVIN_EXPONENT = 0.8  # a camera set below the light's temperature cuts red and lifts blue
EXPOSURE_RANGE_US = (20.0, 500_000.0)
GAIN_RANGE = (1.0, 16.0)
KELVIN_RANGE = (1500.0, 15_000.0)
AE_TARGET_DN = 110.0  # the mean level auto exposure steers toward
AE_RATE = 0.5  # share of the (log) error one metering step corrects
AE_STEPS_PER_CAPTURE = 3  # metering steps between two captures: the camera streams while the arm settles
AE_WARMUP_STEPS = 30  # before the first capture after open or new controls: a second of streaming
SENSOR_START_C, SENSOR_WARM_C, SENSOR_WARM_FRAMES = 25.0, 15.0, 300.0


def kelvin_gains(kelvin: float) -> tuple[float, float]:
    """(red, blue) gains of a white balance set to `kelvin` under the daylight the scene is lit by."""
    ratio = kelvin / REFERENCE_KELVIN
    return ratio**KELVIN_EXPONENT, ratio**-KELVIN_EXPONENT


def _clamp(value: float, bounds: tuple[float, float]) -> float:
    return min(max(value, bounds[0]), bounds[1])


class FakeCamera:
    """`capture` renders `scene` from `true_view()`; bands "rgb" or "multispectral" as in hal.scene.

    `last_mask` (`true_labels()`, its `hal.GroundTruth` capability) is the scene's true label
    map of the last frame returned (None before the first), so ground-truth segmentation never
    renders the view a second time. `reference`
    lays the grey reference card in the scene. `honours_lock=False` makes a camera whose
    automatics keep running whatever it is told (as some webcams do).
    """

    def __init__(self, scene: str, true_view: Callable[[], ViewAngles], seed: int = 0,
                 size: tuple[int, int] = (480, 640), bands: str = "rgb", faults: Faults | None = None,
                 retries: int = 3, reference: bool = False, honours_lock: bool = True) -> None:
        if scene not in SCENES:
            raise HalError(f"fake camera: unknown scene {scene!r}; choose from {', '.join(SCENES)}")
        if bands not in FORMATS:
            raise HalError(f"fake camera: unknown bands {bands!r}; choose from {', '.join(FORMATS)}")
        self.scene, self.true_view, self.seed, self.bands = scene, true_view, seed, bands
        self.size = (int(size[0]), int(size[1]))
        self.faults = faults or Faults()
        self.retries = retries
        self.reference = reference
        self.honours_lock = honours_lock
        self.history: list[Call] = []
        self.is_open = False
        self.last_mask: np.ndarray | None = None
        self.frames = 0
        self.controls = CameraControls(REFERENCE_EXPOSURE_US, 1.0, REFERENCE_KELVIN)
        self.exposure_us, self.gain, self.white_balance = REFERENCE_EXPOSURE_US, 1.0, (1.0, 1.0)
        self._warmup = AE_WARMUP_STEPS

    def open(self, width: int, height: int, pixel_format: str = "BGR3") -> None:
        if pixel_format not in FORMATS[self.bands]:
            raise HalError(f"fake camera: pixel format {pixel_format!r} does not fit bands {self.bands!r}; "
                           f"use {', '.join(FORMATS[self.bands])}")
        if not (8 <= width <= 8192 and 8 <= height <= 8192):
            raise HalError(f"fake camera: frame size {width}x{height} outside 8..8192")
        self.size = (height, width)
        self.is_open = True
        self._warmup = AE_WARMUP_STEPS
        self.history.append(Call("open", (width, height, pixel_format), "ok"))

    # -- controls -------------------------------------------------------------------
    def _auto(self) -> tuple[bool, bool, bool]:
        c, ignore = self.controls, not self.honours_lock
        return ignore or c.exposure_us is None, ignore or c.gain is None, ignore or not c.manual_white_balance

    def set_controls(self, controls: CameraControls) -> CameraSettings:
        self.controls = controls
        self._warmup = AE_WARMUP_STEPS
        auto_exposure, auto_gain, auto_wb = self._auto()
        if not auto_exposure:
            self.exposure_us = _clamp(float(controls.exposure_us), EXPOSURE_RANGE_US)
        if not auto_gain:
            self.gain = _clamp(float(controls.gain), GAIN_RANGE)
        if not auto_wb:
            self.white_balance = (controls.white_balance_gains if controls.white_balance_gains is not None
                                  else kelvin_gains(_clamp(float(controls.white_balance_kelvin), KELVIN_RANGE)))
        self.history.append(Call("set_controls", (controls,), "ok"))
        return self.settings()

    def settings(self) -> CameraSettings:
        auto_exposure, auto_gain, auto_wb = self._auto()
        c = self.controls
        kelvin = (c.white_balance_kelvin if not auto_wb and c.white_balance_kelvin is not None
                  else REFERENCE_KELVIN * float(self.white_balance[0]) ** (1.0 / KELVIN_EXPONENT))
        got = CameraSettings(self.exposure_us, self.gain, white_balance_kelvin=kelvin,
                             white_balance_gains=self.white_balance,
                             sensor_temperature_c=SENSOR_START_C + SENSOR_WARM_C * (1.0 - math.exp(
                                 -self.frames / SENSOR_WARM_FRAMES)),
                             auto_exposure=auto_exposure, auto_gain=auto_gain, auto_white_balance=auto_wb)
        return with_lock_check(c, got, EXACT)

    def _run_automatics(self, light: SceneRadiance) -> None:
        """Metering steps of auto exposure and auto white balance on this view, each correcting
        `AE_RATE` of the remaining (log) error: a lagging, not an instant, normalisation."""
        auto_exposure, auto_gain, auto_wb = self._auto()
        if not (auto_exposure or auto_gain or auto_wb):
            return
        red, blue = (0, 2) if self.bands == "rgb" else (2, 0)
        steps, self._warmup = max(AE_STEPS_PER_CAPTURE, self._warmup), 0
        for _ in range(steps):
            means = light.metered_mean(self.exposure_us / REFERENCE_EXPOSURE_US, self.gain, self.white_balance)
            if auto_wb:
                wanted = (means[1] / max(means[red], 0.5), means[1] / max(means[blue], 0.5))
                self.white_balance = tuple(  # type: ignore[assignment]
                    _clamp(float(g * w**AE_RATE), (0.25, 4.0)) for g, w in zip(self.white_balance, wanted))
            if auto_exposure or auto_gain:
                total = self.exposure_us * self.gain * (AE_TARGET_DN / max(float(means[:5].mean()), 0.5)) ** AE_RATE
                if auto_exposure:
                    self.exposure_us = _clamp(total / (GAIN_RANGE[0] if auto_gain else self.gain), EXPOSURE_RANGE_US)
                if auto_gain:
                    self.gain = _clamp(total / self.exposure_us, GAIN_RANGE)

    # -- frames ---------------------------------------------------------------------
    def capture(self) -> np.ndarray:
        if not self.is_open:
            raise HalError("fake camera: capture before open")
        for _ in range(self.retries + 1):
            if self.faults.hit("drop"):
                self.history.append(Call("capture", (), "drop"))
                continue
            view = self.true_view()
            light = scene_radiance(self.scene, view, size=self.size, seed=self.seed, bands=self.bands,
                                   reference=self.reference)
            self._run_automatics(light)
            rendered = light.expose(self.exposure_us / REFERENCE_EXPOSURE_US, self.gain, self.white_balance)
            self.frames += 1
            self.history.append(Call("capture", (view,), "ok"))
            self.last_mask = rendered.mask
            return rendered.image
        raise HalError(f"fake camera: no frame after {self.retries + 1} tries (frames dropped)")

    def true_labels(self) -> np.ndarray | None:
        """The `hal.GroundTruth` capability: the true label map of the last frame returned."""
        return self.last_mask

    def close(self) -> None:
        self.is_open = False
        self.history.append(Call("close", (), "ok"))
