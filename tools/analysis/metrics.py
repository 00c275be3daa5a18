"""The paper's image-quality metrics, and a few distances it did not use.

All histogram metrics work on normalized histograms over the band's integer
levels (0 .. levels-1), so they are exact for integer pixels:
- hist_diff: sum |h_ref - h_test|, in [0, 2] (the paper's "normalized histogram difference");
- chi2: symmetric chi-squared sum (h_ref - h_test)^2 / (h_ref + h_test) over non-empty bins, in [0, 2];
- ks: Kolmogorov-Smirnov, max |F_ref - F_test|, in [0, 1];
- w1: Wasserstein-1 in levels, sum |F_ref - F_test| (bins are one level wide).
A deep (16-bit) band takes hist_diff and chi2 over at most 256 equal bins of the levels the two
images occupy (tools.analysis.level_bins: per level they would count noise); KS and W1 stay per level.
A circular band (hue) has no first bin: its KS and W1 are minimised over where
the circle is cut, and its correlation is the circular correlation coefficient.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from tools.analysis.level_bins import Grid
from tools.analysis.tiles import label_counts, region_histograms, row_tiles

METRICS = ("hist_diff", "chi2", "ks", "w1")


@dataclass(frozen=True, slots=True)
class RegionMetrics:
    label: int
    band: str
    count_ref: int
    count_test: int
    hist_diff: float
    chi2: float
    ks: float
    w1: float


@dataclass(frozen=True, slots=True)
class Comparison:
    band_names: tuple[str, ...]
    correlation: dict[str, float]
    regions: tuple[RegionMetrics, ...]
    total: dict[str, float]

    def to_json(self) -> dict:
        return {
            "bands": list(self.band_names),
            "correlation": dict(self.correlation),
            "regions": [asdict(r) for r in self.regions],
            "total": dict(self.total),
        }


def histogram(values: np.ndarray, levels: int) -> np.ndarray:
    """Normalized histogram of integer values over 0..levels-1 (all zeros for no values)."""
    v = np.asarray(values).ravel()
    if v.size and (v.min() < 0 or v.max() >= levels):
        raise ValueError(f"values outside 0..{levels - 1}")
    return normalized(np.bincount(v.astype(np.int64), minlength=levels))


def normalized(counts: np.ndarray) -> np.ndarray:
    counts = counts.astype(np.float64)
    total = counts.sum()
    return counts / total if total > 0 else counts


def hist_diff(h_ref: np.ndarray, h_test: np.ndarray) -> float:
    return float(np.abs(h_ref - h_test).sum())


def chi2(h_ref: np.ndarray, h_test: np.ndarray) -> float:
    s = h_ref + h_test
    nz = s > 0
    return float(((h_ref[nz] - h_test[nz]) ** 2 / s[nz]).sum())


def ks(h_ref: np.ndarray, h_test: np.ndarray, circular: bool = False) -> float:
    d = np.cumsum(h_ref) - np.cumsum(h_test)
    if not circular:
        return float(np.abs(d).max())
    # Cutting the circle after bin k shifts every CDF difference by d[k].
    return float(np.min(np.abs(d[None, :] - d[:, None]).max(axis=1)))


def w1(h_ref: np.ndarray, h_test: np.ndarray, circular: bool = False) -> float:
    """Wasserstein-1 in levels: the area between the CDFs (scipy.stats.wasserstein_distance's
    figure; its import alone took 1.5 s of each `compare`)."""
    if h_ref.sum() == 0 or h_test.sum() == 0:
        return 0.0
    d = np.cumsum(h_ref / h_ref.sum()) - np.cumsum(h_test / h_test.sum())
    if not circular:
        return float(np.abs(d).sum())
    # Circular W1 = min over cuts c of sum |d - c|; any median of d is optimal, and the
    # upper median is one of d's values, i.e. a real cut point.
    c = np.sort(d)[len(d) // 2]
    return float(np.abs(d - c).sum())


def correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Pearson correlation; 1.0 for two identical constant inputs, 0.0 when either is constant otherwise."""
    x = np.asarray(a, dtype=np.float64).ravel()
    y = np.asarray(b, dtype=np.float64).ravel()
    if x.size < 2:
        return 1.0 if np.array_equal(x, y) else 0.0
    x = x - x.mean()
    y = y - y.mean()
    den = np.sqrt((x * x).sum() * (y * y).sum())
    if den == 0 or not np.isfinite(den):
        return 1.0 if np.array_equal(np.asarray(a).ravel(), np.asarray(b).ravel()) else 0.0
    return float(np.clip((x * y).sum() / den, -1.0, 1.0))


def circular_mean(theta: np.ndarray) -> float:
    """The mean direction of angles in radians (scipy.stats.circmean's, up to a turn)."""
    return float(np.arctan2(np.sin(theta).mean(), np.cos(theta).mean()))


def circular_correlation(a: np.ndarray, b: np.ndarray, levels: int) -> float:
    """Jammalamadaka's circular correlation of two angle arrays given in 0..levels-1 units."""
    ta = np.asarray(a, dtype=np.float64).ravel() * (2 * np.pi / levels)
    tb = np.asarray(b, dtype=np.float64).ravel() * (2 * np.pi / levels)
    if ta.size == 0:
        return 1.0 if tb.size == 0 else 0.0
    sa = np.sin(ta - circular_mean(ta))
    sb = np.sin(tb - circular_mean(tb))
    den = np.sqrt((sa * sa).sum() * (sb * sb).sum())
    if den == 0 or not np.isfinite(den):
        return 1.0 if np.array_equal(ta, tb) else 0.0
    return float(np.clip((sa * sb).sum() / den, -1.0, 1.0))


class _Correlation:
    """Pearson's (or the circular) correlation of two bands fed tile by tile in two passes:
    means first, then centred sums, as the whole-array functions above compute them."""

    def __init__(self, circular_levels: int | None) -> None:
        self.levels = circular_levels
        self.n = 0
        self.first = np.zeros(4)  # sums of x, y (or sin, cos of each angle)
        self.second = np.zeros(3)  # centred sums of x*y, x*x, y*y
        self.equal = True

    def _prepare(self, a: np.ndarray) -> np.ndarray:
        x = np.asarray(a, dtype=np.float64).ravel()
        return x if self.levels is None else x * (2 * np.pi / self.levels)

    def add_first(self, a: np.ndarray, b: np.ndarray) -> None:
        x, y = self._prepare(a), self._prepare(b)
        self.n += x.size
        if self.levels is None:
            self.first[:2] += x.sum(), y.sum()
        else:
            self.first += np.sin(x).sum(), np.cos(x).sum(), np.sin(y).sum(), np.cos(y).sum()
        self.equal = self.equal and np.array_equal(a, b)

    def add_second(self, a: np.ndarray, b: np.ndarray) -> None:
        x, y = self._prepare(a), self._prepare(b)
        if self.levels is None:
            x -= self.first[0] / self.n
            y -= self.first[1] / self.n
        else:
            x = np.sin(x - np.arctan2(self.first[0], self.first[1]))
            y = np.sin(y - np.arctan2(self.first[2], self.first[3]))
        self.second += (x * y).sum(), (x * x).sum(), (y * y).sum()

    def value(self) -> float:
        if self.n < 2:
            return 1.0 if self.equal else 0.0
        den = np.sqrt(self.second[1] * self.second[2])
        if den == 0 or not np.isfinite(den):
            return 1.0 if self.equal else 0.0
        return float(np.clip(self.second[0] / den, -1.0, 1.0))


def compare_bands(
    ref: np.ndarray,
    test: np.ndarray,
    band_names: tuple[str, ...],
    levels: int = 256,
    mask: np.ndarray | None = None,
    circular: tuple[str, ...] = (),
    circular_levels: int = 180,
    tile_pixels: int | None = None,
) -> Comparison:
    """Metrics between two H x W x B band stacks; regions come from `mask` (all label 0 without).
    Works through row tiles of `tile_pixels` (default tools.analysis.tiles.TILE_PIXELS): memory beyond
    the inputs stays a few tiles."""
    if ref.shape != test.shape:
        raise ValueError(f"images differ in size: {ref.shape} and {test.shape}")
    if ref.ndim != 3 or ref.shape[2] != len(band_names):
        raise ValueError(f"expected H x W x {len(band_names)} bands, got {ref.shape}")
    if mask is not None and mask.shape != ref.shape[:2]:
        raise ValueError(f"mask size {mask.shape} differs from the images' {ref.shape[:2]}")
    blocks = row_tiles(ref.shape[0], ref.shape[1], tile_pixels)
    ids = np.zeros(1, np.int64) if mask is None else np.array(list(label_counts(mask, tile_pixels)), np.int64)
    nlevs = [circular_levels if name in circular else levels for name in band_names]
    counts = [region_histograms(side, mask, ids, nlevs, tile_pixels) for side in (ref, test)]
    corrs = [_Correlation(circular_levels if name in circular else None) for name in band_names]
    for step in ("add_first", "add_second"):
        for r in blocks:
            for k, c in enumerate(corrs):
                getattr(c, step)(ref[r, :, k], test[r, :, k])
    regions: list[RegionMetrics] = []
    for k, name in enumerate(band_names):
        circ = name in circular
        grid = (Grid.over(0, 0, nlevs[k]) if nlevs[k] <= 256 else
                Grid.over(min(ref[..., k].min(), test[..., k].min()), max(ref[..., k].max(), test[..., k].max()),
                          nlevs[k]))
        for i, label in enumerate(ids):
            hr, ht = (normalized(side[k][i]) for side in counts)
            br, bt = (hr, ht) if grid.bins == nlevs[k] else (grid.rebin(hr), grid.rebin(ht))
            n = int(counts[0][k][i].sum())
            regions.append(RegionMetrics(
                int(label), name, n, n, hist_diff(br, bt), chi2(br, bt), ks(hr, ht, circ), w1(hr, ht, circ),
            ))
    total = {m: float(sum(getattr(r, m) for r in regions)) for m in METRICS}
    corr = {name: c.value() for name, c in zip(band_names, corrs)}
    return Comparison(tuple(band_names), corr, tuple(regions), total)
