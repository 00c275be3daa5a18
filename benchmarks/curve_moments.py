"""Moments of Johnson curves, and (gamma, delta) for a given (beta1, beta2) — host-side helpers
for the benchmarks (the stability map's generator and the method-of-moments reference).

For Y = f^-1((Z - gamma) / delta), Z standard normal: SU and SL moments are closed forms of
E[exp(k W)] = exp(-k gamma/delta + k^2 / (2 delta^2)); SB has none, so its moments are a
trapezoid sum over a fine z grid (spectrally accurate for the smooth Gaussian integrand).
"""
from __future__ import annotations

import math

import numpy as np
from scipy import optimize

from btf.johnson import Family

_Z = np.linspace(-12.0, 12.0, 8001)
_W = np.exp(-0.5 * _Z * _Z)
_W /= _W.sum()


def _central(raw: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    """(mean, variance, signed sqrt(beta1), beta2) from raw moments E[Y], .. E[Y^4]."""
    m1, m2, m3, m4 = raw
    var = m2 - m1 * m1
    mu3 = m3 - 3 * m1 * m2 + 2 * m1 ** 3
    mu4 = m4 - 4 * m1 * m3 + 6 * m1 * m1 * m2 - 3 * m1 ** 4
    return m1, var, mu3 / var ** 1.5, mu4 / var ** 2


def _exp_moment(k: float, gamma: float, delta: float) -> float:
    return math.exp(-k * gamma / delta + 0.5 * k * k / (delta * delta))


def shape_moments(family: Family, gamma: float, delta: float) -> tuple[float, float, float, float]:
    """(mean, variance, signed sqrt(beta1), beta2) of the standard curve (xi = 0, lam = 1)."""
    if family is Family.SN:
        return -gamma / delta, 1.0 / delta ** 2, 0.0, 3.0
    if family is Family.SL:
        raw = tuple(_exp_moment(k, gamma, delta) for k in (1, 2, 3, 4))
        # Centre on the mean before forming central moments: raw moments of exp differ hugely.
        e = raw[0]
        w = math.exp(1.0 / delta ** 2)
        var = e * e * (w - 1.0)
        return e, var, (w + 2.0) * math.sqrt(w - 1.0), w ** 4 + 2 * w ** 3 + 3 * w ** 2 - 3.0
    if family is Family.SU:
        # sinh(W)^r expanded: E[sinh^r] = 2^-r sum_j C(r,j) (-1)^j E[exp((r - 2j) W)]
        raw = []
        for r in (1, 2, 3, 4):
            s = sum(math.comb(r, j) * (-1) ** j * _exp_moment(r - 2 * j, gamma, delta) for j in range(r + 1))
            raw.append(s / 2 ** r)
        return _central(tuple(raw))
    if family is Family.SB:
        w = (_Z - gamma) / delta
        y = 0.5 * (1.0 + np.tanh(0.5 * w))
        m1 = float(_W @ y)
        d = y - m1
        d2 = d * d  # products, not powers: this is the SB solver's inner loop
        var = float(_W @ d2)
        return m1, var, float(_W @ (d2 * d)) / var ** 1.5, float(_W @ (d2 * d2)) / var ** 2
    raise ValueError(f"no moments for family {family}")


def lognormal_beta2(beta1: float) -> float:
    """beta2 on the lognormal line for a given beta1 (the SU/SB border)."""
    w = lognormal_omega(beta1)
    return w ** 4 + 2 * w ** 3 + 3 * w ** 2 - 3.0


def lognormal_omega(beta1: float) -> float:
    """omega = exp(1/delta^2) of the lognormal with this beta1: (w - 1)(w + 2)^2 = beta1."""
    x = 0.5 * beta1 + 1.0
    y = math.sqrt(beta1) * math.sqrt(0.25 * beta1 + 1.0)
    u = (x + y) ** (1.0 / 3.0)
    return u + 1.0 / u - 1.0


def solve_shape(family: Family, skew: float, beta2: float) -> tuple[float, float]:
    """(gamma, delta) of the SU or SB curve with signed skewness `skew` and kurtosis `beta2`.

    Least squares on (gamma, ln delta) from a few starts; raises ValueError when no start
    reaches the target (outside the family's region, or too close to its edge to resolve).
    """
    if family not in (Family.SU, Family.SB):
        raise ValueError(f"solve_shape handles SU and SB, not {family}")

    def resid(p):
        with np.errstate(all="ignore"):
            try:
                _, _, s, b2 = shape_moments(family, p[0], math.exp(p[1]))
            except (OverflowError, ZeroDivisionError):
                return [1e6, 1e6]
        if not (math.isfinite(s) and math.isfinite(b2)):
            return [1e6, 1e6]
        return [s - skew, (b2 - beta2) / max(beta2, 1.0)]

    starts = [(g, ld) for ld in (-1.5, -0.5, 0.5, 1.5) for g in (-1.0, 0.0, 1.0)]
    if family is Family.SU:
        starts = [(-math.copysign(g, skew), ld) for g, ld in starts]
    best = None
    for g0, ld0 in starts:
        sol = optimize.least_squares(resid, [g0, ld0], xtol=1e-14, ftol=1e-14, gtol=1e-14,
                                     bounds=([-60.0, -7.0], [60.0, 7.0]))
        if best is None or sol.cost < best.cost:
            best = sol
        if best.cost < 1e-20:
            break
    if best is None or not math.sqrt(2 * best.cost) < 1e-6:
        raise ValueError(f"no {family} curve has skewness {skew:g} and beta2 {beta2:g}")
    return float(best.x[0]), float(math.exp(best.x[1]))
