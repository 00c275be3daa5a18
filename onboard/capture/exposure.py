"""`btf-robot calibrate exposure`: one exposure for a whole sweep, chosen before it starts.

A sweep keeps one exposure, so that only the view changes between captures; it must be short
enough for the brightest view of the plan and no shorter. The plan's extremes are measured
(its first and last elevation at each azimuth), not every pose: at each, frames are taken,
halving the exposure while more than `SATURATED_OK` of the pixels sit at the top (a clipped
frame hides how bright the view is); the top of an unclipped frame (the 99.9th percentile of
each pixel's brightest band) per microsecond of exposure is the view's brightness. The chosen
exposure puts the brightest view's top at (1 - margin) of full scale. Levels are linear in
exposure, so nothing else needs measuring. The result is kept in the state dir
(`camera_exposure.json`), which `btf-robot run` applies over `[camera] exposure`.
"""
from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from hal.interfaces import ViewAngles
from hal.state_file import read_state, write_state
from onboard.sweep.plan import SweepPlan

SATURATED_OK = 0.001  # share of pixels at the top that still lets the top be read
TOP_PROBABILITY = 0.999
MAX_HALVINGS = 12
EXPOSURE_FILE = "camera_exposure.json"


@dataclass(frozen=True, slots=True)
class ViewReading:
    """One frame at one of the plan's extremes."""

    elevation: float
    azimuth: float
    exposure_us: float
    saturated: float  # share of pixels with a band at the top
    top: float  # the TOP_PROBABILITY level of each pixel's brightest band


@dataclass(frozen=True, slots=True)
class ExposureReport:
    exposure_us: float  # chosen (0 when no view could be read)
    margin: float
    levels: int
    brightest: ViewAngles | None
    readings: tuple[ViewReading, ...] = field(default=())
    problem: str = ""  # why no exposure could be chosen ("" when one was)

    @property
    def ok(self) -> bool:
        return not self.problem


def plan_extremes(plan: SweepPlan) -> list[ViewAngles]:
    """The first and last pose of the plan at each azimuth (each once)."""
    per = plan.count // len(plan.azimuths)
    views: list[ViewAngles] = []
    for a in range(len(plan.azimuths)):
        for i in (a * per, a * per + per - 1):
            v = plan.pose(i)
            if v not in views:
                views.append(v)
    return views


def read_frame(frame: np.ndarray) -> tuple[float, float, int]:
    """(saturated share, top level, levels) of a frame (uint8 or uint16, H x W [x B])."""
    levels = 256 if frame.dtype == np.uint8 else 65536
    brightest = frame if frame.ndim == 2 else frame.max(axis=2)
    saturated = float(np.count_nonzero(brightest >= levels - 1)) / brightest.size
    return saturated, float(np.quantile(brightest, TOP_PROBABILITY)), levels


def calibrate_exposure(views: list[ViewAngles], move: Callable[[ViewAngles], None],
                       shoot: Callable[[float], tuple[np.ndarray, float]], start_us: float, margin: float,
                       shortest_us: float = 1.0) -> ExposureReport:
    """Measure `views` (moving to each) and choose the exposure. `shoot(exposure_us)` sets the
    exposure, takes a frame and returns it with the exposure the camera reports."""
    readings: list[ViewReading] = []
    rates: list[tuple[float, ViewAngles]] = []
    exposure, levels, clipped = start_us, 256, []
    for view in views:
        move(view)
        for _ in range(MAX_HALVINGS + 1):
            frame, got = shoot(exposure)
            saturated, top, levels = read_frame(frame)
            readings.append(ViewReading(view.elevation, view.azimuth, got, saturated, top))
            if saturated <= SATURATED_OK or exposure <= shortest_us:
                break
            exposure = max(shortest_us, exposure / 2.0)
        if saturated > SATURATED_OK:
            clipped.append(view)
        elif got > 0:
            rates.append((top / got, view))
    if clipped:
        return ExposureReport(0.0, margin, levels, clipped[0], tuple(readings),
                              f"{len(clipped)} view(s) still clip at the shortest exposure tried "
                              f"({exposure:g} us): the scene is too bright for this camera setting")
    rate, brightest = max(rates, key=lambda r: r[0], default=(0.0, None))
    if not rate > 0:
        return ExposureReport(0.0, margin, levels, None, tuple(readings), "every view is black: no light to expose for")
    chosen = (1.0 - margin) * (levels - 1) / rate
    return ExposureReport(chosen, margin, levels, brightest, tuple(readings))


def save_exposure(state_dir: str | Path, report: ExposureReport, granted_us: float) -> Path:
    """Write the chosen exposure (as the camera granted it) to `state_dir/camera_exposure.json`."""
    path = Path(state_dir) / EXPOSURE_FILE
    doc = {"version": 1, "exposure_us": granted_us, "chosen_us": report.exposure_us, "margin": report.margin,
           "time": time.time(), "brightest": None if report.brightest is None else asdict(report.brightest),
           "readings": [asdict(r) for r in report.readings]}
    return write_state(path, doc)


def load_exposure(state_dir: str | Path) -> float | None:
    """The stored exposure in µs, None when never calibrated; ValueError naming the file when damaged."""
    path = Path(state_dir) / EXPOSURE_FILE
    try:
        raw = read_state(path)
        if raw is None:
            return None
        value = float(raw["exposure_us"])
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise ValueError(f"{path}: not a stored exposure ({exc}); run 'btf-robot calibrate exposure' again") from None
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{path}: exposure {value!r} is not a positive number of microseconds")
    return value
