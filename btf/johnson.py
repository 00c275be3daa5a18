"""The Johnson system of distributions: the one definition used by robot and host.

A model maps a value x to a standard normal deviate z = gamma + delta * f((x - xi) / lam):

    SU  f(u) = asinh(u)                    support: all reals
    SB  f(u) = ln(u / (1 - u))             support: (xi, xi + lam), lam > 0
    SL  f(u) = ln(u)  for lam > 0          support: (xi, inf)
        f(u) = -ln(u) for lam < 0          support: (-inf, xi); the mirror image (negative skew)
    SN  f(u) = u                           canonical gamma = 0, delta = 1, xi = mean, lam = sd
    CONST                                  every value is xi

z is increasing in x for every family, so cdf(x) = Phi(z_of_x(x)) and x_of_z is its inverse.
Evaluation never overflows for finite parameters: exponent arguments are clipped and results
are clipped to the finite range of the output type.
"""
from __future__ import annotations

import enum
import math
import statistics
from dataclasses import dataclass

import numpy as np

# |z| beyond this is clipped: Phi(-37) ~ 6e-300 is still a normal float64.
Z_CLIP = 37.0
_LN_SQRT_2PI = 0.5 * math.log(2.0 * math.pi)
_LUT_BITS = 16
_NORMAL = statistics.NormalDist()
_inv_cdf = np.frompyfunc(_NORMAL.inv_cdf, 1, 1)


class Family(enum.StrEnum):
    SN = "SN"
    SL = "SL"
    SU = "SU"
    SB = "SB"
    CONST = "CONST"


def normal_cdf(z: np.ndarray | float) -> np.ndarray:
    """Phi(z), accurate in both tails (erfc, not 1 - erf)."""
    z = np.asarray(z, dtype=np.float64)
    w = -z / math.sqrt(2.0)
    # math.erfc element by element (numpy has none); fromiter skips the object array.
    e = np.fromiter(map(math.erfc, w.ravel().tolist()), dtype=np.float64, count=w.size)
    return e.reshape(w.shape) * 0.5


def normal_ppf(u: np.ndarray | float) -> np.ndarray:
    """Phi^-1(u) for u in [0, 1]; the end points map to -Z_CLIP and Z_CLIP."""
    u = np.asarray(u, dtype=np.float64)
    if not np.all((u >= 0.0) & (u <= 1.0)):  # also rejects NaN
        raise ValueError("probabilities must lie in [0, 1]")
    lo, hi = _PPF_LO, _PPF_HI
    if u.ndim == 0:
        return np.asarray(normal_ppf_one(float(u)))
    inner = np.clip(u, lo, hi)
    z = np.asarray(_inv_cdf(inner), dtype=np.float64)
    return np.clip(np.where(u <= lo, -Z_CLIP, np.where(u >= 1.0, Z_CLIP, z)), -Z_CLIP, Z_CLIP)


_PPF_LO = float(normal_cdf(-Z_CLIP))
_PPF_HI = min(float(normal_cdf(Z_CLIP)), math.nextafter(1.0, 0.0))


def normal_ppf_one(u: float) -> float:
    """normal_ppf of one probability as a Python float, the same steps without arrays
    (fitting asks one at a time)."""
    if not 0.0 <= u <= 1.0:  # also rejects NaN
        raise ValueError("probabilities must lie in [0, 1]")
    lo, hi = _PPF_LO, _PPF_HI
    z = -Z_CLIP if u <= lo else Z_CLIP if u >= 1.0 else _NORMAL.inv_cdf(min(max(u, lo), hi))
    return min(max(z, -Z_CLIP), Z_CLIP)


def _expit(w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(1 / (1 + e^-w), 1 / (1 + e^w)) without overflow and without 1 - y cancellation."""
    e = np.exp(-np.abs(w))
    big, small = 1.0 / (1.0 + e), e / (1.0 + e)
    pos = w >= 0
    return np.where(pos, big, small), np.where(pos, small, big)


# Per sampling dtype: parameters below the first bound take the fast in-place path, whose
# exponents stop at the second (exp of it is finite: float32 overflows near 88.72, float64
# near 709.78). With |xi| < bound, xi + e^lim cannot overflow either.
_SAFE = {np.dtype(np.float32): (1e36, 88.5), np.dtype(np.float64): (1e305, 709.0)}


def _finite(x: np.ndarray, dtype=np.float64) -> np.ndarray:
    top = np.finfo(dtype).max
    return np.clip(x, -top, top)


@dataclass(frozen=True, slots=True)
class Johnson:
    family: Family
    gamma: float
    delta: float
    xi: float
    lam: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.gamma) and math.isfinite(self.delta) and math.isfinite(self.xi)
                and math.isfinite(self.lam)):
            raise ValueError(f"Johnson parameters must be finite, got {(self.gamma, self.delta, self.xi, self.lam)}")
        if self.family is not Family.CONST:
            if self.delta <= 0.0:
                raise ValueError(f"delta must be positive, got {self.delta}")
            if self.lam == 0.0 or (self.lam < 0.0 and self.family is not Family.SL):
                raise ValueError(f"lam must be positive for {self.family} (negative only for SL), got {self.lam}")

    @classmethod
    def normal(cls, mean: float, sd: float) -> Johnson:
        if not sd > 0.0:
            raise ValueError(f"sd must be positive, got {sd}")
        return cls(Family.SN, 0.0, 1.0, float(mean), float(sd))

    @classmethod
    def constant(cls, value: float) -> Johnson:
        return cls(Family.CONST, 0.0, 1.0, float(value), 1.0)

    # -- the transform -------------------------------------------------------------------

    def _z_raw(self, x: np.ndarray) -> np.ndarray:
        """z for float64 x; +-inf outside the support (callers clip or mask)."""
        g, d, xi, lam = self.gamma, self.delta, self.xi, self.lam
        with np.errstate(all="ignore"):
            if self.family is Family.CONST:
                return np.where(x >= xi, np.inf, -np.inf)
            if self.family is Family.SN:
                return g + d * ((x - xi) / lam)
            if self.family is Family.SU:
                return g + d * np.arcsinh((x - xi) / lam)
            if self.family is Family.SB:
                # ln((x - xi) / (xi + lam - x)): both distances measured from their own bound.
                lo, hi = x - xi, (xi + lam) - x
                z = g + d * (np.log(np.maximum(lo, 0.0)) - np.log(np.maximum(hi, 0.0)))
                return np.where(lo <= 0.0, -np.inf, np.where(hi <= 0.0, np.inf, z))
            # SL
            u = (x - xi) / lam
            ln = np.log(np.maximum(u, 0.0))
            z = g + d * ln if lam > 0 else g - d * ln
            outside = -np.inf if lam > 0 else np.inf
            return np.where(u <= 0.0, outside, z)

    def z_of_x(self, x: np.ndarray | float) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        # Clipped, NaN (e.g. inf - inf) to 0: what nan_to_num then clip gave, in fewer passes.
        z = np.minimum(np.maximum(self._z_raw(x), -Z_CLIP), Z_CLIP)
        nan = np.isnan(z)
        if nan.any():
            z = np.where(nan, 0.0, z)
        return z

    def x_of_z(self, z: np.ndarray | float) -> np.ndarray:
        z = np.asarray(z, dtype=np.float64)
        g, d, xi, lam = self.gamma, self.delta, self.xi, self.lam
        if self.family is Family.CONST:
            return np.full(z.shape, xi)
        with np.errstate(all="ignore"):
            w = np.clip((z - g) / d, -700.0, 700.0)
            if self.family is Family.SN:
                x = xi + lam * w
            elif self.family is Family.SU:
                x = xi + lam * np.sinh(w)
            elif self.family is Family.SB:
                y, one_minus_y = _expit(w)
                # Near the upper bound measure from it, so negative skew keeps its precision.
                x = np.where(w < 0, xi + lam * y, (xi + lam) - lam * one_minus_y)
            else:
                x = xi + lam * np.exp(w if lam > 0 else -w)
        return _finite(x)

    # -- distribution functions -----------------------------------------------------------

    def cdf(self, x: np.ndarray | float) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        if self.family is Family.CONST:
            return np.where(x >= self.xi, 1.0, 0.0)
        return normal_cdf(np.clip(np.nan_to_num(self._z_raw(x), nan=0.0), -40.0, 40.0))

    def ppf(self, u: np.ndarray | float) -> np.ndarray:
        return self.x_of_z(normal_ppf(u))

    def pdf(self, x: np.ndarray | float) -> np.ndarray:
        """Density; zero outside the support and for CONST (a point mass has none)."""
        x = np.asarray(x, dtype=np.float64)
        if self.family is Family.CONST:
            return np.zeros(x.shape)
        d, xi, lam = self.delta, self.xi, self.lam
        with np.errstate(all="ignore"):
            z = self._z_raw(x)
            if self.family is Family.SN:
                log_dz = np.full(x.shape, math.log(d / lam))
            elif self.family is Family.SU:
                u = (x - xi) / lam
                # ln sqrt(1 + u^2) without overflowing u^2
                au = np.abs(u)
                log_hyp = np.where(au > 1e150, np.log(au), 0.5 * np.log1p(np.minimum(au, 1e150) ** 2))
                log_dz = math.log(d / lam) - log_hyp
            elif self.family is Family.SB:
                log_dz = math.log(d) + math.log(lam) - np.log(x - xi) - np.log((xi + lam) - x)
            else:
                log_dz = math.log(d) - np.log(np.abs(x - xi))
            log_pdf = -0.5 * z * z - _LN_SQRT_2PI + log_dz
            out = np.where(np.isfinite(z) & np.isfinite(log_pdf), np.exp(log_pdf), 0.0)
        return _finite(np.nan_to_num(out, nan=0.0, posinf=np.finfo(np.float64).max))

    # -- sampling ---------------------------------------------------------------------------

    def sample(self, n: int, rng: np.random.Generator, dtype=np.float32) -> np.ndarray:
        """n draws in `dtype` (float32 or float64), transformed in place."""
        dtype = np.dtype(dtype)
        if dtype not in (np.dtype(np.float32), np.dtype(np.float64)):
            raise ValueError(f"sample dtype must be float32 or float64, got {dtype}")
        if n < 0:
            raise ValueError(f"sample size must be non-negative, got {n}")
        if self.family is Family.CONST:
            return np.full(n, self.xi, dtype=dtype)
        z = rng.standard_normal(n, dtype=dtype)
        return self._x_of_z_inplace(z)

    def _x_of_z_inplace(self, z: np.ndarray) -> np.ndarray:
        g, d, xi, lam = self.gamma, self.delta, self.xi, self.lam
        dtype = z.dtype
        big, lim = _SAFE[dtype]
        if not max(abs(g), 1.0 / d, abs(xi), abs(lam), 1.0 / abs(lam)) < big:
            # Parameters beyond what the dtype carries: float64 formulas, clipped to the dtype.
            x = _finite(self.x_of_z(z.astype(np.float64)), dtype)
            z[...] = x
            return z
        # exp(lim) is finite in the dtype; for |lam| above 1 (2 for SU) the exponent stops
        # lower, so that lam * e^w runs on to about e^lim, near the dtype's maximum.
        scale = abs(lam) if self.family is Family.SL else 0.5 * abs(lam)
        wmax = lim - max(math.log(scale), 0.0) if self.family in (Family.SU, Family.SL) else lim
        with np.errstate(all="ignore"):
            z -= dtype.type(g)
            z *= dtype.type(1.0 / d)
            np.clip(z, -wmax, wmax, out=z)
            if self.family is Family.SU:
                e = np.exp(z)
                np.reciprocal(e, out=z)
                np.subtract(e, z, out=z)  # 2 sinh(w)
                z *= dtype.type(0.5 * lam)
            elif self.family is Family.SB:
                # expit(w) = 1 / (1 + e^-w); the pixel path is exact, this one is float precision.
                np.negative(z, out=z)
                np.exp(z, out=z)
                z += dtype.type(1.0)
                np.reciprocal(z, out=z)
                z *= dtype.type(lam)
            elif self.family is Family.SL:
                if lam < 0:
                    np.negative(z, out=z)
                np.exp(z, out=z)
                z *= dtype.type(lam)
            else:
                z *= dtype.type(lam)
            z += dtype.type(xi)
        return z

    def thresholds(self, levels: int = 256) -> np.ndarray:
        """t_k = z_of_x(k + 1/2), k = 0 .. levels-2: level k is chosen for z in (t_{k-1}, t_k]."""
        _check_levels(levels)
        return self.z_of_x(np.arange(levels - 1, dtype=np.float64) + 0.5)

    def pixels_of_z(self, z: np.ndarray, levels: int = 256) -> np.ndarray:
        """Integer pixel levels for normal deviates: equals clip(round(x_of_z(z)), 0, levels-1)."""
        out_dtype = np.uint8 if levels <= 256 else np.uint16
        z = np.asarray(z)
        if self.family is Family.CONST:
            _check_levels(levels)
            return np.full(z.shape, min(max(round(self.xi), 0), levels - 1), dtype=out_dtype)
        t = self.thresholds(levels)
        # side="left": a z equal to t_k belongs to level k (x = k + 1/2 rounds down).
        return np.searchsorted(t, z, side="left").astype(out_dtype)

    def level_probabilities(self, levels: int = 256) -> np.ndarray:
        """Probability of each integer level k (mass over [k - 1/2, k + 1/2], tails folded in)."""
        _check_levels(levels)
        if self.family is Family.CONST:
            p = np.zeros(levels)
            p[min(max(round(self.xi), 0), levels - 1)] = 1.0
            return p
        return self._between(self.thresholds(levels))

    def interval_probabilities(self, edges: np.ndarray) -> np.ndarray:
        """Probabilities of (-inf, e0], (e0, e1], ..., (e_last, inf) for increasing finite
        edges: len(edges) + 1 values summing to 1 (level_probabilities on any bin edges)."""
        e = np.asarray(edges, dtype=np.float64)
        if e.ndim != 1 or not np.isfinite(e).all() or (e[1:] < e[:-1]).any():
            raise ValueError("edges must be a 1-D array of finite, non-decreasing values")
        if self.family is Family.CONST:
            p = np.zeros(e.size + 1)
            p[np.searchsorted(e, self.xi, side="left")] = 1.0
            return p
        return self._between(self.z_of_x(e))

    @staticmethod
    def _between(z: np.ndarray) -> np.ndarray:
        t = np.concatenate(([-np.inf], z, [np.inf]))
        # Intervals above the median as differences of the upper tail: 1 - Phi(z) rounds to 0
        # beyond z ~ 8.3, Phi(-z) stays positive out to the clip.
        pos = t[:-1] >= 0.0
        j = pos.size - np.count_nonzero(pos)
        if not np.count_nonzero(pos[:j]):
            # Increasing edges (the usual case): each side's Phi only where its intervals are.
            lower, upper = normal_cdf(t[:j + 1]), normal_cdf(-t[j:])
            out = np.empty(pos.size)
            np.subtract(lower[1:], lower[:-1], out=out[:j])
            np.subtract(upper[:-1], upper[1:], out=out[j:])
            return out
        upper = normal_cdf(-t)
        below, above = np.diff(normal_cdf(t)), upper[:-1] - upper[1:]  # no -0.0
        return np.where(pos, above, below)

    def pixel_table(self, levels: int = 256) -> np.ndarray:
        """2**16-entry lookup table: a uniform random uint16 index gives a level whose
        probability is within 2**-16 of the model's."""
        _check_levels(levels)
        size = 1 << _LUT_BITS
        dtype = np.uint8 if levels <= 256 else np.uint16
        if self.family is Family.CONST:
            return np.full(size, min(max(round(self.xi), 0), levels - 1), dtype=dtype)
        c = normal_cdf(self.thresholds(levels))
        # Entry j covers u in [j, j+1) / size; level k owns entries round(size*c_{k-1}) .. round(size*c_k).
        edges = np.rint(c * size).astype(np.int64)
        counts = np.diff(np.concatenate(([0], edges, [size])))
        return np.repeat(np.arange(levels, dtype=dtype), counts)

    def sample_pixels(self, n: int, rng: np.random.Generator, levels: int = 256) -> np.ndarray:
        """n integer pixels in [0, levels-1]: uint8 for levels <= 256, else uint16."""
        _check_levels(levels)
        if n < 0:
            raise ValueError(f"sample size must be non-negative, got {n}")
        if levels <= 256:
            idx = np.frombuffer(rng.bytes(2 * n), dtype=np.uint16)
            return self.pixel_table(levels).take(idx)
        return self.pixels_of_z(rng.standard_normal(n), levels)


def _check_levels(levels: int) -> None:
    if not 2 <= levels <= 65536:
        raise ValueError(f"levels must be in [2, 65536], got {levels}")
