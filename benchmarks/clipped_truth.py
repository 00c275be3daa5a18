"""Yardsticks of bracketing's test and benchmark: a fake view in bright sun, its unclipped
truth, and how far a region's models miss the quantiles the clipping hid.

A fake camera clips its levels at 255; the scene renderer knows the light before the clip, so
the truth of a saturated region is its radiance at the exposure, unclipped (`unclipped`).
"""
from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from btf.johnson import Johnson
from hal.factory import build_hal
from hal.interfaces import ViewAngles
from hal.scene import scene_radiance
from onboard import config
from onboard.capture.pipeline import FittedView, Pipeline
from onboard.capture.segmentation import Segmentation
from tools.analysis.radiometry import adjusted

TOP_PROBABILITY = 0.995  # hidden quantiles up to here (beyond, a few hundred pixels decide)
SATURATION = 254.5  # a level rounds to 255 above this
PROBABILITY_STEP = 0.0025


def unclipped(scene: str, view: ViewAngles, size: tuple[int, int], exposure_us: float) -> tuple[np.ndarray, np.ndarray]:
    """(levels before the clip H x W x 3, mask) of a fake view at `exposure_us` (gain 1, 5500 K)."""
    light = scene_radiance(scene, view, size=size, seed=0)
    return light.radiance * 255.0 * (exposure_us / 10_000.0), light.mask


def exposure_saturating(scene: str, view: ViewAngles, size: tuple[int, int], label: int, band: int,
                        share: float) -> float:
    """The exposure (µs) at which `share` of region `label`'s band `band` saturates."""
    levels, mask = unclipped(scene, view, size, 10_000.0)
    return 10_000.0 * SATURATION / float(np.quantile(levels[mask == label][:, band], 1.0 - share))


def hidden_error(models: dict[tuple[int, int], Johnson], truth: np.ndarray, mask: np.ndarray,
                 label: int) -> float:
    """Mean |model quantile - true quantile| (levels) over the probability mass the clip hid,
    the region's bands pooled: probabilities every PROBABILITY_STEP from a band's share below
    the clip to TOP_PROBABILITY, so each band weighs by how much of it clipped. 0 when nothing
    of the region clips."""
    errors = []
    for band in range(truth.shape[2]):
        values = truth[mask == label][:, band]
        below = float(np.mean(values < SATURATION))
        if below >= TOP_PROBABILITY:
            continue
        probs = np.arange(below, TOP_PROBABILITY, PROBABILITY_STEP)
        errors.append(np.abs(models[(label, band)].ppf(probs) - np.quantile(values, probs)))
    return float(np.mean(np.concatenate(errors))) if errors else 0.0


def robot_pipeline(scene: str, size: tuple[int, int], exposure_us: float, bracket_limit: float,
                   reference: bool = False) -> Pipeline:
    """The robot's pipeline on the fake HAL (the arm straight down, torque on) with the camera
    locked at `exposure_us`; `reference` lays the grey card and records its level."""
    d = Path(tempfile.mkdtemp(prefix="btf-bracket-"))
    (d / "robot.toml").write_text(
        f'[hal]\nbody = "fake"\nscene = "{scene}"\nsize = [{size[0]}, {size[1]}]\nreference = {str(reference).lower()}\n'
        f'[segment]\nmethod = "scene"\n[camera]\nexposure = {exposure_us!r}\ngain = 1\nwhite_balance = "5500K"\n'
        f'bracket_limit = {bracket_limit!r}\nreference_label = {7 if reference else -1}\n')
    cfg = config.load(d / "robot.toml")
    hal = build_hal(cfg.hal)
    hal.camera.open(size[1], size[0])
    hal.arm.enable()
    pipe = Pipeline(cfg, hal, Segmentation(cfg, hal))
    pipe.lock_camera()
    return pipe


def host_models(cap: FittedView) -> dict[tuple[int, int], Johnson]:
    """A capture's models as the host synthesizes them: every region at the capture's exposure."""
    return dict(adjusted({k: r.model for k, r in cap.results.items()}, cap.camera))
