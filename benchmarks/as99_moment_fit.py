"""A method-of-moments Johnson fit after Hill, Hill and Holder (1976), Algorithm AS 99 —
a reference to compare the percentile fit with, not part of the product.

Family selection by (beta1, beta2): below the impossible boundary beta2 = beta1 + 1 no
distribution exists; at the normal point SN; on the lognormal line SL; above it SU, fitted
by Johnson's iteration (AS 99's SUFIT); below it SB, whose (gamma, delta) match the sample's
skewness and kurtosis numerically (AS 99 iterates Newton steps on moments computed by
quadrature; here a least-squares solve on the same moments). xi and lam then match the
mean and standard deviation.
"""
from __future__ import annotations

import math

import numpy as np

from benchmarks.curve_moments import lognormal_omega, shape_moments, solve_shape
from btf.johnson import Family, Johnson

TOL = 0.01  # AS 99's tolerance for the normal point and the lognormal line


class MomentFitError(ValueError):
    """The sample moments admit no Johnson curve the method can fit; the message says why."""


def sample_moments(values: np.ndarray) -> tuple[float, float, float, float]:
    """(mean, sd, signed sqrt(beta1), beta2) of the values."""
    x = np.asarray(values, dtype=np.float64).ravel()
    return _moments(x, np.full(x.size, 1.0 / max(x.size, 1)))


def histogram_moments(counts: np.ndarray) -> tuple[float, float, float, float]:
    """(mean, sd, signed sqrt(beta1), beta2) of pixels whose level counts these are (level k = k)."""
    c = np.asarray(counts, dtype=np.float64).ravel()
    if not c.sum() > 0:
        raise MomentFitError("empty histogram: no curve to fit")
    return _moments(np.arange(c.size, dtype=np.float64), c / c.sum())


def _moments(x: np.ndarray, w: np.ndarray) -> tuple[float, float, float, float]:
    mean = float(np.dot(w, x))
    d = x - mean
    m2 = float(np.dot(w, d * d))
    if not m2 > 0.0:
        raise MomentFitError("zero variance: no curve to fit")
    return mean, math.sqrt(m2), float(np.dot(w, d ** 3)) / m2 ** 1.5, float(np.dot(w, d ** 4)) / m2 ** 2


def fit_moments(mean: float, sd: float, skew: float, beta2: float) -> Johnson:
    """The Johnson curve with these four moments (AS 99's JNSN)."""
    b1 = skew * skew
    if beta2 < b1 + 1.0 + TOL:
        raise MomentFitError(f"beta2 {beta2:.4g} is at or below beta1 + 1 = {b1 + 1:.4g}: "
                             "a two-point distribution (AS 99's ST), not a Johnson curve")
    if abs(skew) <= TOL and abs(beta2 - 3.0) <= TOL:
        return Johnson.normal(mean, sd)
    w = lognormal_omega(b1)
    on_line = w * w * (3.0 + w * (2.0 + w)) - 3.0
    if abs(on_line - beta2) <= TOL:
        return _sl(mean, sd, skew, w)
    if beta2 > on_line:
        return _su(mean, sd, skew, beta2)
    return _sb(mean, sd, skew, beta2)


def fit(values: np.ndarray) -> Johnson:
    return fit_moments(*sample_moments(values))


def fit_counts(counts: np.ndarray) -> Johnson:
    """The moments fit of the pixels behind a level histogram (the same curve as `fit` on them)."""
    return fit_moments(*histogram_moments(counts))


def _sl(mean: float, sd: float, skew: float, w: float) -> Johnson:
    if not w > 1.0:
        raise MomentFitError("lognormal with zero skewness: the normal point")
    delta = 1.0 / math.sqrt(math.log(w))
    gamma = 0.5 * delta * math.log(w * (w - 1.0) / (sd * sd))
    sign = 1.0 if skew > 0 else -1.0
    xi = mean - sign * math.exp((0.5 / delta - gamma) / delta)
    return Johnson(Family.SL, gamma, delta, xi, sign)


def _su(mean: float, sd: float, skew: float, beta2: float) -> Johnson:
    """Johnson's iteration for omega = exp(delta^-2), as in AS 99's SUFIT."""
    b1, b3 = skew * skew, beta2 - 3.0
    w = math.sqrt(math.sqrt(2.0 * beta2 - 2.8 * b1 - 2.0) - 1.0)
    if abs(skew) > TOL:
        for _ in range(50):
            w1, wm1 = w + 1.0, w - 1.0
            z = w1 * b3
            v = w * (6.0 + w * (3.0 + w))
            a = 8.0 * (wm1 * (3.0 + w * (7.0 + v)) - z)
            b = 16.0 * (wm1 * (6.0 + v) - b3)
            m = (math.sqrt(a * a - 2.0 * b * (wm1 * (3.0 + w * (9.0 + w * (10.0 + v))) - 2.0 * w1 * z)) - a) / b
            z = m * wm1 * (4.0 * (w + 2.0) * m + 3.0 * w1 * w1) ** 2 / (2.0 * (2.0 * m + w1) ** 3)
            v = w * w
            w = math.sqrt(math.sqrt(1.0 - 2.0 * (1.5 - beta2 + (b1 * (beta2 - 1.5 - v * (1.0 + 0.5 * v))) / z)) - 1.0)
            if abs(b1 - z) <= 1e-8:
                break
        else:
            raise MomentFitError("Johnson's SU iteration did not converge")
        y = m / w
        y = math.log(math.sqrt(y) + math.sqrt(y + 1.0))
        if skew > 0.0:
            y = -y
    else:
        w = math.sqrt(math.sqrt(2.0 * beta2 - 2.0) - 1.0)
        y = 0.0
    delta = math.sqrt(1.0 / math.log(w))
    gamma = y * delta
    e = math.exp(y)
    lam = sd / math.sqrt(0.5 * (w - 1.0) * (0.5 * w * (e * e + 1.0 / (e * e)) + 1.0))
    xi = 0.5 * math.sqrt(w) * (e - 1.0 / e) * lam + mean
    return Johnson(Family.SU, gamma, delta, xi, lam)


def _sb(mean: float, sd: float, skew: float, beta2: float) -> Johnson:
    try:
        gamma, delta = solve_shape(Family.SB, skew, beta2)
    except ValueError as exc:
        raise MomentFitError(str(exc)) from None
    m, var, _, _ = shape_moments(Family.SB, gamma, delta)
    lam = sd / math.sqrt(var)
    return Johnson(Family.SB, gamma, delta, mean - lam * m, lam)
