"""Skip what a scene does not need: each rule is a small pure function the capture calls.

- labels absent or under `min_pixels` are neither fitted nor sent (`kept_labels`);
- bands not asked for are never computed (`feature_bands`: the feature spec names them);
- large regions are fitted from a deterministic pixel stride sized so that every kept
  region still has enough pixels for the target percentile precision (`subsample_stride`);
- a capture whose percentiles all moved less than a tolerance since the previous
  capture at the same pose is sent as an UNCHANGED marker (`unchanged`);
- a pose already measured in this sweep is not measured again (see `onboard.sweep.plan`).
"""
from __future__ import annotations

import math
from typing import Mapping, Protocol, Sequence

import numpy as np

from hal.interfaces import ViewAngles


class HasPercentiles(Protocol):
    percentiles: tuple[float, float, float, float]


def label_counts(labels: np.ndarray, n_labels: int) -> np.ndarray:
    """Pixels per label id (0..n_labels-1); ids at or above n_labels are ignored."""
    flat = labels.reshape(-1)
    counts = np.zeros(max(n_labels, 256), np.int64)
    for a in range(0, flat.size, 1 << 16):  # bounded chunks: bincount widens to int64
        counts += np.bincount(flat[a:a + (1 << 16)], minlength=counts.size)[:counts.size]
    return counts[:n_labels]


def kept_labels(counts: np.ndarray, min_pixels: int) -> tuple[int, ...]:
    """Label ids with at least `min_pixels` pixels: the only ones fitted and sent."""
    return tuple(int(i) for i in np.flatnonzero(counts >= max(1, min_pixels)))


def pixels_for_precision(precision: float) -> int:
    """Pixels needed so a percentile's probability has standard error <= `precision`.

    The sample quantile's probability has standard error sqrt(p(1-p)/n); p = 1/2 is the
    worst case, so n = 1 / (4 precision^2).
    """
    if not 0.0 < precision < 0.5:
        raise ValueError(f"percentile precision must lie in (0, 0.5), got {precision}")
    return int(math.ceil(0.25 / (precision * precision)))


def subsample_stride(counts: np.ndarray, keep: Sequence[int], precision: float, width: int = 1) -> int:
    """A pixel stride (1 = every pixel) leaving each kept region >= the needed pixels.

    A stride is deterministic (same frame, same pixels) and costs nothing to apply;
    0 precision turns the rule off. Over a row-major frame `width` pixels wide the
    stride is kept coprime with the width, so the lattice visits every column instead
    of a few (a stride of exactly the width would sample one column).
    """
    if precision <= 0.0 or not keep:
        return 1
    needed = pixels_for_precision(precision)
    smallest = int(min(counts[k] for k in keep))
    stride = max(1, smallest // needed)
    while math.gcd(stride, width) > 1:  # smaller, so still >= the needed pixels
        stride -= 1
    return stride


def unchanged(
    previous: Mapping[tuple[int, int], HasPercentiles] | None,
    current: Mapping[tuple[int, int], HasPercentiles],
    tolerance: float,
) -> bool:
    """True when both captures hold the same (label, band) models and every percentile
    moved by at most `tolerance` data units (0 turns the rule off)."""
    if tolerance <= 0.0 or not previous or set(previous) != set(current):
        return False
    for key, result in current.items():
        old = np.asarray(previous[key].percentiles, dtype=np.float64)
        new = np.asarray(result.percentiles, dtype=np.float64)
        if not np.all(np.abs(new - old) <= tolerance):
            return False
    return True


def pose_key(view: ViewAngles, resolution_deg: float = 1.0) -> tuple[int, int]:
    """A commanded pose rounded to a grid, so captures 'at the same pose' can be paired."""
    r = max(resolution_deg, 1e-6)
    return int(round(view.elevation / r)), int(round((view.azimuth % 360.0) / r))
