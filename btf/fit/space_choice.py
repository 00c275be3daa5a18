"""Which feature space to fit a scene in: the criterion robot and host share (numpy only).

The paper's step (4) selects the feature space "with the goal of de-correlating bands". For
each candidate space of a frame under its label mask:

table2         the paper's Table-2 error of an independent draw: the mean over regions and
               bands of the normalized histogram difference sum_k |h_k - s_k| (0..2) between
               the photograph's region histogram h and that of as many pixels drawn from the
               region's fitted Johnson model s; drawn at two seeds (a deep band is scored over
               at most 256 equal bins of the levels the region occupies)
decorrelation  the largest |Pearson correlation| between two bands within one region (regions
               of at least MIN_PIXELS pixels; 0 for one band); hue is treated as linear

The choice: a space is admissible when its Table-2 error (mean of the two seeds) is no worse
than RGB's by more than RGB's own difference between the two seeds (the noise of the figure).
Among admissible spaces the one whose bands correlate least wins, but RGB is kept unless the
winner lowers the band correlation by at least MARGIN. Gray is never chosen for a colour
frame (it drops the colour); a one-band frame has only gray.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from btf.johnson import Johnson

MIN_PIXELS = 256  # regions smaller than this do not count towards the band correlation
MARGIN = 0.05  # the band correlation another space must save before RGB is given up
SCORED_BINS = 256  # a deep band's Table-2 error is taken over at most this many bins
BASELINE = "rgb"
EXTRA_KEY = "space_auto"  # the MODELS extra in which a robot says why it chose its space


@dataclass(frozen=True)
class SpaceFigures:
    space: str
    table2: tuple[float, float]  # Table-2 error of an independent draw at seed and seed + 1
    decorrelation: float
    bands: int

    @property
    def error(self) -> float:
        return (self.table2[0] + self.table2[1]) / 2

    @property
    def noise(self) -> float:
        return abs(self.table2[0] - self.table2[1])


@dataclass(frozen=True)
class Choice:
    space: str
    reason: str
    admissible: tuple[str, ...]


def _scored(levels_of_counts: np.ndarray, levels: int) -> tuple[np.ndarray, int, int, int]:
    """(histogram over the scored bins, lo, span, bins): every level for 8-bit bands, else at
    most SCORED_BINS equal bins over the region's occupied levels."""
    used = np.flatnonzero(levels_of_counts)
    lo, hi = (int(used[0]), int(used[-1])) if used.size else (0, 0)
    if levels <= SCORED_BINS:
        return levels_of_counts.astype(np.float64), 0, levels, levels
    span = hi - lo + 1
    bins = min(SCORED_BINS, span)
    index = (np.arange(span) * bins) // span
    return np.bincount(index, levels_of_counts[lo:hi + 1], bins), lo, span, bins


def draw_error(counts: np.ndarray, model: Johnson, levels: int, rng: np.random.Generator) -> float:
    """Normalized histogram difference between a region's level counts and as many pixels drawn
    independently from its model (the paper's Table-2 measure on one region and band)."""
    n = int(counts.sum())
    if n == 0:
        return 0.0
    h, lo, span, bins = _scored(counts, levels)
    drawn = model.sample_pixels(n, rng, levels).astype(np.int64)
    if levels > SCORED_BINS:
        drawn = (np.clip(drawn - lo, 0, span - 1) * bins) // span
    s = np.bincount(drawn, minlength=bins)[:bins]
    return float(np.abs(h / n - s / n).sum())


def table2_error(counts: np.ndarray, models: Mapping[tuple[int, int], Johnson], levels: int, seed: int) -> float:
    """Mean draw_error over every fitted (label, band); counts is labels x bands x levels."""
    rng = np.random.default_rng(seed)
    errors = [draw_error(counts[lab, band], models[(lab, band)], levels, rng) for lab, band in sorted(models)]
    return float(np.mean(errors)) if errors else 0.0


def decorrelation(bands: np.ndarray, labels: np.ndarray) -> float:
    """The largest |correlation| between two bands of an H x W x B stack within one region."""
    b = bands.shape[2]
    if b < 2:
        return 0.0
    lab = labels.ravel().astype(np.intp)
    n = np.bincount(lab)
    x = bands.reshape(-1, b).astype(np.float64)
    sums = [np.bincount(lab, x[:, i], len(n)) for i in range(b)]
    worst = 0.0
    keep = n >= MIN_PIXELS
    if not keep.any():
        return 0.0
    moments = {}
    for i in range(b):
        for j in range(i, b):
            moments[i, j] = np.bincount(lab, x[:, i] * x[:, j], len(n))
    with np.errstate(all="ignore"):
        for i in range(b):
            for j in range(i + 1, b):
                m = n[keep]
                cov = moments[i, j][keep] / m - sums[i][keep] * sums[j][keep] / m ** 2
                vi = moments[i, i][keep] / m - (sums[i][keep] / m) ** 2
                vj = moments[j, j][keep] / m - (sums[j][keep] / m) ** 2
                r = np.where((vi > 1e-9) & (vj > 1e-9), cov / np.sqrt(np.maximum(vi * vj, 1e-300)), 0.0)
                worst = max(worst, float(np.abs(np.nan_to_num(r)).max()))
    return min(worst, 1.0)


def figures(space: str, bands: np.ndarray, labels: np.ndarray, counts: np.ndarray,
            models: Mapping[tuple[int, int], Johnson], levels: int, seed: int = 0) -> SpaceFigures:
    """One space's figures from its bands, the mask, the fitter's counts and its models."""
    t2 = (table2_error(counts, models, levels, seed), table2_error(counts, models, levels, seed + 1))
    return SpaceFigures(space, t2, decorrelation(bands, labels), bands.shape[2])


def choose(candidates: list[SpaceFigures]) -> Choice:
    """The space to fit in, by the criterion above, and the reason in one line."""
    if not candidates:
        raise ValueError("no feature spaces to choose from")
    colour = [f for f in candidates if f.bands > 1]
    if not colour:
        f = candidates[0]
        return Choice(f.space, f"{f.space}: the photograph has one band", (f.space,))
    base = next((f for f in colour if f.space == BASELINE), colour[0])
    bound = base.error + base.noise
    admissible = [f for f in colour if f.error <= bound]
    best = min(admissible, key=lambda f: (f.decorrelation, f.space != base.space))
    if best is base or best.decorrelation > base.decorrelation - MARGIN:
        others = ", ".join(f"{f.space} {f.decorrelation:.2f} at error {f.error:.4f}" for f in colour if f is not base)
        return Choice(base.space, f"{base.space}: no other space lowers the band correlation within regions "
                      f"({base.decorrelation:.2f}) by {MARGIN} at a Table-2 error within {base.space}'s "
                      f"{base.error:.4f} + seed noise {base.noise:.4f}" + (f" ({others})" if others else ""),
                      tuple(f.space for f in admissible))
    return Choice(best.space, f"{best.space}: its bands correlate at most {best.decorrelation:.2f} within a "
                  f"region against {base.space}'s {base.decorrelation:.2f}, at a Table-2 error of {best.error:.4f} "
                  f"against {base.space}'s {base.error:.4f} (seed noise {base.noise:.4f})",
                  tuple(f.space for f in admissible))
