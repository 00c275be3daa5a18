"""Which percentiles to read: a handful of percentile fits per histogram, the nearest kept.

The Slifker-Shapiro fit reads four percentiles at s + (-3z, -z, z, 3z) on the normal scale.
Which spread z and centre s describe a region best depends on its shape (a long tail wants
the outer points far out, a skewed bulk an off-centre read), so the fitter reads each
histogram a few ways (the plain read at the count's ladder z, a `GRID` of spreads and centres,
and, for censored or piled regions, their placements), solves each in closed form and keeps the
model whose level probabilities are nearest the histogram in L1, the first of equals. The
plain read (the count's z, no shift, the family from the sign of ln d alone) is always first,
so no rule fits a region worse than the plain percentile fit. Nothing iterates: a fixed set of
reads, one closed form and one distance each, in array passes over every row of a frame.

The distance here only ranks reads (a fast normal cdf, accurate to 2e-7); the chosen model
is then solved once more by `btf.percentile.model_from_percentiles`, as the host does
from the packet, so robot and host hold the same model bit for bit.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from btf.codec import MIN_TAIL_PIXELS, Z_LADDER, percentile_probs
from btf.percentile import GAP_FLOOR

# The reads of every region after its plain read: three spreads z by three centres s (shift
# codes in 1/32, btf.codec.SHIFT_SCALE), the plain read's own z and centre excepted.
GRID: tuple[tuple[float, int], ...] = (
    (0.524, -16), (0.524, 16), (0.3, 0), (0.3, -16), (0.3, 16), (0.7, 0), (0.7, -16), (0.7, 16))
# Template columns: 0 the plain read (exact family), 1 the same with the SL band, 2.. the grid;
# then two for a censored region's placement and fallback.
TEMPLATE = 2 + len(GRID)
WIDTH = TEMPLATE + 2
# Family codes of the solved arrays.
SN, SL, SU, SB, CONST = range(5)
# Deeper histograms are ranked on this many merged bins (bounded time; the final model still
# comes from the full histogram's percentiles).
MAX_RANK_BINS = 1024
_SQRT1_2 = 1.0 / math.sqrt(2.0)
_Z_CLIP = 37.0


def _phi_one(x: float) -> float:
    return 0.5 * math.erfc(-x * _SQRT1_2)


def min_count(z: float, shift_code: int) -> int:
    """The fewest pixels for which both outer percentiles of a read rest on MIN_TAIL_PIXELS."""
    return math.ceil(MIN_TAIL_PIXELS / _phi_one(-abs(shift_code) / 32.0 - 3.0 * z))


@dataclass(frozen=True)
class Template:
    """The reads of a region whose ladder z is z0, as columns: z, shift code, exact family,
    censored fallback, percentile probabilities (columns x 4) and the fewest pixels each read
    needs. Columns TEMPLATE and TEMPLATE + 1 are left for a censored or piled region's own
    placement and fallback (never applicable here: they need more pixels than exist)."""

    z: np.ndarray
    code: np.ndarray
    exact: np.ndarray
    fallback: np.ndarray
    probs: np.ndarray
    need: np.ndarray


@functools.lru_cache(maxsize=32)
def template(z0: float) -> Template:
    reads = ((z0, 0), (z0, 0)) + GRID
    for z, _ in reads:
        if z not in Z_LADDER:
            raise AssertionError(f"read z {z} must be on the z ladder")
    never = np.iinfo(np.int64).max
    t = Template(
        z=np.array([z for z, _ in reads] + [z0, z0]),
        code=np.array([c for _, c in reads] + [0, 0]),
        exact=np.array([True] + [False] * (TEMPLATE + 1)),
        fallback=np.array([False] * TEMPLATE + [False, True]),
        probs=np.array([percentile_probs(z, c / 32.0) for z, c in reads] + [(0.5,) * 4] * 2),
        need=np.array([0, 0] + [min_count(z, c) for z, c in GRID] + [never, never], dtype=np.int64))
    for arr in vars(t).values():
        arr.flags.writeable = False
    return t


def in_band(pct: np.ndarray, band: np.ndarray) -> np.ndarray:
    """Where the SL band decides the family of reads (N x 4 percentiles): |ln d| <= band."""
    a, b, c, e = pct[:, 0], pct[:, 1], pct[:, 2], pct[:, 3]
    floor = GAP_FLOOR * (e - a)
    m, n, p = np.maximum(e - c, floor), np.maximum(b - a, floor), np.maximum(c - b, floor)
    with np.errstate(all="ignore"):
        return np.abs(np.log(m) + np.log(n) - 2.0 * np.log(p)) <= band


def sl_bands(count: np.ndarray) -> np.ndarray:
    """btf.percentile.sl_band of each count."""
    return np.maximum(4.0 / np.sqrt(np.maximum(count, 1.0)), 1e-6)


def solve(pct: np.ndarray, z: np.ndarray, shift: np.ndarray, band: np.ndarray):
    """The closed forms of btf.percentile for N reads at once: (family, gamma, delta, xi,
    lam) arrays. `band` is each read's SL half-width (0: the family from the sign of ln d).
    Only for ranking: a failed form falls back to the normal, as the scalar solve does."""
    a, b, c, e = pct[:, 0], pct[:, 1], pct[:, 2], pct[:, 3]
    n_reads = a.size
    span = e - a
    floor = GAP_FLOOR * span
    m, n, p = np.maximum(e - c, floor), np.maximum(b - a, floor), np.maximum(c - b, floor)
    mid = 0.5 * (b + c)
    fam = np.full(n_reads, SN, dtype=np.int8)
    gamma, delta = np.zeros(n_reads), np.ones(n_reads)
    # the normal: mean of the four, sd from the full span (also every fallback)
    xi = 0.25 * (a + b + c + e)
    lam = np.maximum((0.5 * e - 0.5 * a) / (3.0 * z), 1e-300)
    with np.errstate(all="ignore"):
        ln_d = np.log(m) + np.log(n) - 2.0 * np.log(p)
        ln_mn = np.log(m) - np.log(n)
        in_band = np.abs(ln_d) <= band
        for family, form, where in ((SL, _sl, in_band & (np.abs(ln_mn) > band)),
                                    (SU, _su, ~in_band & (ln_d > 0.0)), (SB, _sb, ~in_band & (ln_d <= 0.0))):
            rows = np.flatnonzero(where)
            if rows.size:
                _put(fam, gamma, delta, xi, lam, family, rows,
                     *form(m[rows], n[rows], p[rows], mid[rows], z[rows]))
    sn = fam == SN
    xi = np.where(sn, xi - shift * lam, xi)
    gamma = np.where(sn, gamma, gamma + shift)
    const = span == 0.0
    fam[const] = CONST
    xi[const] = a[const]
    return fam, gamma, delta, xi, lam


def _put(fam, gamma, delta, xi, lam, family, rows, g, d, x, l) -> None:
    good = np.isfinite(g) & np.isfinite(d) & np.isfinite(x) & np.isfinite(l) & (d > 0) & (l != 0)
    ok = rows[good]
    g, d, x, l = g[good], d[good], x[good], l[good]
    fam[ok] = family
    gamma[ok], delta[ok], xi[ok], lam[ok] = g, d, x, l


def _su(m, n, p, mid, z):
    mp, np_ = m / p, n / p
    s = mp + np_
    root = np.sqrt(mp * np_ - 1.0)
    delta = 2.0 * z / np.arccosh(0.5 * s)
    return (delta * np.arcsinh((np_ - mp) / (2.0 * root)), delta,
            mid + p * (np_ - mp) / (2.0 * (s - 2.0)), 2.0 * p * root / ((s - 2.0) * np.sqrt(s + 2.0)))


def _sb(m, n, p, mid, z):
    pm, pn = p / m, p / n
    q = pm * pn - 1.0
    t = (1.0 + pm) * (1.0 + pn)
    delta = z / np.arccosh(0.5 * np.sqrt(t))
    lam = p * np.sqrt((t - 2.0) ** 2 - 4.0) / q
    return (delta * np.arcsinh((pn - pm) * np.sqrt(t - 4.0) / (2.0 * q)), delta,
            mid - 0.5 * lam + p * (pn - pm) / (2.0 * q), lam)


def _sl(m, n, p, mid, z):
    flip = n > m
    hi, lo = np.where(flip, n, m), np.where(flip, m, n)
    sign = np.where(flip, -1.0, 1.0)
    r = np.sqrt(hi / lo)
    delta = 2.0 * z / np.log(r)
    gamma = delta * np.log((r - 1.0) / np.sqrt(r))
    xi = sign * mid - 0.5 * p * (r + 1.0) / (r - 1.0)
    return sign * gamma, delta, sign * xi, sign * p


def phi(z: np.ndarray) -> np.ndarray:
    """Normal cdf in float32, absolute error below 3e-7 (Abramowitz & Stegun 7.1.26): for
    ranking reads only."""
    x = np.abs(z)
    x *= np.float32(_SQRT1_2)
    t = np.float32(0.3275911) * x
    t += np.float32(1.0)
    np.reciprocal(t, out=t)
    poly = np.float32(1.061405429) * t
    for c in (-1.453152027, 1.421413741, -0.284496736, 0.254829592):
        poly += np.float32(c)
        poly *= t
    x *= x
    np.negative(x, out=x)
    np.exp(x, out=x)
    poly *= x
    poly *= np.float32(0.5)
    return np.where(z < 0.0, poly, np.float32(1.0) - poly)


def z_at(fam, gamma, delta, xi, lam, x: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """z of each read's model (`fam` sorted, so that each family is one block of reads) at its
    `counts` points, laid end to end in x, clipped to +-37, in float32 (u = (x - xi) / lam taken
    in float64)."""
    u = np.subtract(x, np.repeat(xi, counts))
    u /= np.repeat(lam, counts)
    u32 = u.astype(np.float32)
    del u
    out = np.repeat(delta.astype(np.float32), counts)  # each point's delta, then its transform times it
    ends = np.cumsum(counts).tolist()
    bounds = (np.flatnonzero(fam[1:] != fam[:-1]) + 1).tolist()
    with np.errstate(all="ignore"):
        for a, b in zip([0, *bounds], [*bounds, fam.size]):
            family, lo, hi = int(fam[a]), (ends[a - 1] if a else 0), ends[b - 1]
            uf, zf = u32[lo:hi], out[lo:hi]
            if family == SN:
                zf *= uf
            elif family == SU:
                zf *= np.arcsinh(uf)
            elif family == SB:
                zf *= np.log(uf / (np.float32(1.0) - uf))
                zf[uf <= 0.0] = -np.inf
                zf[uf >= 1.0] = np.inf
            elif family == SL:
                sign = np.repeat(np.sign(lam[a:b]).astype(np.float32), counts[a:b])
                zf *= np.log(uf)
                zf *= sign
                zf[uf <= 0.0] = -np.inf
                zf *= np.where(uf <= 0.0, sign, np.float32(1.0))
            else:  # CONST: a step at xi
                zf[:] = np.where(x[lo:hi] >= np.repeat(xi[a:b], counts[a:b]), np.float32(np.inf), np.float32(-np.inf))
        out += np.repeat(gamma.astype(np.float32), counts)
    np.clip(out, -_Z_CLIP, _Z_CLIP, out=out)
    out[np.isnan(out)] = 0.0
    return out


def rank_grid(counts: np.ndarray, lo: float, bin_width: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """What reads are ranked on, per row of (rows, bins) counts: (edges, observed probabilities,
    first, span). Row r occupies bins first[r] .. first[r] + span[r] - 1; edges[k] is the lower
    edge of bin k (-inf for bin 0, +inf above the last bin: the end bins hold the tails, as a
    clipping sensor's end levels do) and probs[r, k] its share of the row's pixels. Deeper than
    MAX_RANK_BINS bins, groups of bins are merged first (bounded time)."""
    rows, bins = counts.shape
    group = -(-bins // MAX_RANK_BINS)
    if group > 1:
        pad = (-bins) % group
        counts = np.pad(counts, ((0, 0), (0, pad))).reshape(rows, -1, group).sum(axis=2)
        bins = counts.shape[1]
    width = bin_width * group
    edges = np.concatenate(([-np.inf], (lo - 0.5 * bin_width) + width * np.arange(1, bins), [np.inf]))
    nz = counts > 0
    f0 = np.argmax(nz, axis=1)
    f1 = bins - 1 - np.argmax(nz[:, ::-1], axis=1)
    return edges, counts / counts.sum(axis=1, keepdims=True), f0, f1 - f0 + 1


def l1(fam, gamma, delta, xi, lam, row: np.ndarray, grid) -> np.ndarray:
    """Histogram L1 of each read's model against its row of the rank grid: the occupied span
    bin by bin plus the model's mass outside it. All reads in one pass over their spans laid
    end to end (grouped by family); each read's terms are then summed by one reduction over its
    own stretch, so a row gets the same figures alone or in a batch."""
    edges, probs, first, span = grid
    order = np.argsort(fam, kind="stable")
    cols = row[order]
    n_edges = span[cols] + 1
    ends = np.cumsum(n_edges)
    starts = ends - n_edges
    bins = np.arange(int(ends[-1]))
    bins += np.repeat(first[cols] - starts, n_edges)  # each read's edges: the lower edges of bins first..
    cdf = phi(z_at(fam[order], gamma[order], delta[order], xi[order], lam[order], edges[bins], n_edges))
    # bin j of a read lies between its edges j and j + 1; the term after its last edge is no bin
    n_bins = probs.shape[1]
    np.minimum(bins, n_bins - 1, out=bins)
    bins += np.repeat(cols * n_bins, n_edges)
    dev = cdf[1:] - cdf[:-1] - probs.ravel()[bins[:-1]]
    del bins
    np.abs(dev, out=dev)
    dev[ends[:-1] - 1] = 0.0
    errors = np.add.reduceat(dev, starts) + cdf[starts] + (1.0 - cdf[ends - 1])
    out = np.empty_like(errors)
    out[order] = errors
    return out
