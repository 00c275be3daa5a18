"""The camera's controls from `[camera]`, applied, judged before every capture, and recorded.

A BTF is the change of appearance with the view: a camera left to its automatics flattens
it. So the robot locks exposure, gain and white balance (at the configured values, or
`hold`: where the camera stands when the robot starts) and refuses to measure when the
device does not hold the lock, unless `allow_auto = true`; such captures are flagged. Each
capture carries the settings the device reported for it (`btf.capture_settings`).
"""
from __future__ import annotations

import numpy as np

from btf.capture_settings import CaptureSettings, bounded_source
from hal.controls import describe
from hal.interfaces import Camera, CameraControls, CameraSettings, HalError
from onboard.config import CameraConfig
from radio.packets.camera import held_by_wire

REFERENCE_CLIPPED_WARN = 0.01  # a reference with more of its pixels at a limit understates the light


def reference_level(data: np.ndarray, labels: np.ndarray, label: int,
                    levels: int) -> tuple[tuple[float, ...], float] | None:
    """(mean level per band, share of its pixels at a sensor limit) of region `label`; None when absent."""
    where = labels == label
    n = int(np.count_nonzero(where))
    if n == 0:
        return None
    values = data[where]  # (n, bands)
    means = tuple(float(v) for v in values.mean(axis=0, dtype=np.float64))
    at_limit = np.any((values <= 0) | (values >= levels - 1), axis=1)
    return means, float(np.count_nonzero(at_limit)) / n


class CameraLock:
    """Applies `[camera]` to one camera and says, per capture, whether it may measure."""

    def __init__(self, camera: Camera, cfg: CameraConfig) -> None:
        self.camera = camera
        self.applied = cfg  # the [camera] last asked of the device (the configuration in force is the runtime's)
        self.standing: CameraSettings | None = None  # before the first lock: what `hold` keeps
        self.asked: CameraControls | None = None
        self.granted: CameraSettings | None = None

    def apply(self, cfg: CameraConfig) -> CameraSettings:
        """Ask the camera for `cfg`'s controls; what it granted (read back)."""
        if self.standing is None:
            self.standing = self.camera.settings()
        self.asked = cfg.controls(self.standing)
        self.applied = cfg
        self.granted = self.camera.set_controls(self.asked)
        return self.granted

    def set_exposure(self, exposure_us: float) -> CameraSettings:
        """The same controls at another exposure (bracketing, calibration); what was granted."""
        asked = self.asked or self.applied.controls(self.standing)
        self.granted = self.camera.set_controls(CameraControls(exposure_us, asked.gain, asked.white_balance_kelvin,
                                                               asked.white_balance_gains))
        return self.granted

    def restore(self) -> None:
        """Back to the configured controls after a bracket; if the camera refuses now, the
        next capture applies them again (with its retries) before it takes a frame."""
        if self.asked is None:
            return
        try:
            self.granted = self.camera.set_controls(self.asked)
        except (HalError, OSError, ValueError):
            self.asked = None

    def refusal(self, now: CameraSettings | None = None) -> str:
        """Why a capture must not be kept with these settings ("" when it may)."""
        s = now or self.granted
        if s is None or s.locked or self.applied.allow_auto:
            return ""
        return (f"camera does not hold its lock ({describe(s)}); set [camera] controls the device honours, "
                "or camera.allow_auto = true to measure anyway (captures are then flagged)")

    def record(self, now: CameraSettings) -> CaptureSettings:
        """The capture's settings as the device reported them, flagged when it was not locked."""
        gains_asked = self.asked is not None and self.asked.white_balance_gains is not None
        kelvin = None if gains_asked and now.white_balance_gains is not None else now.white_balance_kelvin
        return held_by_wire(CaptureSettings(
            exposure_us=now.exposure_us, gain=now.gain, white_balance_kelvin=kelvin,
            white_balance_gains=None if kelvin is not None else now.white_balance_gains,
            sensor_temperature_c=now.sensor_temperature_c, unlocked=not now.locked,
            source=None if now.source is None else bounded_source(now.source)))
