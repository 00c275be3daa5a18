"""A band's marginal as synthesis draws it: a map from a standard normal z to a pixel level,
kept within the levels the region took.

The Johnson curve F is restricted to [lo - 1/2, hi + 1/2] (the region's observed levels) and
renormalised, G(x) = (F(x) - F(lo - 1/2)) / (F(hi + 1/2) - F(lo - 1/2)), so no pixel is ever
drawn outside them. A side is truncated only where it lies strictly inside the sensor's range:
at level 0 or the top level the sensor itself clipped, and the curve's mass beyond piles onto
that level as it did in the photograph. A curve with no mass inside [lo, hi] is drawn clipped
to the sensor's levels instead. In z the map is a step function, level lo + k for z in
(t_(k-1), t_k] with t_k = Phi^-1(G(lo + k + 1/2)), so

- independent pixels come from a 2**16-entry table indexed by uniform 16-bit draws;
- correlated fields go through one table over z (`z_table`): the level at the centre of each of
  2**16 bins (2**20 for deeper sensors) in [-Z_SPAN, Z_SPAN];
- its Hermite coefficients are closed form, E[level(Z) He_n(Z)] = sum_k phi(t_k) He_(n-1)(t_k),
  so the Pearson correlation of level_a(Z1), level_b(Z2) when corr(Z1, Z2) = rho is a power
  series in rho (`pixel_corr`) that includes the rounding and the truncation.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from scipy.special import ndtr, ndtri

from btf.johnson import Family, Johnson

Z_SPAN = 8.5  # thresholds beyond +-Z_SPAN carry < 1e-17 of the mass
UNIFORM_BITS = 16
HERMITE_TERMS = 160


@dataclass(frozen=True, eq=False)
class LevelMap:
    """z -> level for one band of one region."""

    lo: int
    hi: int
    thresholds: np.ndarray = field(repr=False)  # float64, increasing, hi - lo of them
    probs: np.ndarray = field(repr=False)  # probability of each level lo..hi
    mean: float
    sd: float
    hermite: np.ndarray = field(repr=False)  # c_n / sd for n = 1..HERMITE_TERMS

    @property
    def dtype(self) -> type:
        return np.uint8 if self.hi < 256 else np.uint16

    def levels_of(self, z: np.ndarray) -> np.ndarray:
        """Exact levels of any z (searchsorted; the tables' reference)."""
        return (self.lo + np.searchsorted(self.thresholds, np.asarray(z, np.float64), side="left")).astype(self.dtype)


def truncates(lo: int, hi: int, levels: int) -> tuple[bool, bool]:
    """Which sides a region's observed levels cut: only those strictly inside the sensor's."""
    return lo > 0, hi < levels - 1


@lru_cache(maxsize=1024)
def level_map(model: Johnson, levels: int, lo: int = 0, hi: int | None = None) -> LevelMap:
    """The map of `model` over the observed levels lo..hi (default: all the sensor's levels,
    the curve clipped to them)."""
    hi = levels - 1 if hi is None else hi
    if not 0 <= lo <= hi < levels:
        raise ValueError(f"observed levels {lo}..{hi} outside 0..{levels - 1}")
    if model.family is Family.CONST:
        level = int(min(max(round(model.xi), lo), hi))
        t = np.where(np.arange(lo, hi) < level, -Z_SPAN, Z_SPAN).astype(np.float64)
        return _finish(lo, hi, t)
    cut_lo, cut_hi = truncates(lo, hi, levels)
    z_lo = float(model.z_of_x(lo - 0.5)) if cut_lo else -np.inf
    z_hi = float(model.z_of_x(hi + 0.5)) if cut_hi else np.inf
    zk = model.z_of_x(np.arange(lo, hi, dtype=np.float64) + 0.5)  # upper edges of levels lo..hi-1
    below = ndtr(zk) - ndtr(z_lo)  # G's numerator from below
    above = ndtr(-zk) - ndtr(-z_hi)  # 1 - G's numerator from above: no cancellation in the tail
    total = ndtr(z_hi) - ndtr(z_lo) if z_lo < 0 else ndtr(-z_lo) - ndtr(-z_hi)
    if not total > 1e-300:  # no mass inside the observed levels: the clipped curve
        return level_map(model, levels) if (lo, hi) != (0, levels - 1) else _finish(lo, hi, zk)
    with np.errstate(all="ignore"):
        t = np.where(below <= above, ndtri(np.clip(below / total, 0, 1)), -ndtri(np.clip(above / total, 0, 1)))
    return _finish(lo, hi, np.nan_to_num(t, nan=0.0))


def _finish(lo: int, hi: int, t: np.ndarray) -> LevelMap:
    t = np.maximum.accumulate(np.clip(t, -Z_SPAN, Z_SPAN))
    probs = np.diff(np.concatenate(([0.0], ndtr(t), [1.0])))
    lv = np.arange(lo, hi + 1, dtype=np.float64)
    mean = float(probs @ lv)
    sd = float(np.sqrt(max(float(probs @ (lv - mean) ** 2), 0.0)))
    for a in (t, probs):
        a.flags.writeable = False
    return LevelMap(lo, hi, t, probs, mean, sd, _hermite(t, sd))


def _hermite(t: np.ndarray, sd: float) -> np.ndarray:
    """c_n / sd for n = 1..HERMITE_TERMS, c_n = E[level(Z) h_n(Z)] with the orthonormal
    h_n = He_n / sqrt(n!): c_n = sum_k phi(t_k) h_(n-1)(t_k) / sqrt(n)."""
    out = np.zeros(HERMITE_TERMS)
    inner = np.abs(t) < Z_SPAN  # thresholds at the span's ends carry no mass
    t = t[inner]
    if sd <= 0 or not t.size:
        return out
    phi = np.exp(-0.5 * t * t) / np.sqrt(2 * np.pi)
    h_prev, h = np.zeros_like(t), np.ones_like(t)
    for n in range(1, HERMITE_TERMS + 1):
        out[n - 1] = float(phi @ h) / np.sqrt(n)
        h_prev, h = h, (t * h - np.sqrt(n - 1) * h_prev) / np.sqrt(n)
    return out / sd


def pixel_corr(a: LevelMap, b: LevelMap, rho: np.ndarray, same: bool = False) -> np.ndarray:
    """Pearson correlation of level_a(Z1), level_b(Z2) when corr(Z1, Z2) = rho (any array).
    `same` (a band with itself): the series' missing mass goes to the next power, so rho = 1
    gives 1."""
    rho = np.asarray(rho, dtype=np.float64)
    c = a.hermite * b.hermite
    out = np.zeros_like(rho)
    if not c.any():
        return out
    for cn in c[::-1]:  # Horner: sum_n c_n rho^n
        out = (out + cn) * rho
    if same:
        out += max(1.0 - float(c.sum()), 0.0) * rho ** (len(c) + 1)
    return out


@lru_cache(maxsize=1024)
def uniform_table(m: LevelMap) -> np.ndarray:
    """2**16 entries: a uniform 16-bit index gives a level with the map's probabilities (each
    within 2**-16)."""
    size = 1 << UNIFORM_BITS
    edges = np.rint(ndtr(m.thresholds) * size).astype(np.int64)
    counts = np.diff(np.concatenate(([0], edges, [size])))
    table = np.repeat(np.arange(m.lo, m.hi + 1).astype(m.dtype), counts)
    table.flags.writeable = False
    return table


def z_bits(levels: int) -> int:
    """Bins of the z table: 2**16 for 8-bit sensors, 2**20 for deeper ones (a bin stays under
    a level wherever the levels are dense)."""
    return 16 if levels <= 256 else 20


@lru_cache(maxsize=1024)
def z_table(m: LevelMap, bits: int) -> np.ndarray:
    """The level at the centre of each of 2**bits bins over [-Z_SPAN, Z_SPAN]: index
    (z + Z_SPAN) * 2**bits / (2 Z_SPAN) (`z_scale`). A pixel whose bin straddles a threshold may
    take the neighbouring level; a level's probability moves by far less than 2**-16."""
    size = 1 << bits
    centres = (np.arange(size) + 0.5) * (2 * Z_SPAN / size) - Z_SPAN
    table = (m.lo + np.searchsorted(m.thresholds, centres, side="left")).astype(m.dtype)
    table.flags.writeable = False
    return table


def z_scale(bits: int) -> float:
    """Table index per unit of z."""
    return (1 << bits) / (2 * Z_SPAN)


def quantile(model: Johnson, levels: int, lo: int, hi: int, z: np.ndarray) -> np.ndarray:
    """The continuous quantile function truncated like `level_map`: x(z) with x = F^-1 of
    F(lo - 1/2) + Phi(z) (F(hi + 1/2) - F(lo - 1/2)) on the cut sides (what angle blends mix)."""
    z = np.asarray(z, dtype=np.float64)
    cut_lo, cut_hi = truncates(lo, hi, levels)
    if model.family is Family.CONST or not (cut_lo or cut_hi):
        return model.x_of_z(z)
    z_lo = float(model.z_of_x(lo - 0.5)) if cut_lo else -np.inf
    z_hi = float(model.z_of_x(hi + 0.5)) if cut_hi else np.inf
    if z_lo >= 0:  # both cuts in the upper tail: survival functions, so nothing cancels
        s_lo, s_hi = ndtr(-z_lo), ndtr(-z_hi)
        if not s_lo - s_hi > 1e-300:
            return model.x_of_z(z)
        w = -ndtri(np.clip(s_lo - ndtr(z) * (s_lo - s_hi), 1e-300, 1 - 1e-16))
    else:
        p_lo, p_hi = ndtr(z_lo), ndtr(z_hi)
        if not p_hi - p_lo > 1e-300:
            return model.x_of_z(z)
        w = ndtri(np.clip(p_lo + ndtr(z) * (p_hi - p_lo), 1e-300, 1 - 1e-16))
    # inside the levels' edges, so rounding never leaves lo..hi
    return np.clip(model.x_of_z(w), lo - 0.49 if cut_lo else -np.inf, hi + 0.49 if cut_hi else np.inf)
