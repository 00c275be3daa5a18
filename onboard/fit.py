"""The fixed-memory fitter: histograms in, Johnson models out.

Only a lookup table and the percentile method: no optimiser, no iteration, no sorting.
Each integer level's mass is spread uniformly over [v - 1/2, v + 1/2] when reading
percentiles, so ties in 8-bit data never make a gap zero or bias the family.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from onboard.censor import (MIN_REPORTED, SHIFT_SCALE, Placement, censored_counts, censored_end_one,
                            fallback_probs, l1_grid, l1_on_grid, piled_counts, place, quantize)
from onboard.johnson import Johnson
from onboard.percentile import model_from_percentiles, support_of, widen

__all__ = [
    "Z_LADDER", "FitResult", "FrameFitter", "PercentileCodec", "fit_histogram", "fit_values",
    "histogram_percentiles", "model_from_percentiles", "rebuild", "support_point", "z_for_count",
]

# z values tried from the top; the packet sends the index of the one used.
Z_LADDER: tuple[float, ...] = (0.524, 0.5, 0.45, 0.4, 0.35, 0.3, 0.25, 0.2, 0.15, 0.1)
# The tail percentile x(3z) should rest on at least this many pixels.
MIN_TAIL_PIXELS = 8


def _phi(x: float) -> float:
    return 0.5 * math.erfc(-x / math.sqrt(2.0))


# Lower-tail probabilities Phi(-3z), Phi(-z), Phi(z), Phi(3z) for each ladder step.
_PROBS: dict[float, tuple[float, float, float, float]] = {
    z: (_phi(-3 * z), _phi(-z), _phi(z), _phi(3 * z)) for z in Z_LADDER
}


def z_for_count(count: int) -> float:
    """The largest ladder step whose outer tail holds MIN_TAIL_PIXELS of `count` pixels."""
    for z in Z_LADDER:
        if count * _PROBS[z][0] >= MIN_TAIL_PIXELS:
            return z
    return Z_LADDER[-1]


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


class PercentileCodec:
    """Fixed-point codes for percentiles across a sensor range [lo, hi]."""

    def __init__(self, lo: float, hi: float, bits: int = 16) -> None:
        if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
            raise ValueError(f"codec range must be finite with hi > lo, got [{lo}, {hi}]")
        if bits not in (8, 16, 32):
            raise ValueError(f"codec bits must be 8, 16 or 32, got {bits}")
        self.lo, self.hi, self.bits = float(lo), float(hi), bits
        self.step = (self.hi - self.lo) / (1 << bits)
        self._top = (1 << bits) - 1

    @classmethod
    def for_levels(cls, levels: int) -> PercentileCodec:
        """Integer sensors: the spread range [-1/2, levels - 1/2]; 16-bit codes up to 8 bits."""
        if not 2 <= levels <= 65536:
            raise ValueError(f"levels must be in [2, 65536], got {levels}")
        return cls(-0.5, levels - 0.5, 16 if levels <= 256 else 32)

    def encode(self, percentiles) -> tuple[int, int, int, int]:
        codes = []
        for x in percentiles:
            x = float(x)
            if not math.isfinite(x):
                raise ValueError(f"cannot encode non-finite percentile {x}")
            codes.append(min(max(round((x - self.lo) / self.step), 0), self._top))
        return tuple(codes)  # type: ignore[return-value]

    def decode(self, codes) -> tuple[float, float, float, float]:
        out = []
        for c in codes:
            c = int(c)
            if not 0 <= c <= self._top:
                raise ValueError(f"percentile code {c} outside [0, {self._top}]")
            out.append(self.lo + c * self.step)
        return tuple(out)  # type: ignore[return-value]

    def snap(self, percentiles) -> tuple[float, float, float, float]:
        return self.decode(self.encode(percentiles))

    def snap_one(self, x: float) -> float:
        """One value through the fixed point (as `snap` does each of four)."""
        x = float(x)
        if not math.isfinite(x):
            raise ValueError(f"cannot encode non-finite percentile {x}")
        return self.lo + min(max(round((x - self.lo) / self.step), 0), self._top) * self.step

    def __repr__(self) -> str:
        return f"PercentileCodec(lo={self.lo}, hi={self.hi}, bits={self.bits})"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, PercentileCodec) and (self.lo, self.hi, self.bits) == (
            other.lo, other.hi, other.bits)

    def __hash__(self) -> int:
        return hash((self.lo, self.hi, self.bits))


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
    """_percentile_rows of one row in scalar steps: the same float operations, so the same
    numbers (searchsorted finds what the batch's comparison count finds in a sorted row)."""
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
    return _fit_counts(counts, occupied, _exact_total(counts, occupied), lo, bin_width, codec, z, censor)


def _fit_counts(counts: np.ndarray, occupied: np.ndarray, count: int, lo: float, bin_width: float,
                codec: PercentileCodec | None, z: float | None, censor: bool) -> FitResult:
    """fit_histogram of checked counts, their occupied bins and exact total."""
    if codec is None:
        codec = _default_codec(lo, bin_width, counts.size)
    z = z_for_count(count) if z is None else z
    return _fit_rows(counts[None, :], [count], [z], lo, bin_width, codec, censor, occupied)[0]


@functools.lru_cache(maxsize=16)
def _default_codec(lo: float, bin_width: float, bins: int) -> PercentileCodec:
    """The range of the bins at 16 bits (32 above 256 bins)."""
    return PercentileCodec(lo - 0.5 * bin_width, lo + (bins - 0.5) * bin_width, 16 if bins <= 256 else 32)


def _fit_rows(counts: np.ndarray, totals: list[int], zs: list[float], lo: float, bin_width: float,
              codec: PercentileCodec, censor: bool = True,
              occupied: np.ndarray | None = None) -> list[FitResult]:
    """Fit each row of (rows, bins) counts; every row has pixels. Shared by fit_histogram and
    FrameFitter.fit, so both give the same model for the same histogram. A single row may come
    with its occupied bins (flatnonzero) already found."""
    rows, bins = counts.shape
    cum = np.cumsum(counts, axis=1, dtype=np.float64)
    beta1, beta2 = _betas(counts, lo, bin_width)
    if rows == 1:  # one histogram (fit_histogram): scalar steps, the same numbers
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
    # The four percentiles of every row read by the symmetric method, in one batch.
    batch = [i for i, p in enumerate(plans) if p is not None and not p[0].fallback]
    if rows == 1:
        raw = {i: _percentiles_one(counts[i], cum[i], _placed_probs(plans[i][0]), lo, bin_width) for i in batch}
    else:
        raw = dict(zip(batch, _percentile_rows(
            counts[batch], cum[batch], np.array([_placed_probs(plans[i][0]) for i in batch]).reshape(-1, 4),
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
    """_ends_rows of one row by scalar steps (censor.censored_end_one): the same numbers."""
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
             raw: list[float] | None = None) -> FitResult:
    """One histogram read at `where` (`raw`: its percentiles, when already read), its support
    widened to the occupied bins f0..f1 if short (betas left at zero: the caller has them)."""
    normal_probs = fallback_probs(low, high) if where.fallback else None
    pct, model = _fit_placed(counts, cum, where, normal_probs, low, high, count, lo, bin_width, codec, raw)
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


def support_point(level: int, side: int, codec: PercentileCodec, lo: float = 0.0,
                  bin_width: float = 1.0) -> float:
    """The point a bounded support must reach when `level` is the lowest (side 0) or highest
    (side 1) occupied bin: a quarter level into that bin from its inner edge, snapped through
    the codec, so the level has positive probability while the bound moves as little as it can
    (widening to the bin's outer edge moved a pole-at-bound SB's quantiles by up to 3.6 gray).
    The receiver calls it on the transmitted level."""
    if side not in (0, 1):
        raise ValueError(f"side must be 0 (low) or 1 (high), got {side}")
    return codec.snap_one(lo + bin_width * (level + (0.25 if side == 0 else -0.25)))


def _fit_placed(counts: np.ndarray, cum: np.ndarray, where: Placement, normal_probs, low: float,
                high: float, count: int, lo: float, bin_width: float, codec: PercentileCodec,
                raw: list[float] | None = None):
    """(snapped percentiles, model) for one histogram read at `where`."""
    bins = counts.size
    if where.fallback:
        ends = _percentiles_one(counts, cum, normal_probs, lo, bin_width)
        a = lo + bin_width * 0.5 if low > 0.0 else float(ends[0])
        e = lo + bin_width * (bins - 1.5) if high > 0.0 else float(ends[1])
        pct = codec.snap([a, a, e, e])
    else:
        if raw is None:
            raw = _percentiles_one(counts, cum, _placed_probs(where), lo, bin_width)
        pct = codec.snap(raw)
    return pct, model_from_percentiles(pct, where.z, count, shift=where.shift, normal_probs=normal_probs)


def rebuild(result: FitResult, percentiles=None) -> Johnson:
    """The model from a result's (or the given, e.g. decoded) percentiles and its placement:
    what the receiver computes from a packet."""
    normal_probs = fallback_probs(result.censored_low, result.censored_high) if result.fallback else None
    return model_from_percentiles(result.percentiles if percentiles is None else percentiles,
                                  result.z, result.count, shift=result.shift,
                                  normal_probs=normal_probs, support=result.support)


def _placed_probs(where: Placement) -> tuple[float, float, float, float]:
    return _probs(where.z) if where.shift_code == 0 else _shifted_probs(where.z, where.shift)


def _shifted_probs(z: float, shift: float) -> tuple[float, float, float, float]:
    return (_phi(shift - 3 * z), _phi(shift - z), _phi(shift + z), _phi(shift + 3 * z))


def _probs(z: float) -> tuple[float, float, float, float]:
    if z in _PROBS:
        return _PROBS[z]
    return (_phi(-3 * z), _phi(-z), _phi(z), _phi(3 * z))


def _exact_total(counts: np.ndarray, occupied: np.ndarray) -> int:
    """The pixel count, exact even for counts near 2**53 or 2**64 (a float sum would round)."""
    if counts.dtype.kind not in "iu":
        return int(round(float(counts.sum())))
    if counts.dtype.itemsize < 8 or int(counts.max()) < (1 << 62) // counts.size:
        return int(counts.sum(dtype=np.int64))  # cannot overflow: the common case, fast
    return sum(int(c) for c in counts[occupied])


def fit_values(values: np.ndarray, value_range: tuple[float, float] | None = None,
               bins: int | None = None) -> FitResult:
    """Fit raw values. Integer dtypes default to one bin per level over the dtype's range;
    floats to 256 bins over `value_range` (default: the data's own range)."""
    v = np.asarray(values).ravel()
    if v.size == 0:
        raise ValueError("no values to fit")
    if v.dtype.kind not in "iuf":
        raise ValueError(f"values must be numeric, got dtype {v.dtype}")
    if v.dtype.kind == "f" and not np.all(np.isfinite(v)):
        raise ValueError("values contain NaN or inf")
    lo, hi, bins = _value_grid(v.dtype, value_range, bins, v)
    if value_range is not None:  # otherwise the grid is the dtype's or the data's own range
        vmin, vmax = float(v.min()), float(v.max())
        if vmin < lo or vmax > hi:
            raise ValueError(f"values [{vmin}, {vmax}] outside the declared range [{lo}, {hi}]")
    counts, width, centre0 = _bin(v, lo, hi, bins)
    # Counts of v's values: non-negative integers summing to v.size, nothing to re-check.
    return _fit_counts(counts, np.flatnonzero(counts), v.size, centre0, width, None, None, True)


def _value_grid(dtype: np.dtype, value_range, bins, v: np.ndarray | None = None):
    """(lo, hi, bins) for a dtype: integers get unit bins centred on each level."""
    if dtype.kind in "iu" and value_range is None and bins is None:
        info = np.iinfo(dtype)
        if info.max - info.min + 1 > 65536:
            raise ValueError(f"integer dtype {dtype} is deeper than 16 bits: give value_range and bins")
        return float(info.min), float(info.max), int(info.max - info.min + 1)
    if value_range is None:
        if v is None:
            raise ValueError(f"float data of dtype {dtype} needs a value_range")
        value_range = (float(v.min()), float(v.max()))
    lo, hi = float(value_range[0]), float(value_range[1])
    if not (math.isfinite(lo) and math.isfinite(hi) and hi >= lo):
        raise ValueError(f"value_range must be finite with hi >= lo, got {value_range}")
    if bins is None:
        bins = int(hi - lo + 1) if dtype.kind in "iu" else 256
    if not 2 <= bins <= 65536:
        raise ValueError(f"bins must be in [2, 65536], got {bins}")
    return lo, hi, bins


def _bin_geometry(lo: float, hi: float, bins: int, integer: bool) -> tuple[float, float]:
    """(bin width, centre of bin 0). Integer data whose levels fill the bins one each
    is centred on the levels; otherwise the bins tile [lo, hi]."""
    if hi == lo or (integer and hi - lo + 1 == bins):
        return 1.0, lo
    width = (hi - lo) / bins
    return width, lo + 0.5 * width


def _bin(v: np.ndarray, lo: float, hi: float, bins: int) -> tuple[np.ndarray, float, float]:
    width, centre0 = _bin_geometry(lo, hi, bins, v.dtype.kind in "iu")
    idx = _bin_index(v, lo, width, centre0, bins)
    return np.bincount(idx, minlength=bins), width, centre0


def _bin_index(v: np.ndarray, lo: float, width: float, centre0: float, bins: int) -> np.ndarray:
    if width == 1.0 and centre0 == lo and v.dtype.kind in "iu":
        return (v.astype(np.intp) - int(lo)) if lo != 0 else v.astype(np.intp, copy=False)
    edge0 = centre0 - 0.5 * width
    return np.clip(((v - edge0) * (1.0 / width)).astype(np.intp), 0, bins - 1)


class FrameFitter:
    """Per-(label, band) histograms in preallocated memory, filled in bounded row chunks.

    Without `value_range` the bins are the integer levels 0 .. bins-1 (256 for 8-bit,
    65536 for 16-bit sensors). With it, integer-like ranges (hi - lo + 1 == bins) keep one
    bin per level; otherwise the bins tile [lo, hi]. A chunk holds chunk_rows * 1024 pixels
    (chunk_rows rows of a 1024-wide frame; more rows of narrower, fewer of wider frames), so
    the extra memory of add() does not grow with frame size.
    """

    def __init__(self, n_labels: int, n_bands: int, bins: int = 256,
                 value_range: tuple[float, float] | None = None, chunk_rows: int = 64,
                 subsample: int = 1) -> None:
        if n_labels < 1 or n_bands < 1:
            raise ValueError(f"need at least one label and one band, got {n_labels}, {n_bands}")
        if not 2 <= bins <= 65536:
            raise ValueError(f"bins must be in [2, 65536], got {bins}")
        if chunk_rows < 1 or subsample < 1:
            raise ValueError(f"chunk_rows and subsample must be >= 1, got {chunk_rows}, {subsample}")
        if n_labels * n_bands * bins >= 2**31:
            raise ValueError("labels x bands x bins is too large for one histogram array")
        lo, hi = (0.0, float(bins - 1)) if value_range is None else map(float, value_range)
        if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
            raise ValueError(f"value_range must be finite with hi > lo, got {value_range}")
        self.n_labels, self.n_bands, self.bins = n_labels, n_bands, bins
        self.lo, self.hi = lo, hi
        self.chunk_pixels = chunk_rows * 1024
        self.chunk_rows, self.subsample = chunk_rows, subsample
        self.bin_width, self.centre0 = _bin_geometry(lo, hi, bins, hi - lo + 1 == bins)
        self._unit_levels = self.bin_width == 1.0 and self.centre0 == lo and lo == 0.0
        edge0 = self.centre0 - 0.5 * self.bin_width
        if self._unit_levels:
            self.codec = PercentileCodec.for_levels(bins)
        else:
            self.codec = PercentileCodec(edge0, edge0 + bins * self.bin_width, 16 if bins <= 256 else 32)
        self.counts = np.zeros((n_labels, n_bands, bins), dtype=np.int64)
        self._bases = (np.arange(n_labels, dtype=np.intp)[:, None] * n_bands
                       + np.arange(n_bands, dtype=np.intp)[None, :]) * bins
        self.empty_labels: tuple[int, ...] = ()
        # 8-bit frames with few labels and bands: a pixel's label base fits in 16 bits.
        self._fits16 = n_labels * n_bands * bins <= 65536 and bins == 256

    def reset(self) -> None:
        self.counts[...] = 0
        self.empty_labels = ()

    def add(self, frame: np.ndarray, labels: np.ndarray) -> None:
        """Accumulate one frame (HxWxB, or HxW for one band) under its label image (HxW)."""
        frame, labels = self._checked(frame, labels)
        frame, labels = frame[::self.subsample, ::self.subsample], labels[::self.subsample, ::self.subsample]
        height, width = labels.shape
        if height == 0 or width == 0:
            return
        step = max(1, self.chunk_pixels // width)
        if self._fits16 and self._unit_levels and frame.dtype == np.uint8:
            self._add_8bit(frame, labels, step)
            return
        flat = self.counts.reshape(-1)
        for r0 in range(0, height, step):
            lab, vals = labels[r0:r0 + step], frame[r0:r0 + step]
            self._check_labels(lab)
            # One gather of each pixel's (label, band) base offset, then add the bin index.
            idx = np.take(self._bases, lab, axis=0)
            if self._unit_levels and vals.dtype.kind in "ui":
                self._check_range(vals)
                np.add(idx, vals, out=idx, casting="unsafe")
            else:
                idx += self._value_index(vals)
            flat += np.bincount(idx.reshape(-1), minlength=flat.size)

    def _add_8bit(self, frame: np.ndarray, labels: np.ndarray, step: int) -> None:
        """8-bit frames whose (label, band, level) indices fit 16 bits: per chunk and band, the
        index label * bands * 256 + band * 256 + value in two buffers reused across chunks, one
        bincount each (no gather, no broadcast over the short band axis, no per-chunk copies)."""
        flat = self.counts.reshape(-1)
        height, width = labels.shape
        cap = min(step, height) * width
        base = np.empty(cap, dtype=np.uint16)
        idx = np.empty(cap, dtype=np.intp)  # bincount's own type: it copies nothing
        stride, level_step = np.uint16(self.n_bands * self.bins), np.uint16(self.bins)
        for r0 in range(0, height, step):
            lab, vals = labels[r0:r0 + step], frame[r0:r0 + step]
            self._check_labels(lab)
            n = lab.size
            b = base[:n].reshape(lab.shape)
            i = idx[:n].reshape(lab.shape)
            np.multiply(lab, stride, out=b, casting="unsafe")
            for band in range(self.n_bands):
                if band:
                    b += level_step
                np.add(vals[..., band], b, out=i, casting="unsafe")
                flat += np.bincount(idx[:n], minlength=flat.size)

    def _check_labels(self, lab: np.ndarray) -> None:
        lmin, lmax = int(lab.min()), int(lab.max())
        if lmin < 0 or lmax >= self.n_labels:
            bad = lmin if lmin < 0 else lmax
            raise ValueError(f"label {bad} outside [0, {self.n_labels - 1}]")

    def fit(self, min_count: int = 1, censor: bool = True) -> dict[tuple[int, int], FitResult]:
        """Fit every (label, band) with at least `min_count` pixels; others go to empty_labels."""
        totals = self.counts[:, 0, :].sum(axis=1)
        keep = [lab for lab in range(self.n_labels) if int(totals[lab]) >= max(min_count, 1)]
        self.empty_labels = tuple(sorted(set(range(self.n_labels)) - set(keep)))
        if not keep:
            return {}
        counts = [int(totals[lab]) for lab in keep for _ in range(self.n_bands)]
        zs = [z_for_count(c) for c in counts]
        rows = self.counts[keep].reshape(-1, self.bins)
        fits = _fit_rows(rows, counts, zs, self.centre0, self.bin_width, self.codec, censor)
        keys = [(lab, band) for lab in keep for band in range(self.n_bands)]
        return dict(zip(keys, fits))

    def _checked(self, frame: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        frame, labels = np.asarray(frame), np.asarray(labels)
        if frame.dtype.kind not in "uif" or frame.dtype.itemsize > 8:
            raise ValueError(f"frame dtype must be unsigned, integer or float, got {frame.dtype}")
        if labels.dtype.kind not in "ui":
            raise ValueError(f"labels must be integers, got dtype {labels.dtype}")
        if frame.ndim == 2:
            frame = frame[..., None]
        if frame.ndim != 3 or frame.shape[2] != self.n_bands:
            raise ValueError(f"frame shape {frame.shape} is not HxWx{self.n_bands}")
        if labels.shape != frame.shape[:2]:
            raise ValueError(f"labels shape {labels.shape} does not match frame {frame.shape[:2]}")
        return frame, labels

    def _check_range(self, vals: np.ndarray) -> None:
        if vals.dtype.kind in "ui":
            info = np.iinfo(vals.dtype)
            if info.min >= self.lo and info.max <= self.hi:
                return  # the dtype cannot leave the range
        vmin, vmax = vals.min(), vals.max()
        if vmin < self.lo or vmax > self.hi:
            raise ValueError(f"frame values [{vmin}, {vmax}] outside the declared range [{self.lo}, {self.hi}]")

    def _value_index(self, vals: np.ndarray) -> np.ndarray:
        """Bin index of every value (new intp array), after range checks."""
        if vals.dtype.kind == "f" and not np.all(np.isfinite(vals)):
            raise ValueError("frame contains NaN or inf")
        self._check_range(vals)
        if self.bin_width == 1.0 and self.centre0 == self.lo:
            # one bin per level: round to the nearest level
            return np.rint(vals - self.lo).astype(np.intp)
        edge0 = self.centre0 - 0.5 * self.bin_width
        idx = ((vals - edge0) * (1.0 / self.bin_width)).astype(np.intp)
        np.clip(idx, 0, self.bins - 1, out=idx)
        return idx
