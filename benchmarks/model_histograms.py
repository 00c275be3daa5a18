"""Histograms of known models, and how far a model lies from a histogram: the yardsticks of the
fit's benchmarks and tests (not part of the robot).

`saturating` moves a model so that a given fraction of it lies beyond a sensor limit;
`expected_histogram` gives the noise-free level counts of a model as a clipping sensor records
them; `histogram_l1` is the exact L1 between a model's level probabilities and a histogram.
"""
from __future__ import annotations

import numpy as np

from btf.johnson import Family, Johnson


def histogram_l1(model: Johnson, counts: np.ndarray, lo: float = 0.0, bin_width: float = 1.0) -> float:
    """Sum over bins of |P_model(bin) - count / total| (bin k centred on lo + k * bin_width, the
    end bins holding the tails, as a clipping sensor does). Only the occupied bins and the empty
    runs between them are evaluated: the same sum as over every bin, cheaper for deep sensors."""
    return l1_on_grid(model, l1_grid(counts, lo, bin_width))


def l1_grid(counts: np.ndarray, lo: float = 0.0, bin_width: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """(edges, observed probabilities) that histogram_l1 compares a model on; built once when
    several models are compared on one histogram."""
    c = np.asarray(counts)
    bins = c.size
    occ = np.flatnonzero(c)
    # edge k separates bins k - 1 and k; the outer edges 0 and bins are the sensor's limits
    mark = np.zeros(bins + 1, dtype=bool)
    mark[occ] = True
    mark[occ + 1] = True
    mark[0] = mark[bins] = False
    k = np.flatnonzero(mark)
    # each interval starts at bin 0 or an edge; an occupied bin is an interval of its own
    starts = np.concatenate(([0], k))
    return lo + (k - 0.5) * bin_width, c[starts].astype(np.float64) / float(c.sum())


def l1_on_grid(model: Johnson, grid: tuple[np.ndarray, np.ndarray]) -> float:
    """histogram_l1 of `model` on a grid from l1_grid."""
    edges, h = grid
    return float(np.abs(model.interval_probabilities(edges) - h).sum())


def saturating(model: Johnson, high: float = 0.0, low: float = 0.0, levels: int = 256) -> Johnson:
    """`model` translated (and, with both ends, scaled) so that `high` of its mass lies above
    levels - 3/2 (read as the top level) and `low` below 1/2 (the bottom level). With one end
    the other keeps the model's own width; with neither, the model is returned unchanged."""
    if not (0.0 <= low < 1.0 and 0.0 <= high < 1.0 and low + high < 1.0):
        raise ValueError(f"need 0 <= low, high and low + high < 1, got {low}, {high}")
    if model.family is Family.CONST:
        raise ValueError("a constant model cannot be made to saturate")
    top, bottom = levels - 1.5, 0.5
    if low > 0.0 and high > 0.0:
        xa, xe = float(model.ppf(low)), float(model.ppf(1.0 - high))
        scale = (top - bottom) / (xe - xa)
        return _affine(model, scale, bottom - scale * xa)
    if high > 0.0:
        return _affine(model, 1.0, top - float(model.ppf(1.0 - high)))
    if low > 0.0:
        return _affine(model, 1.0, bottom - float(model.ppf(low)))
    return model


def _affine(m: Johnson, scale: float, offset: float) -> Johnson:
    """The model of scale * X + offset (scale > 0)."""
    if m.family is Family.SN:
        return Johnson.normal(m.xi * scale + offset, m.lam * scale)
    return Johnson(m.family, m.gamma, m.delta, m.xi * scale + offset, m.lam * scale)


def expected_histogram(model: Johnson, count: int, levels: int = 256) -> np.ndarray:
    """Integer counts summing to `count`: the model's level probabilities, tails folded into the
    end levels as a clipping sensor does (largest remainders get the leftover pixels)."""
    p = model.level_probabilities(levels) * count
    base = np.floor(p).astype(np.int64)
    short = count - int(base.sum())
    if short > 0:
        base[np.argsort(base - p, kind="stable")[:short]] += 1
    return base
