"""The paper's Table 2: how well Johnson and its peers fit each region's histogram.

For every (label, band) the error of a model is the normalized-histogram L1
difference  sum_k |h_k - p_k|  (0 .. 2) between the data's normalized histogram h and
the model's probability p_k of each integer level k, i.e. its mass over
[k - 1/2, k + 1/2] with both tails folded into the end levels (exactly what
rounding and clipping a continuous draw to the sensor's levels gives). Using the
binned probabilities rather than samples keeps the table free of sampling noise.
A deep (16-bit) band is scored over at most 256 equal bins of the levels it occupies
(tools.analysis.level_bins), the models' probabilities taken over the same bins.

Johnson is our robot's percentile fit from the region's histogram. The peers are
scipy.stats maximum-likelihood fits to the dequantized values (each integer spread
uniformly over its level, seeded): normal; uniform; Weibull and lognormal with their
location fixed just below the lowest level's lower edge, so their support covers the data.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy import stats

from btf.fit.fitter import fit_histogram
from btf.johnson import Johnson
from tools.analysis.level_bins import Grid
from tools.analysis.metrics import normalized
from tools.analysis.tiles import Region, label_counts, region, region_histograms

PEERS = ("johnson", "gaussian", "uniform", "weibull", "lognormal")
# MLE fits see at most this many values; enough for a stable fit, bounded time.
FIT_SAMPLE = 20000


@dataclass(frozen=True, slots=True)
class PdfRow:
    label: int
    band: str
    count: int
    errors: dict[str, float]
    failed: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True)
class PdfTable:
    rows: tuple[PdfRow, ...]
    total: dict[str, float]

    def to_json(self) -> dict:
        return {
            "peers": list(PEERS),
            "rows": [{"label": r.label, "band": r.band, "count": r.count, "errors": dict(r.errors),
                      "failed": list(r.failed)} for r in self.rows],
            "total": dict(self.total),
        }


def binned(dist, levels: int, edges: np.ndarray | None = None) -> np.ndarray:
    """Probability of each integer level, or of each bin between `edges` (tails folded in)."""
    inner = np.arange(levels - 1, dtype=np.float64) + 0.5 if edges is None else edges
    c = dist.cdf(inner)
    return np.diff(np.concatenate(([0.0], c, [1.0])))


Values = Callable[[np.ndarray], np.ndarray]  # positions among a region's pixels -> their values


def _peer_probabilities(values: Values, n: int, levels: int, rng: np.random.Generator,
                        edges: np.ndarray | None = None) -> dict[str, np.ndarray]:
    v = values(np.arange(n) if n <= FIT_SAMPLE else rng.choice(n, FIT_SAMPLE, replace=False))
    x = v.astype(np.float64) + rng.uniform(-0.5, 0.5, len(v))
    floor = float(v.min()) - 0.5 - 1e-3
    out: dict[str, np.ndarray] = {}
    with np.errstate(all="ignore"):
        mu, sd = stats.norm.fit(x)
        out["gaussian"] = binned(stats.norm(mu, sd), levels, edges)
        lo, width = stats.uniform.fit(x)
        out["uniform"] = binned(stats.uniform(lo, width), levels, edges)
        c, _, scale = stats.weibull_min.fit(x, floc=floor)
        out["weibull"] = binned(stats.weibull_min(c, floor, scale), levels, edges)
        s, _, scale = stats.lognorm.fit(x, floc=floor)
        out["lognormal"] = binned(stats.lognorm(s, floor, scale), levels, edges)
    return out


def peer_probabilities(values: np.ndarray, levels: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """The peers' binned probabilities fitted to integer `values` (at most FIT_SAMPLE of them, seeded)."""
    return _peer_probabilities(lambda positions: values[positions], len(values), levels, rng)


def gather(bands: np.ndarray, band: int, mask: np.ndarray, where: Region, positions: np.ndarray) -> np.ndarray:
    """The values of band `band` at `positions` (any order) among the region's pixels in
    row-major order, read tile by tile: memory for the positions only."""
    order = np.argsort(positions, kind="stable")
    wanted = positions[order]
    out = np.empty(len(positions), dtype=bands.dtype)
    start = done = 0
    for r in where.tiles:
        vals = bands[r, where.cols, band][mask[r, where.cols] == where.label]
        stop = int(np.searchsorted(wanted, start + len(vals)))
        out[order[done:stop]] = vals[wanted[done:stop] - start]
        start, done = start + len(vals), stop
    return out


def table(bands: np.ndarray, mask: np.ndarray, band_names: tuple[str, ...],
          fit: Callable[[np.ndarray, int], Johnson] | None = None, levels: int = 256,
          seed: int = 0) -> PdfTable:
    """Table 2 for an H x W x B band stack under a label mask. Johnson is the robot's percentile
    fit from each region's histogram, or `fit(values, levels)` when given (which needs the
    region's values gathered). Histograms and samples are read in row tiles (tools.analysis.tiles)."""
    if bands.shape[:2] != mask.shape:
        raise ValueError(f"mask size {mask.shape} differs from the image's {bands.shape[:2]}")
    rng = np.random.default_rng(seed)
    ids = np.array(list(label_counts(mask)), np.int64)
    counts = region_histograms(bands, mask, ids, [levels] * len(band_names))
    grids = [_grid(c, levels) for c in counts]
    rows = []
    for i, label in enumerate(ids):
        where = region(mask, int(label))
        for k, name in enumerate(band_names):
            c, grid = counts[k][i], grids[k]
            deep = grid.bins != levels
            h = normalized(grid.rebin(c) if deep else c)
            if np.count_nonzero(c) == 1:
                # A constant region: every model degenerates to the one level, exactly.
                probs = {p: h for p in PEERS}
            else:
                values = lambda positions, k=k: gather(bands, k, mask, where, positions)  # noqa: E731
                model = (fit_histogram(c).model if fit is None
                         else fit(values(np.arange(where.count)).astype(np.int64), levels))
                edges = grid.edges() if deep else None
                probs = {"johnson": model.interval_probabilities(edges) if deep else model.level_probabilities(levels)}
                probs.update(_peer_probabilities(values, where.count, levels, rng, edges))
            errors, failed = {}, []
            for p in PEERS:
                e = float(np.abs(h - probs[p]).sum())
                if not np.isfinite(e):
                    e, failed = 2.0, failed + [p]  # a failed fit scores the worst possible error
                errors[p] = e
            rows.append(PdfRow(int(label), name, where.count, errors, tuple(failed)))
    total = {p: float(sum(r.errors[p] for r in rows)) for p in PEERS}
    return PdfTable(tuple(rows), total)


def _grid(counts: np.ndarray, levels: int) -> Grid:
    """The band's bins: its levels (8-bit), or equal bins over the levels its pixels occupy."""
    if levels <= 256:
        return Grid.over(0, 0, levels)
    used = np.flatnonzero(counts.sum(axis=0))
    return Grid.over(int(used[0]), int(used[-1]), levels) if used.size else Grid.over(0, 0, 256)
