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

from btf.codec import (
    COUNT_LADDER,
    SHIFT_SCALE,
    PercentileCodec,
    default_codec,
    fallback_probs,
    percentile_probs,
    quantize,
    z_for_count,
)
from btf.fit.censor import MIN_REPORTED, Placement, censored_counts, censored_end_one, piled_counts, place
from btf.fit.reads import SN, TEMPLATE, WIDTH, in_band, l1, rank_grid, sl_bands, solve, template
from btf.johnson import Johnson
from btf.percentile import model_from_percentiles
from btf.record import FittedModel


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
                  censor: bool = True) -> FittedModel:
    """Fit one histogram (bin k centred on lo + k * bin_width). Percentiles are snapped
    through `codec` (default: the range of the bins at 16 or 32 bits) before solving.
    With `censor`, mass piled up in the end bins is treated as censored (btf.fit.censor)."""
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
               codec: PercentileCodec | None, z: float | None, censor: bool) -> FittedModel:
    """fit_histogram of checked counts, their occupied bins and exact total."""
    if codec is None:
        codec = default_codec(lo, bin_width, counts.size)
    z = z_for_count(count) if z is None else z
    return fit_rows(counts[None, :], [count], [z], lo, bin_width, codec, censor, occupied)[0]


def fit_rows(counts: np.ndarray, totals: list[int], zs: list[float], lo: float, bin_width: float,
             codec: PercentileCodec, censor: bool = True,
             occupied: np.ndarray | None = None) -> list[FittedModel]:
    """Fit each row of (rows, bins) counts; every row has pixels. Shared by fit_histogram and
    FrameFitter.fit, so both give the same model for the same histogram. A single row may come
    with its occupied bins (flatnonzero) already found. Each row is read several ways
    (btf.fit.reads) and the model nearest its histogram kept."""
    rows, bins = counts.shape
    cum = np.cumsum(counts, axis=1, dtype=np.float64)
    beta1, beta2 = _betas(counts, lo, bin_width)
    # One row (fit_histogram, or a frame of one label and band) in scalar steps: array overhead
    # would dominate it. The same float operations, so the same numbers.
    if rows == 1:
        first, last, low_n, high_n, pile_lo, pile_hi = _ends_one(counts[0], occupied, censor)
    else:
        first, last, low_n, high_n, pile_lo, pile_hi = _ends_rows(counts, censor)
    out: list[FittedModel | None] = [None] * rows
    plans: dict[int, tuple[Placement, float, float]] = {}
    b1, b2 = beta1.tolist(), beta2.tolist()
    for i in range(rows):
        count, z = totals[i], zs[i]
        if first[i] == last[i]:
            # One occupied bin: a constant region, sent as four equal percentiles.
            pct = codec.snap([lo + bin_width * int(first[i])] * 4)
            out[i] = FittedModel(Johnson.constant(pct[0]), count, z, pct, b1[i], b2[i])
            continue
        if not censor or not (low_n[i] or high_n[i] or pile_lo[i] or pile_hi[i]):
            plans[i] = (Placement(z), 0.0, 0.0)  # nothing censored or piled: the plain placement
            continue
        low, high = quantize(float(low_n[i]) / count), quantize(float(high_n[i]) / count)
        where = _placement(z, low, high, count, pile_lo[i], pile_hi[i])
        if where == Placement(z) and max(low, high) < MIN_REPORTED:
            low = high = 0.0
        plans[i] = (where, low, high)
    if plans:
        live = list(plans)
        reads = _read_all(counts, cum, live, plans, zs, totals, lo, bin_width, codec)
        chosen = _choose(counts[live], reads, plans, live, totals, lo, bin_width)
        at = (np.arange(len(live)), chosen)
        z_of, code_of, pct_of = reads.z[at].tolist(), reads.code[at].tolist(), reads.pct[at].tolist()
        exact_of, fallback_of, banded = reads.exact[at].tolist(), reads.fallback[at].tolist(), reads.ok[:, 1].tolist()
        # each live row's fullest bin, in one pass and no copy of the rows (16-bit rows are 65,536 bins)
        spikes = counts.argmax(axis=1)[live]
        peaks = counts[live, spikes]
        sizes = np.array([totals[i] for i in live])
        for j in np.flatnonzero((peaks >= SPIKE_SHARE * sizes) & (sizes >= SPIKE_PIXELS)).tolist():
            if plans[live[j]] != (Placement(zs[live[j]]), 0.0, 0.0) and not fallback_of[j]:
                continue  # a censored or piled region's own placement reads clear of its pile
            one = _spike_reads(reads, j, int(spikes[j]), lo, bin_width, codec)
            k = int(_choose(counts[live[j]][None], one, plans, [live[j]], totals, lo, bin_width)[0])
            z_of[j], code_of[j], pct_of[j] = float(one.z[0, k]), int(one.code[0, k]), one.pct[0, k].tolist()
            exact_of[j], fallback_of[j] = bool(one.exact[0, k]), bool(one.fallback[0, k])
        for j, i in enumerate(live):
            z, shift, exact, fallback = z_of[j], code_of[j] / SHIFT_SCALE, exact_of[j], fallback_of[j]
            _, low, high = plans[i]
            p = tuple(pct_of[j])
            model = model_from_percentiles(p, z, totals[i], shift=shift,
                                           normal_probs=fallback_probs(low, high) if fallback else None,
                                           exact_family=exact)
            # the exact family travels only where the SL band would have chosen another
            out[i] = FittedModel(model, totals[i], z, p, b1[i], b2[i], shift, low, high, fallback, exact and banded[j])
    return out  # type: ignore[return-value]


# A bin holding at least this share of a region's pixels is a spike (a black border's one level,
# a dark background's): where inside it the percentiles fall is unknown, and spread evenly over
# its width (as every read above spreads a level) they leave the curve no tail beyond it. The
# spike reads place its mass in part of its bin instead, (width, centre) in bins; the L1 ranking
# keeps one only where its model is nearer the histogram. Only regions of SPIKE_PIXELS or more
# (fewer: the reads chase counting noise; on the stability map's n = 100 the worst W1 rose from 31
# to 45 gray), uncensored or left to the censored fallback (a censored region's placement already
# reads clear of its pile: beside it, spike reads cost 2 gray of worst quantile error).
SPIKE_SHARE = 0.75
SPIKE_PIXELS = 10_000
SPIKE_PLACEMENTS: tuple[tuple[float, float], ...] = (
    (0.1, -0.4), (0.1, -0.15), (0.1, 0.15), (0.1, 0.4), (0.4, -0.25), (0.4, 0.25))

# Another read replaces the plain one only when nearer the histogram by more than this times
# occupied levels / pixels: on a few hundred pixels the other reads would otherwise chase
# counting noise (the stability map's worst off-band quantile error at n = 100 doubled), while
# on large regions the margin vanishes and the nearest read wins.
NOISE_MARGIN = 0.25


@dataclass
class _Reads:
    """Every live row's reads (rows x WIDTH columns, btf.fit.reads.Template) and their snapped
    percentiles (rows x WIDTH x 4); `ok`: the reads that apply."""

    z: np.ndarray
    code: np.ndarray
    exact: np.ndarray
    fallback: np.ndarray
    ok: np.ndarray
    pct: np.ndarray
    at: np.ndarray | None  # the bin of each percentile (rows x WIDTH x 4), and its place in it
    frac: np.ndarray | None


def _read_all(counts: np.ndarray, cum: np.ndarray, live: list[int], plans: dict, zs: list[float],
              totals: list[int], lo: float, bin_width: float, codec: PercentileCodec) -> _Reads:
    """The template's reads of every live row, a censored or piled row's placement and (censored
    at a sensor limit) its normal fallback, with their percentiles: each row's found by one
    searchsorted over its cumulative counts, then the float steps of _percentiles_one for all
    at once (so a row alone or in a batch reads the same numbers)."""
    n = len(live)
    z0 = np.array([zs[i] for i in live])
    total = np.array([totals[i] for i in live], dtype=np.int64)
    z, code = np.empty((n, WIDTH)), np.empty((n, WIDTH), dtype=np.int64)
    exact, fallback = np.empty((n, WIDTH), dtype=bool), np.empty((n, WIDTH), dtype=bool)
    probs, ok = np.empty((n, WIDTH, 4)), np.empty((n, WIDTH), dtype=bool)
    for value in set(z0.tolist()):
        rows = np.flatnonzero(z0 == value)
        t = template(value)
        z[rows], code[rows], exact[rows], fallback[rows], probs[rows] = t.z, t.code, t.exact, t.fallback, t.probs
        ok[rows] = total[rows, None] >= t.need
    for j, i in enumerate(live):
        where, low, high = plans[i]
        if where.shift_code or where.z != zs[i] or where.fallback:
            z[j, TEMPLATE], code[j, TEMPLATE], fallback[j, TEMPLATE] = where.z, where.shift_code, where.fallback
            ok[j, TEMPLATE] = True
            if not where.fallback:
                probs[j, TEMPLATE] = percentile_probs(where.z, where.shift)
        if (low or high) and not where.fallback:
            z[j, TEMPLATE + 1] = where.z
            ok[j, TEMPLATE + 1] = True
    # A fallback reads the middle of the uncensored mass (its pa and pe) where a side is uncensored,
    # the censor limit where it is censored (btf.fit.censor)
    fallbacks = [(j, k, *plans[live[j]][1:]) for j, k in zip(*np.nonzero(ok & fallback))]
    for j, k, low, high in fallbacks:
        pa, pe = fallback_probs(low, high)
        probs[j, k] = (pa, pa, pe, pe)
    every = n == counts.shape[0]
    c, cm = (counts, cum) if every else (counts[live], cum[live])
    targets = probs.reshape(n, -1) * cm[:, -1:]
    at = _bins_below(c, cm, targets)
    r = np.arange(n)[:, None]
    here = c[r, at].astype(np.float64)
    below = cm[r, at] - here
    frac = np.minimum(np.maximum((targets - below) / np.maximum(here, 1.0), 0.0), 1.0)
    points = (lo + bin_width * (at - 0.5 + frac)).reshape(n, WIDTH, 4)
    for j, k, low, high in fallbacks:
        if low > 0.0:
            points[j, k, :2] = lo + bin_width * 0.5
        if high > 0.0:
            points[j, k, 2:] = lo + bin_width * (counts.shape[1] - 1.5)
    pct = codec.snap_array(points)
    # the banded plain read only where the band decides its family (elsewhere it is column 0)
    ok[:, 1] = in_band(pct[:, 0], sl_bands(total.astype(np.float64)))
    return _Reads(z, code, exact, fallback, ok, pct, at.reshape(n, WIDTH, 4), frac.reshape(n, WIDTH, 4))


def _spike_reads(reads: _Reads, j: int, spike: int, lo: float, bin_width: float, codec: PercentileCodec) -> _Reads:
    """Row j's reads and the template's again (the banded copy of the plain read excepted) with
    its spike's mass in part of its bin (SPIKE_PLACEMENTS), as a batch of one row: the same z
    and shift, so the same packet fields and the same solve on the host; the family by the SL
    band. One row at a time: the ranking's memory stays one row's reads by its levels."""
    source = [k for k in range(TEMPLATE) if k != 1]
    cols = [(k, width, centre) for width, centre in SPIKE_PLACEMENTS for k in source]
    ks = np.array([k for k, _, _ in cols])
    width = np.array([w for _, w, _ in cols])[:, None]
    centre = np.array([c for _, _, c in cols])[:, None]
    bins, f = reads.at[j, ks], reads.frac[j, ks]
    points = np.where(bins == spike, spike + centre - 0.5 * width + width * f, bins - 0.5 + f)
    pct = codec.snap_array(lo + bin_width * points)
    ok = reads.ok[j, ks] & ~reads.fallback[j, ks]
    join = lambda a, b: np.concatenate([a[j], b])[None]  # noqa: E731
    none = np.zeros(len(ks), dtype=bool)
    return _Reads(join(reads.z, reads.z[j, ks]), join(reads.code, reads.code[j, ks]), join(reads.exact, none),
                  join(reads.fallback, none), join(reads.ok, ok), join(reads.pct, pct), None, None)


def _bins_below(counts: np.ndarray, cum: np.ndarray, targets: np.ndarray) -> np.ndarray:
    """Per row, the bins whose cumulative count is below each target (searchsorted, side
    "left"), at most the last bin. Integer counts: one search over all rows, each row lifted
    by its own multiple of the largest total + 1; for a whole-number cum, cum < t holds exactly
    when cum < ceil(t), so every value searched is a whole number below 2**53 and exact."""
    rows, bins = cum.shape
    lift = float(cum[:, -1].max()) + 1.0
    if counts.dtype.kind in "iu" and lift * rows < 2.0**53:
        base = np.arange(rows, dtype=np.float64)[:, None] * lift
        at = np.searchsorted((cum + base).ravel(), (np.ceil(targets) + base).ravel(), side="left")
        at = at.reshape(targets.shape) - np.arange(0, rows * bins, bins)[:, None]
    else:
        at = np.empty(targets.shape, dtype=np.intp)
        for j in range(rows):
            at[j] = np.searchsorted(cum[j], targets[j], side="left")
    return np.minimum(at, bins - 1, out=at)


def _choose(counts: np.ndarray, reads: _Reads, plans: dict, live: list[int], totals: list[int],
            lo: float, bin_width: float) -> np.ndarray:
    """Per live row, the column of its read whose model is nearest its histogram (L1, the first
    of equals). Fallbacks are solved one by one (rare); the rest in one array pass."""
    n, width = reads.ok.shape
    flat = np.flatnonzero(reads.ok)
    row = flat // width
    total = np.array([totals[i] for i in live], dtype=np.float64)[row]
    band = np.where(reads.exact.ravel()[flat], 0.0, sl_bands(total))
    fam, gamma, delta, xi, lam = solve(reads.pct.reshape(-1, 4)[flat], reads.z.ravel()[flat],
                                       reads.code.ravel()[flat] / SHIFT_SCALE, band)
    for m in np.flatnonzero(reads.fallback.ravel()[flat]).tolist():
        j, k = divmod(int(flat[m]), width)
        model = model_from_percentiles(tuple(reads.pct[j, k]), float(reads.z[j, k]), totals[live[j]],
                                       normal_probs=fallback_probs(*plans[live[j]][1:]))
        fam[m], gamma[m], delta[m], xi[m], lam[m] = SN, model.gamma, model.delta, model.xi, model.lam
    errors = np.full(n * width, np.inf)
    errors[flat] = l1(fam, gamma, delta, xi, lam, row, rank_grid(counts, lo, bin_width))
    errors = errors.reshape(n, width)
    total = np.array([totals[i] for i in live], dtype=np.float64)
    margin = NOISE_MARGIN * np.count_nonzero(counts, axis=1) / total
    better = errors.min(axis=1) < errors[:, 0] - margin
    return np.where(better, np.argmin(errors, axis=1), 0)


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
        where = place(z, low + quantize(pile_lo / count), high + quantize(pile_hi / count), count, COUNT_LADDER)
        if not where.fallback:
            return where
    return place(z, low, high, count, COUNT_LADDER)


def plain_fit(counts: np.ndarray, lo: float = 0.0, bin_width: float = 1.0,
              codec: PercentileCodec | None = None) -> Johnson:
    """The plain Slifker-Shapiro fit of a histogram: read at the count's ladder z, unshifted,
    the family by the sign of ln d, nothing censored. Every rule of the fitter is held to fit
    no worse than this (btf.fit.reads)."""
    counts = np.asarray(counts)
    count = _exact_total(counts, np.flatnonzero(counts))
    if codec is None:
        codec = default_codec(lo, bin_width, counts.size)
    z = z_for_count(count)
    pct = codec.snap(histogram_percentiles(counts, percentile_probs(z), lo, bin_width))
    return model_from_percentiles(pct, z, count, exact_family=True)


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
