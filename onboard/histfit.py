"""One histogram, or a batch of them, to Johnson models by the percentile method.

Only a lookup table and the percentile method: no optimiser, no iteration, no sorting.
Each integer level's mass is spread uniformly over [v - 1/2, v + 1/2] when reading
percentiles, so ties in 8-bit data never make a gap zero or bias the family.

A batch (FrameFitter.fit) reads all its rows in array passes; a single histogram
(fit_histogram, fit_values) takes scalar steps with the same float operations, because array
overhead dominates one row and the MLE speed bar is measured on single fits. Both give the
same numbers (tests/test_fit_single.py pins them).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from onboard.censor import (MIN_REPORTED, SHIFT_SCALE, Placement, censored_counts, censored_end_one,
                            fallback_probs, l1_grid, l1_on_grid, piled_counts, place, quantize)
from onboard.codec import Z_LADDER, PercentileCodec, default_codec, percentile_probs, support_point, z_for_count
from onboard.johnson import Johnson
from onboard.percentile import model_from_percentiles, support_of, widen


@dataclass(frozen=True, slots=True)
class FitResult:
    """One (label, band) fit: the model and what the packet carries to rebuild it."""

    model: Johnson
    count: int
    z: float
    percentiles: tuple[float, float, float, float]  # x(-3z), x(-z), x(z), x(3z), data units
    beta1: float  # squared skewness of the histogram, for diagnostics
    beta2: float  # kurtosis of the histogram
    # Percentiles read at shift + (-3z, -z, z, 3z) on the normal scale (onboard.censor).
    shift: float = 0.0
    # Fractions of the pixels censored at the lowest and highest level (1/65535 fixed point).
    censored_low: float = 0.0
    censored_high: float = 0.0
    fallback: bool = False  # the normal through the censor limits (onboard.censor)
    # Points the support was widened to reach, low and high (None: that side held the data).
    support: tuple[float | None, float | None] | None = None


def histogram_percentiles(counts: np.ndarray, probs, lo: float = 0.0, bin_width: float = 1.0,
                          cum: np.ndarray | None = None) -> np.ndarray:
    """Quantiles at `probs` of a histogram whose bin k is centred on lo + k * bin_width,
    each bin's mass spread uniformly across its width."""
    counts = np.asarray(counts)
    if cum is None:
        cum = np.cumsum(counts, dtype=np.float64)
    probs = np.asarray(probs, dtype=np.float64)
    return _percentile_rows(counts[None], cum[None], probs[None], lo, bin_width)[0]


def _percentile_rows(counts: np.ndarray, cum: np.ndarray, probs: np.ndarray, lo: float,
                     bin_width: float) -> np.ndarray:
    """histogram_percentiles of each row, the same operations on each element whether a row
    comes alone or in a batch (so batched and single fits agree bit for bit)."""
    rows, bins = cum.shape
    targets = probs * cum[:, -1:]
    if rows == 0:
        return targets
    if bins <= 1024:
        # bins below each target: searchsorted(side="left") for every row at once
        k = (cum[:, None, :] < targets[:, :, None]).sum(axis=2)
    else:
        k = np.stack([np.searchsorted(c, t, side="left") for c, t in zip(cum, targets)])
    k = np.minimum(k, bins - 1)
    r = np.arange(rows)[:, None]
    here = counts[r, k].astype(np.float64)
    below = cum[r, k] - here
    frac = np.clip((targets - below) / np.maximum(here, 1.0), 0.0, 1.0)
    return lo + bin_width * (k - 0.5 + frac)


def _percentiles_one(counts: np.ndarray, cum: np.ndarray, probs, lo: float,
                     bin_width: float) -> list[float]:
    """_percentile_rows of one row in scalar steps, for speed: the same float operations, so the
    same numbers (searchsorted finds what the batch's comparison count finds in a sorted row)."""
    bins = cum.size
    total = float(cum[-1])
    targets = [p * total for p in probs]
    out = []
    for t, k in zip(targets, np.searchsorted(cum, targets, side="left").tolist()):
        k = min(k, bins - 1)
        here = float(counts[k])
        below = float(cum[k]) - here
        frac = min(max((t - below) / max(here, 1.0), 0.0), 1.0)
        out.append(lo + bin_width * (k - 0.5 + frac))
    return out


def _betas(counts: np.ndarray, lo: float, bin_width: float) -> tuple[np.ndarray, np.ndarray]:
    """beta1, beta2 of each spread histogram row (uniform within each bin, so never degenerate)."""
    w = np.asarray(counts, dtype=np.float64)
    w = w / np.add.reduce(w, axis=-1, keepdims=True)
    c = _centres(lo, bin_width, w.shape[-1])
    # Row-wise sums (not matmul): the same numbers for a row alone or in a batch.
    mu = np.add.reduce(w * c, axis=-1)
    dv = c - mu[..., None]
    dv2 = dv * dv
    h2 = bin_width * bin_width / 12.0
    wdv2 = w * dv2
    m2 = np.add.reduce(wdv2, axis=-1) + h2
    t = w * dv
    t *= dv2 + 3.0 * h2
    m3 = np.add.reduce(t, axis=-1)
    wdv2 *= dv2 + 6.0 * h2
    m4 = np.add.reduce(wdv2, axis=-1) + bin_width ** 4 / 80.0
    return m3 * m3 / m2 ** 3, m4 / (m2 * m2)


@functools.lru_cache(maxsize=16)
def _centres(lo: float, bin_width: float, bins: int) -> np.ndarray:
    c = lo + bin_width * np.arange(bins)
    c.flags.writeable = False  # shared between calls
    return c


def fit_histogram(counts: np.ndarray, lo: float = 0.0, bin_width: float = 1.0,
                  codec: PercentileCodec | None = None, z: float | None = None,
                  censor: bool = True) -> FitResult:
    """Fit one histogram (bin k centred on lo + k * bin_width). Percentiles are snapped
    through `codec` (default: the range of the bins at 16 or 32 bits) before solving.
    With `censor`, mass piled up in the end bins is treated as censored (onboard.censor)."""
    counts = np.asarray(counts)
    if counts.ndim != 1 or counts.size == 0:
        raise ValueError(f"counts must be a non-empty 1-D array, got shape {counts.shape}")
    if counts.dtype.kind not in "iuf":
        raise ValueError(f"counts must be numeric, got dtype {counts.dtype}")
    if counts.dtype.kind == "f" and not np.isfinite(counts).all():
        raise ValueError("counts must be finite")
    if counts.dtype.kind != "u" and counts.min() < 0:
        raise ValueError("counts must be non-negative")
    if not (math.isfinite(lo) and math.isfinite(bin_width) and bin_width > 0):
        raise ValueError(f"need finite lo and positive bin_width, got {lo}, {bin_width}")
    occupied = np.flatnonzero(counts)
    if occupied.size == 0:
        raise ValueError("histogram is empty: nothing to fit")
    return fit_counts(counts, occupied, _exact_total(counts, occupied), lo, bin_width, codec, z, censor)


def fit_counts(counts: np.ndarray, occupied: np.ndarray, count: int, lo: float, bin_width: float,
               codec: PercentileCodec | None, z: float | None, censor: bool) -> FitResult:
    """fit_histogram of checked counts, their occupied bins and exact total."""
    if codec is None:
        codec = default_codec(lo, bin_width, counts.size)
    z = z_for_count(count) if z is None else z
    return fit_rows(counts[None, :], [count], [z], lo, bin_width, codec, censor, occupied)[0]


def fit_rows(counts: np.ndarray, totals: list[int], zs: list[float], lo: float, bin_width: float,
             codec: PercentileCodec, censor: bool = True,
             occupied: np.ndarray | None = None) -> list[FitResult]:
    """Fit each row of (rows, bins) counts; every row has pixels. Shared by fit_histogram and
    FrameFitter.fit, so both give the same model for the same histogram. A single row may come
    with its occupied bins (flatnonzero) already found."""
    rows, bins = counts.shape
    cum = np.cumsum(counts, axis=1, dtype=np.float64)
    beta1, beta2 = _betas(counts, lo, bin_width)
    # One row (fit_histogram, or a frame of one label and band) in scalar steps: array overhead
    # would dominate it. The same float operations, so the same numbers.
    if rows == 1:
        first, last, low_n, high_n, pile_lo, pile_hi = _ends_one(counts[0], occupied, censor)
    else:
        first, last, low_n, high_n, pile_lo, pile_hi = _ends_rows(counts, censor)
    plans: list[tuple[Placement, float, float] | None] = []
    for i in range(rows):
        count, z = totals[i], zs[i]
        if first[i] == last[i]:
            plans.append(None)
            continue
        low = quantize(float(low_n[i]) / count) if censor else 0.0
        high = quantize(float(high_n[i]) / count) if censor else 0.0
        where = _placement(z, low, high, count, pile_lo[i], pile_hi[i]) if censor else Placement(z)
        if where == Placement(z) and max(low, high) < MIN_REPORTED:
            low = high = 0.0
        plans.append((where, low, high))
    # Every row's four percentiles in one array pass (fallbacks read two of their own); a single
    # row reads its own in _fit_one, by scalar steps.
    raw = {}
    if rows > 1:
        batch = [i for i, p in enumerate(plans) if p is not None and not p[0].fallback]
        raw = dict(zip(batch, _percentile_rows(
            counts[batch], cum[batch], np.array([_probs_at(plans[i][0]) for i in batch]).reshape(-1, 4),
            lo, bin_width)))
    out = []
    for i in range(rows):
        count, z = totals[i], zs[i]
        f0, f1 = int(first[i]), int(last[i])
        if plans[i] is None:
            # One occupied bin: a constant region, sent as four equal percentiles.
            pct = codec.snap([lo + bin_width * f0] * 4)
            out.append(FitResult(Johnson.constant(pct[0]), count, z, pct, float(beta1[i]), float(beta2[i])))
            continue
        where, low, high = plans[i]
        fit = _fit_one(counts[i], cum[i], where, low, high, count, f0, f1, lo, bin_width, codec, raw.get(i))
        if low or high or where.shift_code or where.fallback or where.z != z:
            fit = _best_censored(counts[i], cum[i], fit, z, count, f0, f1, lo, bin_width, codec)
        out.append(FitResult(fit.model, count, fit.z, fit.percentiles, float(beta1[i]), float(beta2[i]),
                             fit.shift, low, high, fit.fallback, fit.support))
    return out


def _ends_rows(counts: np.ndarray, censor: bool):
    """Per row: first and last occupied bin, censored counts at the sensor limits and piles at
    an interior first or last occupied level (a pole at a bound inside the range), which are
    read like censored ones: percentiles placed clear of them."""
    rows, bins = counts.shape
    nz = counts > 0
    first = np.argmax(nz, axis=1)
    last = bins - 1 - np.argmax(nz[:, ::-1], axis=1)
    if not censor:
        return first.tolist(), last.tolist(), None, None, None, None
    low_n, high_n = censored_counts(counts)
    piles = piled_counts(counts, first, last)
    pile_lo = np.where(first == 0, 0, piles[0]).tolist()
    pile_hi = np.where(last == bins - 1, 0, piles[1]).tolist()
    return first.tolist(), last.tolist(), low_n.tolist(), high_n.tolist(), pile_lo, pile_hi


def _ends_one(counts: np.ndarray, occupied: np.ndarray | None, censor: bool):
    """_ends_rows of one row by scalar steps (censor.censored_end_one), for speed: the same
    numbers."""
    bins = counts.size
    if occupied is None:
        occupied = np.flatnonzero(counts)
    first, last = int(occupied[0]), int(occupied[-1])
    if not censor:
        return [first], [last], None, None, None, None
    low_n = high_n = pile_lo = pile_hi = 0
    if bins >= 4:
        c = counts[[0, 1, 2, -1, -2, -3]].tolist()
        low_n, high_n = censored_end_one(*c[:3]), censored_end_one(*c[3:])
    if last - first >= 3:
        if first != 0:
            pile_lo = censored_end_one(*counts[first:first + 3].tolist())
        if last != bins - 1:
            pile_hi = censored_end_one(*counts[last - 2:last + 1].tolist()[::-1])
    return [first], [last], [low_n], [high_n], [pile_lo], [pile_hi]


def _placement(z: float, low: float, high: float, count: int, pile_lo: int, pile_hi: int) -> Placement:
    """Where to read the percentiles of a row with censored fractions low, high at the sensor
    limits and pile_lo, pile_hi pixels piled at an interior end. An interior pile is genuine
    density (an SB's pole at its bound): the model must hold it, not clip it, so it never takes
    the fallback, whose normal only reproduces piles at the sensor limits."""
    if pile_lo or pile_hi:
        where = place(z, low + quantize(pile_lo / count), high + quantize(pile_hi / count), count, Z_LADDER)
        if not where.fallback:
            return where
    return place(z, low, high, count, Z_LADDER)


def _fit_one(counts: np.ndarray, cum: np.ndarray, where: Placement, low: float, high: float, count: int,
             f0: int, f1: int, lo: float, bin_width: float, codec: PercentileCodec,
             raw: np.ndarray | None = None) -> FitResult:
    """One histogram read at `where` (`raw`: its percentiles, when already read), its support
    widened to the occupied bins f0..f1 if short (betas left at zero: the caller has them)."""
    normal_probs = None
    if where.fallback:
        # four points a, a, e, e: the censor limits, or where a side is uncensored the middle of
        # the uncensored mass (onboard.censor)
        normal_probs = fallback_probs(low, high)
        mid = _percentiles_one(counts, cum, normal_probs, lo, bin_width)
        a = lo + bin_width * 0.5 if low > 0.0 else mid[0]
        e = lo + bin_width * (counts.size - 1.5) if high > 0.0 else mid[1]
        pct = codec.snap([a, a, e, e])
    else:
        pct = codec.snap(_percentiles_one(counts, cum, _probs_at(where), lo, bin_width) if raw is None else raw)
    model = model_from_percentiles(pct, where.z, count, shift=where.shift, normal_probs=normal_probs)
    support = None
    # Bounded supports must reach into every occupied bin (support_point), so each has mass;
    # only the side that falls short is recorded (it travels).
    ends = (support_point(f0, 0, codec, lo, bin_width), support_point(f1, 1, codec, lo, bin_width))
    s_lo, s_hi = support_of(model)
    if s_lo > ends[0] or s_hi < ends[1]:
        support = (ends[0] if s_lo > ends[0] else None, ends[1] if s_hi < ends[1] else None)
        model = widen(model, support, pct)  # what model_from_percentiles(..., support) gives
    return FitResult(model, count, where.z, pct, 0.0, 0.0, where.shift, low, high, where.fallback, support)


def _best_censored(counts: np.ndarray, cum: np.ndarray, placed: FitResult, z: float, count: int,
                   f0: int, f1: int, lo: float, bin_width: float, codec: PercentileCodec) -> FitResult:
    """Of the censored placement, the normal fallback (only when a sensor limit is censored) and
    the plain symmetric read at the label's z (censored fractions still recorded), the model
    whose bin probabilities are nearest the histogram (L1; the first of equals). A shifted fit
    extrapolates the pile-up from what the uncensored part shows, and a U- or J-shaped histogram
    can mislead it where the plain read would not; the comparison keeps censoring from ever
    fitting the histogram worse. Only censored or piled models pay for it. The choice travels
    as shift, z and fallback flag."""
    low, high = placed.censored_low, placed.censored_high
    cands = [placed]
    done = Placement(placed.z, round(placed.shift * SHIFT_SCALE), placed.fallback)
    for where in (Placement(placed.z, 0, True), Placement(z)):
        if where != done and (low or high or not where.fallback):
            cands.append(_fit_one(counts, cum, where, low, high, count, f0, f1, lo, bin_width, codec))
    grid = l1_grid(counts, lo, bin_width)
    errors = [l1_on_grid(c.model, grid) for c in cands]
    return cands[errors.index(min(errors))]


def rebuild(result: FitResult, percentiles=None) -> Johnson:
    """The model from a result's (or the given, e.g. decoded) percentiles and its placement:
    what the receiver computes from a packet."""
    normal_probs = fallback_probs(result.censored_low, result.censored_high) if result.fallback else None
    return model_from_percentiles(result.percentiles if percentiles is None else percentiles,
                                  result.z, result.count, shift=result.shift,
                                  normal_probs=normal_probs, support=result.support)


def _exact_total(counts: np.ndarray, occupied: np.ndarray) -> int:
    """The pixel count, exact even for counts near 2**53 or 2**64 (a float sum would round)."""
    if counts.dtype.kind not in "iu":
        return int(round(float(counts.sum())))
    if counts.dtype.itemsize < 8 or int(counts.max()) < (1 << 62) // counts.size:
        return int(counts.sum(dtype=np.int64))  # cannot overflow: the common case, fast
    return sum(int(c) for c in counts[occupied])


def _probs_at(where: Placement) -> tuple[float, float, float, float]:
    """Lower-tail probabilities of the four percentiles a placement reads."""
    return percentile_probs(where.z, where.shift)
