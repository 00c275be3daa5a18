"""Sensor limits: censored mass at the lowest and highest level, and where to read percentiles.

A pixel at the top of a sensor's range says "at least this", not "this". The fitter counts such
pixels as censored when the end level holds more than the neighbouring levels suggest, and then
reads its four percentiles at s + (-3z, -z, z, 3z) on the normal scale, with z from the ladder
and the shift s chosen so that none falls inside the censored mass. The fitted model then
describes the whole distribution, beyond the limit too; sampling clips at the limit, which
reproduces the pile-up by itself.

Fallback: when the uncensored part is too thin for four percentiles (the window between the
censored masses is narrower than six steps of the smallest z: roughly more than 80-90% at one
limit, or both limits leaving little between), the model is the normal through the two points
the data still pin down exactly: P(X < a) = pa and P(X < e) = pe, where a and e are the censor
limits (or, at an uncensored end, the middle of the uncensored mass). Its clipped samples put
exactly the censored fractions at the limits and spread the rest between, which is all such a
histogram says.

Piles inside the range: the same test at the first or last occupied level finds a pile at a
bound inside the sensor's range (an SB's pole); the percentiles are placed clear of it the same
way, but it is density, not clipping: nothing is reported censored and there is no fallback.

Choice: a shifted fit extrapolates the pile-up from the uncensored part, and on U- and J-shaped
histograms that can go badly wrong where the plain read would not. So for every censored model
the fitter compares the shifted fit, the fallback and the plain symmetric read at the label's z
by their histogram L1 (`btf.fit.reads`) and keeps the nearest (the first of equals): censoring never fits a histogram
worse than not censoring. Everything here is deterministic from the transmitted shift, z,
fallback flag and fractions, so the receiver repeats it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from btf.codec import MAX_SHIFT_CODE, SHIFT_SCALE
from btf.johnson import normal_ppf_one

# Percentiles stay this much probability away from censored mass.
MARGIN = 0.01
# An end level is censored when it holds more than its neighbours extrapolate to, by more than
# counting noise, and at least this many pixels. A clipping sensor's end level always means
# "at most" / "at least", so erring towards censored only costs a little tail information.
EXCESS = 1.1
NOISE_SDS = 4.0
MIN_CENSORED_PIXELS = 8
# Smaller censored fractions are not reported unless they moved the percentiles: they cannot
# matter to the model and would cost packet bytes.
MIN_REPORTED = 0.005


@dataclass(frozen=True, slots=True)
class Placement:
    """Where the four percentiles are read: s + (-3z, -z, z, 3z), or the normal fallback;
    `exact`: the family from the sign of ln d alone (no SL band, btf.percentile)."""

    z: float
    shift_code: int = 0
    fallback: bool = False
    exact: bool = False

    @property
    def shift(self) -> float:
        return self.shift_code / SHIFT_SCALE


def censored_counts(counts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Censored pixel counts at the lowest and highest bin of each row of (rows, bins) counts."""
    c = np.asarray(counts)
    if c.shape[-1] < 4:
        zero = np.zeros(c.shape[:-1], dtype=c.dtype)
        return zero, zero
    return _censored_end(c[..., 0], c[..., 1], c[..., 2]), _censored_end(c[..., -1], c[..., -2], c[..., -3])


def piled_counts(counts: np.ndarray, first: np.ndarray, last: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixels piled at each row's first and last occupied bin (`first`, `last`), by the censoring
    test read there: at the sensor limits the same counts as `censored_counts`. Rows spanning
    fewer than four occupied-range bins have no piles (too little to tell a pile from a peak)."""
    c = np.asarray(counts)
    r = np.arange(c.shape[0])
    wide = last - first >= 3
    f0, f1 = np.where(wide, first, 0), np.where(wide, last, 3)
    low = _censored_end(c[r, f0], c[r, f0 + 1], c[r, f0 + 2])
    high = _censored_end(c[r, f1], c[r, f1 - 1], c[r, f1 - 2])
    zero = np.zeros_like(low)
    return np.where(wide, low, zero), np.where(wide, high, zero)


def _censored_end(end: np.ndarray, next1: np.ndarray, next2: np.ndarray) -> np.ndarray:
    n1, n2 = next1.astype(np.float64), next2.astype(np.float64)
    # a density rising towards the limit extrapolates linearly; a falling one stays at next1
    ref = np.maximum(n1, 2.0 * n1 - n2)
    excess = end > EXCESS * ref + NOISE_SDS * np.sqrt(n1 + 1.0)
    return np.where(excess & (end >= MIN_CENSORED_PIXELS), end, 0)


def censored_end_one(end, next1, next2):
    """_censored_end of one end level given as Python numbers: the same test in the same float
    steps (one histogram needs no arrays), `end` or 0."""
    n1, n2 = float(next1), float(next2)
    ref = max(n1, 2.0 * n1 - n2)
    if float(end) > EXCESS * ref + NOISE_SDS * math.sqrt(n1 + 1.0) and end >= MIN_CENSORED_PIXELS:
        return end
    return 0


def place(z_base: float, low: float, high: float, count: int, ladder: tuple[float, ...]) -> Placement:
    """The widest ladder z (at most z_base) and a shift keeping s +- 3z clear of the censored
    fractions `low` and `high`; the fallback when no ladder step fits."""
    if low <= 0.0 and high <= 0.0:
        return Placement(z_base)
    outer = 3.0 * z_base
    # How far each side may go: clear of its censored mass ...
    lo_cap = _ppf(low + MARGIN) if low > 0.0 else -math.inf
    hi_cap = _ppf(1.0 - high - MARGIN) if high > 0.0 else math.inf
    lo_z, hi_z = max(-outer, lo_cap), min(outer, hi_cap)
    if lo_z == -outer and hi_z == outer:
        return Placement(z_base)  # the censored mass is beyond the outer percentiles
    if hi_z - lo_z < 6.0 * z_base:
        # ... and, when the window got narrow, into the tails as far as the pixel count supports.
        tail = max(_ppf(min(0.5, 8.0 / max(count, 1))), -2.0 * outer)
        lo_z, hi_z = max(tail, lo_cap), min(-tail, hi_cap)
    for z in ladder:
        if z > z_base:
            continue
        # the lowest and highest shift codes keeping the window clear
        lo_code = math.ceil((lo_z + 3.0 * z) * SHIFT_SCALE)
        hi_code = math.floor((hi_z - 3.0 * z) * SHIFT_SCALE)
        if lo_code <= hi_code:
            code = min(max((lo_code + hi_code) // 2, -MAX_SHIFT_CODE), MAX_SHIFT_CODE)
            if lo_code <= code <= hi_code:
                return Placement(z, code)
    return Placement(ladder[-1], 0, fallback=True)


def _ppf(u: float) -> float:
    return normal_ppf_one(min(max(u, 0.0), 1.0))
