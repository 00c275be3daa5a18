"""Slifker-Shapiro percentile fitting: four quantiles at -3z, -z, z, 3z to a Johnson model.

With x(-3z) < x(-z) < x(z) < x(3z), m = x(3z) - x(z), n = x(-z) - x(-3z), p = x(z) - x(-z)
and d = mn / p**2: SU when d > 1, SB when d < 1, SL near 1 and SN when also m ~ n ~ p.
Slifker & Shapiro, Technometrics 22 (1980) 239-246; every form here is checked by round trip
on exact quantiles in tests/test_fit.py.
"""
from __future__ import annotations

import math

from btf.johnson import Family, Johnson, normal_ppf_one

# ln d has a sampling sd of roughly 4 / sqrt(count); the SL band is one such sd wide on each
# side, never narrower than the floor that keeps the SU/SB forms well conditioned.
_BAND_SD = 4.0
_BAND_FLOOR = 1e-6
# Gaps below this fraction of the span are lifted to it: no ratio can overflow.
GAP_FLOOR = 1e-9
# The censored fallback's two normal deviates are kept at least this far apart.
_MIN_DZ = 0.01


def sl_band(count: int) -> float:
    """Half-width of the band of ln d (and ln m/n for SN) treated as lognormal (normal)."""
    return max(_BAND_SD / math.sqrt(max(count, 1)), _BAND_FLOOR)


def model_from_percentiles(percentiles, z: float, count: int, *, shift: float = 0.0,
                           normal_probs: tuple[float, float] | None = None,
                           exact_family: bool = False) -> Johnson:
    """The Johnson model through the four percentiles x(s-3z), x(s-z), x(s+z), x(s+3z).

    `shift` s moves the four points along the normal scale (censored data: keep them out of
    the pile-up); the symmetric forms still apply with gamma lowered by s. `normal_probs`
    (pa, pe) instead asks for the normal with P(X < a) = pa and P(X < e) = pe (the censored
    fallback, see btf.fit.censor). The family follows ln d = ln(mn / p^2), with a band around
    0 (`sl_band`) read as lognormal or normal; `exact_family` drops the band (the family from
    the sign of ln d alone, the plain Slifker-Shapiro rule). Deterministic: the host calls it
    on the transmitted values to recompute the robot's model bit for bit. All four equal
    means a constant region.
    """
    if len(percentiles) != 4:
        raise ValueError(f"need four percentiles, got {len(percentiles)}")
    a, b, c, e = map(float, percentiles)
    if not (math.isfinite(a) and math.isfinite(b) and math.isfinite(c) and math.isfinite(e)):
        raise ValueError(f"percentiles must be finite, got {percentiles}")
    if not (a <= b <= c <= e):
        raise ValueError(f"percentiles must be non-decreasing, got {percentiles}")
    if not (math.isfinite(z) and z > 0.0):
        raise ValueError(f"z must be positive, got {z}")
    if not (math.isfinite(shift) and abs(shift) < 8.0):
        raise ValueError(f"shift must be finite and below 8 in size, got {shift}")
    span = e - a
    if span == 0.0:
        return Johnson.constant(a)
    if normal_probs is not None:
        model = _normal_through(a, e, *normal_probs)
    else:
        model = _shifted(_symmetric(a, b, c, e, z, 0.0 if exact_family else sl_band(count)), shift)
    return model


def _symmetric(a: float, b: float, c: float, e: float, z: float, band: float) -> Johnson:
    span = e - a
    floor = GAP_FLOOR * span
    m, n, p = max(e - c, floor), max(b - a, floor), max(c - b, floor)
    mid = 0.5 * (b + c)
    ln_d = math.log(m) + math.log(n) - 2.0 * math.log(p)
    try:
        if abs(ln_d) <= band:
            ln_mn = math.log(m) - math.log(n)
            if abs(ln_mn) <= band:
                model = _normal(a, b, c, e, z)
            else:
                model = _sl(m, n, p, mid, z)
        elif ln_d > 0.0:
            model = _su(m, n, p, mid, z)
        else:
            model = _sb(m, n, p, mid, z)
    except (OverflowError, ValueError, ZeroDivisionError):
        model = None
    if model is None:
        model = _normal(a, b, c, e, z)
    return model


def _shifted(model: Johnson, shift: float) -> Johnson:
    """Points at s + (-3z, -z, z, 3z): the model fitted as if symmetric has gamma - s."""
    if shift == 0.0:
        return model
    if model.family is Family.SN:
        return Johnson.normal(model.xi - shift * model.lam, model.lam)
    return Johnson(model.family, model.gamma + shift, model.delta, model.xi, model.lam)


def _normal_through(a: float, e: float, pa: float, pe: float) -> Johnson:
    """The normal with P(X < a) = pa and P(X < e) = pe, a < e (0 < pa < pe < 1)."""
    za, ze = normal_ppf_one(pa), normal_ppf_one(pe)
    if not ze - za >= _MIN_DZ:  # all the mass at the limits: a wide normal between them
        mid = 0.5 * (za + ze)
        za, ze = mid - 0.5 * _MIN_DZ, mid + 0.5 * _MIN_DZ
    sd = max((e - a) / (ze - za), GAP_FLOOR * (abs(a) + abs(e) + 1.0))
    return Johnson.normal(a - sd * za, sd)


def _normal(a: float, b: float, c: float, e: float, z: float) -> Johnson:
    # The mean of the four and the full span: exact for normal quantiles. Halves and quarters
    # first, so percentiles near the float limit cannot overflow the sums.
    sd = max((0.5 * e - 0.5 * a) / (3.0 * z), GAP_FLOOR * (abs(0.5 * a) + abs(0.5 * e)), 1e-300)
    mean = 0.25 * a + 0.25 * b + 0.25 * c + 0.25 * e
    return Johnson.normal(mean, min(sd, 1e300))


def _su(m: float, n: float, p: float, mid: float, z: float) -> Johnson | None:
    mp, np_ = m / p, n / p
    s = mp + np_
    root = math.sqrt(mp * np_ - 1.0)
    delta = 2.0 * z / math.acosh(0.5 * s)
    gamma = delta * math.asinh((np_ - mp) / (2.0 * root))
    lam = 2.0 * p * root / ((s - 2.0) * math.sqrt(s + 2.0))
    xi = mid + p * (np_ - mp) / (2.0 * (s - 2.0))
    return _checked(Family.SU, gamma, delta, xi, lam)


def _sb(m: float, n: float, p: float, mid: float, z: float) -> Johnson | None:
    pm, pn = p / m, p / n
    q = pm * pn - 1.0  # p^2/mn - 1 > 0
    t = (1.0 + pm) * (1.0 + pn)
    delta = z / math.acosh(0.5 * math.sqrt(t))
    gamma = delta * math.asinh((pn - pm) * math.sqrt(t - 4.0) / (2.0 * q))
    lam = p * math.sqrt((t - 2.0) ** 2 - 4.0) / q
    xi = mid - 0.5 * lam + p * (pn - pm) / (2.0 * q)
    return _checked(Family.SB, gamma, delta, xi, lam)


def _sl(m: float, n: float, p: float, mid: float, z: float) -> Johnson | None:
    # For an exact lognormal mn = p^2, so m/p = sqrt(m/n); using sqrt(m/n) keeps the two tails
    # symmetric when d is only near 1. n > m is negative skew: fit the mirror image.
    reflect = n > m
    if reflect:
        m, n, mid = n, m, -mid
    r = math.sqrt(m / n)
    delta = 2.0 * z / math.log(r)
    gamma = delta * math.log((r - 1.0) / math.sqrt(r))
    xi = mid - 0.5 * p * (r + 1.0) / (r - 1.0)
    lam = p
    if reflect:
        return _checked(Family.SL, -gamma, delta, -xi, -lam)
    return _checked(Family.SL, gamma, delta, xi, lam)


def _checked(family: Family, gamma: float, delta: float, xi: float, lam: float) -> Johnson | None:
    if not (math.isfinite(gamma) and math.isfinite(delta) and math.isfinite(xi) and math.isfinite(lam)
            and delta > 0.0 and lam != 0.0):
        return None
    return Johnson(family, gamma, delta, xi, lam)
