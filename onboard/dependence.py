"""Cross-band and spatial dependence of a region, measured in the models' normal scores.

Every fitted model maps its band to a standard normal deviate z. Per region this module
measures, in one bounded pass over a deterministic lattice of anchor pixels:

  corr  the correlation matrix of the bands' z (a Gaussian copula), upper triangle;
  dx    the autocorrelation of z at horizontal lags LAGS (band average);
  dy    the same at vertical lags.

One spatial autocorrelation serves all bands of a region (space x band separable), so
synthesis mixes identically filtered fields and keeps both the copula and the grain.

Integer pixels carry the conditional mean of z within their level,
E[Z | t_{k-1} < Z <= t_k] = (phi(t_{k-1}) - phi(t_k)) / (Phi(t_k) - Phi(t_{k-1})), so a level's
z is unbiased for the model, and correlations are Pearson (normalised by the sample
spread). Quantization then shrinks a correlation by sqrt(v1 v2), v the variance of the
conditional means, which is above 0.99 once a band spreads over two or more levels.

Memory is fixed: a table of levels per (label, band), accumulators per label, and at most
`chunk` anchors gathered at a time; the frame itself is only indexed.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from onboard.johnson import Family, Johnson, Z_CLIP, normal_cdf

LAGS = (1, 2, 4, 8)
MAX_ANCHORS = 65536
MIN_PAIRS = 32  # fewer pairs than this: the correlation is reported as 0 (independent)
_LUT_MAX_LEVELS = 4096
_MAX_LAG = max(LAGS)


@dataclass(frozen=True, slots=True)
class Dependence:
    """One region's dependence: band copula (upper triangle, row-major) and z autocorrelation."""

    corr: tuple[float, ...]
    dx: tuple[float, ...]
    dy: tuple[float, ...]

    def __post_init__(self) -> None:
        for name in ("corr", "dx", "dy"):
            values = getattr(self, name)
            if not all(math.isfinite(v) and -1.0 <= v <= 1.0 for v in values):
                raise ValueError(f"dependence {name} values must lie in [-1, 1], got {values}")
        if len(self.dx) != len(LAGS) or len(self.dy) != len(LAGS):
            raise ValueError(f"dependence needs {len(LAGS)} lags per direction")
        bands_of(len(self.corr))  # a triangle of some band count

    @property
    def n_bands(self) -> int:
        return bands_of(len(self.corr))

    def matrix(self) -> np.ndarray:
        """The full B x B correlation matrix."""
        b = self.n_bands
        m = np.eye(b)
        iu = np.triu_indices(b, 1)
        m[iu] = self.corr
        m[(iu[1], iu[0])] = self.corr
        return m

    @classmethod
    def independent(cls, n_bands: int) -> Dependence:
        return cls((0.0,) * corr_size(n_bands), (0.0,) * len(LAGS), (0.0,) * len(LAGS))


def corr_size(n_bands: int) -> int:
    if n_bands < 1:
        raise ValueError(f"need at least one band, got {n_bands}")
    return n_bands * (n_bands - 1) // 2


def bands_of(n_corr: int) -> int:
    b = (1 + math.isqrt(1 + 8 * n_corr)) // 2
    if corr_size(b) != n_corr:
        raise ValueError(f"{n_corr} correlations are not the upper triangle of a square matrix")
    return b


def level_z(model: Johnson, levels: int) -> np.ndarray:
    """Conditional mean of z within each integer level k (mass over [k - 1/2, k + 1/2])."""
    if model.family is Family.CONST:
        return np.zeros(levels)
    t = model.thresholds(levels)
    lo = np.concatenate(([-Z_CLIP], t))
    hi = np.concatenate((t, [Z_CLIP]))
    p = np.diff(normal_cdf(np.concatenate(([-Z_CLIP], t, [Z_CLIP]))))
    phi = lambda z: np.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)  # noqa: E731
    with np.errstate(all="ignore"):
        m = (phi(lo) - phi(hi)) / p
    # A level the model gives (almost) no mass: its conditional mean is its nearer edge.
    edge = np.where(np.abs(lo) < np.abs(hi), lo, hi)
    m = np.where(p > 1e-12, m, edge)
    return np.clip(np.nan_to_num(m, nan=0.0), lo, hi)


def _anchor_step(h: int, w: int, max_anchors: int) -> int:
    return max(1, math.ceil(math.sqrt(h * w / max_anchors)))


def measure(
    data: np.ndarray, labels: np.ndarray, models: Mapping[tuple[int, int], Johnson],
    levels: int = 256, max_anchors: int = MAX_ANCHORS, chunk: int = 8192,
) -> dict[int, Dependence]:
    """Dependence of every label that has a model for each band of `data` (H x W x B ints)."""
    if data.ndim == 2:
        data = data[..., None]
    if data.ndim != 3 or labels.shape != data.shape[:2]:
        raise ValueError(f"data {data.shape} and labels {labels.shape} do not match")
    h, w, n_bands = data.shape
    if max_anchors < 1 or chunk < 1:
        raise ValueError("max_anchors and chunk must be positive")
    regions = sorted({lab for lab, _ in models if all((lab, b) in models for b in range(n_bands))})
    if not regions:
        return {}
    index = np.full(max(int(labels.max(initial=0)), max(regions)) + 1, -1, dtype=np.int64)
    index[regions] = np.arange(len(regions))
    n_reg = len(regions)
    direct = levels > _LUT_MAX_LEVELS or not np.issubdtype(data.dtype, np.integer)
    lut = None if direct else np.stack([
        np.stack([level_z(models[(lab, b)], levels) for b in range(n_bands)]) for lab in regions
    ])  # (regions, bands, levels)
    live = np.array([[models[(lab, b)].family is not Family.CONST for b in range(n_bands)]
                     for lab in regions])

    def z_at(rr: np.ndarray, cc: np.ndarray, li: np.ndarray) -> np.ndarray:
        pix = data[rr, cc]  # (n, B)
        if lut is not None:
            k = np.clip(pix.astype(np.int64), 0, levels - 1)
            return lut[li[:, None], np.arange(n_bands)[None, :], k]
        out = np.empty(pix.shape)
        for j, lab in enumerate(regions):
            sel = li == j
            for b in range(n_bands):
                out[sel, b] = models[(lab, b)].z_of_x(pix[sel, b].astype(np.float64))
        return out

    # Accumulators: anchors (n, sum z, sum z z') and pairs per direction and lag.
    n0 = np.zeros(n_reg)
    s1 = np.zeros((n_reg, n_bands))
    s2 = np.zeros((n_reg, n_bands, n_bands))
    npair = np.zeros((2, len(LAGS), n_reg))
    ps = np.zeros((2, len(LAGS), 5, n_reg, n_bands))  # sum a, sum b, sum a^2, sum b^2, sum ab

    step = _anchor_step(h, w, max_anchors)
    rows, cols = np.arange(0, h, step), np.arange(0, w, step)
    per = max(1, chunk // max(1, len(cols)))
    for start in range(0, len(rows), per):
        rr, cc = np.meshgrid(rows[start:start + per], cols, indexing="ij")
        rr, cc = rr.ravel(), cc.ravel()
        li = index[labels[rr, cc]]
        ok = li >= 0
        rr, cc, li = rr[ok], cc[ok], li[ok]
        if not rr.size:
            continue
        za = z_at(rr, cc, li)
        n0 += np.bincount(li, minlength=n_reg)
        s1 += _sum_by(li, za, n_reg)
        s2 += _sum_by(li, za[:, :, None] * za[:, None, :], n_reg)
        for d, (dr, dc) in enumerate(((0, 1), (1, 0))):
            for k, lag in enumerate(LAGS):
                r2, c2 = rr + dr * lag, cc + dc * lag
                inside = (r2 < h) & (c2 < w)
                sel = np.flatnonzero(inside)
                sel = sel[index[labels[r2[sel], c2[sel]]] == li[sel]]
                if not sel.size:
                    continue
                a, lk = za[sel], li[sel]
                b = z_at(r2[sel], c2[sel], lk)
                npair[d, k] += np.bincount(lk, minlength=n_reg)
                for q, v in enumerate((a, b, a * a, b * b, a * b)):
                    ps[d, k, q] += _sum_by(lk, v, n_reg)

    out = {}
    for j, lab in enumerate(regions):
        corr = _pearson_matrix(n0[j], s1[j], s2[j])
        iu = np.triu_indices(n_bands, 1)
        spatial = []
        for d in range(2):
            per_lag = []
            for k in range(len(LAGS)):
                r = _pearson_pairs(npair[d, k, j], ps[d, k, :, j, :])
                use = live[j]
                per_lag.append(float(np.mean(r[use])) if use.any() else 0.0)
            spatial.append(tuple(_clip1(v) for v in per_lag))
        out[lab] = Dependence(tuple(_clip1(v) for v in corr[iu]), spatial[0], spatial[1])
    return out


def _sum_by(index: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    flat = values.reshape(len(index), -1)
    return np.stack([np.bincount(index, flat[:, i], minlength=n) for i in range(flat.shape[1])],
                    axis=1).reshape((n,) + values.shape[1:])


def _pearson_matrix(n: float, s1: np.ndarray, s2: np.ndarray) -> np.ndarray:
    b = len(s1)
    if n < MIN_PAIRS:
        return np.eye(b)
    mean = s1 / n
    cov = s2 / n - np.outer(mean, mean)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    with np.errstate(all="ignore"):
        r = cov / np.outer(sd, sd)
    r = np.where(np.outer(sd, sd) > 1e-9, r, 0.0)
    np.fill_diagonal(r, 1.0)
    return np.clip(np.nan_to_num(r, nan=0.0), -1.0, 1.0)


def _pearson_pairs(n: float, s: np.ndarray) -> np.ndarray:
    """Per band correlation of pair sets from (sum a, sum b, sum a^2, sum b^2, sum ab)."""
    if n < MIN_PAIRS:
        return np.zeros(s.shape[1])
    ma, mb = s[0] / n, s[1] / n
    va, vb = s[2] / n - ma * ma, s[3] / n - mb * mb
    cov = s[4] / n - ma * mb
    den = np.sqrt(np.maximum(va, 0.0) * np.maximum(vb, 0.0))
    with np.errstate(all="ignore"):
        r = np.where(den > 1e-9, cov / den, 0.0)
    return np.clip(np.nan_to_num(r, nan=0.0), -1.0, 1.0)


def _clip1(v: float) -> float:
    return float(min(1.0, max(-1.0, v)))
