"""Cross-band and spatial dependence of a region, measured on board in fixed memory.

Per region, in one bounded pass over a deterministic lattice of anchor pixels:

  corr  the correlation matrix of the bands' pixel values, upper triangle;
  dx    the autocorrelation of the pixels at horizontal lags LAGS (band average);
  dy    the same at vertical lags.

These are plain Pearson correlations of the pixels, what an image comparison measures.
The host turns them into the correlations of the models' normal scores z that reproduce
them through the Johnson quantile functions (a Gaussian copula fitted by moment matching,
`tools.analysis.fields.latent`), so the robot needs no table of z per level and quantization needs
no correction: the pixels are what they are. One spatial autocorrelation serves all bands
of a region (space x band separable), so synthesis mixes identically filtered fields.

Memory is fixed: accumulators per label and at most `chunk` anchors gathered at a time;
the frame itself is only indexed.
"""
from __future__ import annotations

import math
from typing import Mapping

import numpy as np

from btf.dependence import LAGS, Dependence
from btf.johnson import Family, Johnson

MAX_ANCHORS = 65536
MIN_PAIRS = 32  # fewer pairs than this: the correlation is reported as 0 (independent)
_MAX_LAG = max(LAGS)


def _anchor_step(h: int, w: int, max_anchors: int) -> int:
    return max(1, math.ceil(math.sqrt(h * w / max_anchors)))


def measure(
    data: np.ndarray, labels: np.ndarray, models: Mapping[tuple[int, int], Johnson],
    levels: int = 256, max_anchors: int = MAX_ANCHORS, chunk: int = 8192,
) -> dict[int, Dependence]:
    """Dependence of every label that has a model for each band of `data` (H x W x B pixels).
    `levels` is accepted for symmetry with the fitter; pixel correlations do not need it."""
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
    live = np.array([[models[(lab, b)].family is not Family.CONST for b in range(n_bands)]
                     for lab in regions])

    def pixels_at(rr: np.ndarray, cc: np.ndarray, li: np.ndarray) -> np.ndarray:
        return data[rr, cc].astype(np.float64)  # (n, B)

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
        za = pixels_at(rr, cc, li)
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
                b = pixels_at(r2[sel], c2[sel], lk)
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
