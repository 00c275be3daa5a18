"""A region's grain and band dependence, measured on board in one anchored pass of fixed memory.

Per region (btf.dependence.Dependence):

  corr  the correlation matrix of the bands' pixel values, upper triangle;
  acf   the autocorrelation of the pixels at every lag of the half-plane window W(R)
        (btf.dependence.window): one row per band when some region's bands differ in grain
        by more than ROW_SPREAD beyond sampling noise (JPEG and Bayer noise set a band apart),
        else their average;
  lo/hi the lowest and highest level of each band, from the fitter's histograms (`observed`).

Anchors lie on a deterministic lattice (btf.fit.anchors: at most `max_anchors`, inside the
frame by R so every partner exists). Each anchor's whole window of partners is read at once as
a strided view of the frame; a pair counts only when both pixels carry the anchor's label, so a
mask edge never mixes regions. A region the lattice leaves with few pairs (its median lag under
SPARSE_PAIRS: a small or scattered region) gets a second pass on its own pixels off the
lattice, at most max_anchors // SPARSE_SHARE in all, its sums added to the first's; the
other regions' values are those of the lattice alone (a small region whose bands differ in
grain beyond its noise may give the frame rows per band). A lag still under MIN_PAIRS pairs
is reported unmeasured (the record's `unmeasured`, its value 0.0), not independent. Values are
centred on the region's median (from its models) before the float32 products, which keeps 8-bit
products exact and 16-bit ones accurate. Per region, lag and band the pass keeps the pair count
and the sums of a, b, a^2, b^2 and a b (anchor a, partner b): per window row, the partners' planes
(bands apart) masked to the anchor's label, then one-hot matrix products small enough for one
BLAS thread; the Pearson correlation of the pairs follows. The lags (0, dx) are read on both
sides of the anchor, doubling their pairs.

These are plain Pearson correlations of the pixels, what an image comparison measures; the
host turns them into the correlations of normal scores that reproduce them through the
models (tools.analysis.latent). Memory is fixed: the accumulators (regions x window x bands)
and, per chunk of anchors, a few chunk x bands x (2R+1) float32 planes (the second pass also
gathers its chunk's windows, chunk x bands x (R+1) x (2R+1) pixels); the frame itself is only
viewed.
"""
from __future__ import annotations

import math
from typing import Callable, Mapping

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from btf.dependence import RADIUS, Dependence, check_radius
from btf.fit.anchors import lattice, sparse_anchors
from btf.johnson import Family, Johnson

# The most anchors whose lattice pass stays within the fit's time at 1 MP on replayed photographs
# (benchmarks: "dependence", "pose"; the second pass for sparse regions comes on top); the error
# against every pixel pair is in RESULTS.md.
MAX_ANCHORS = 6144
CHUNK = 2048  # anchors per chunk: about 1 MB of temporaries
PRODUCT_LIMIT = 400_000  # regions x anchors x positions of one product: OpenBLAS keeps it on one thread
MIN_PAIRS = 32  # fewer pairs than this: the lag is reported unmeasured (its value 0.0)
# A region whose median lag has fewer pairs than this (a standard error of about 1/16) gets a
# second pass on its own pixels: a small or scattered region meets few of the lattice's anchors
SPARSE_PAIRS = 256
# The second pass takes at most max_anchors // SPARSE_SHARE anchors in all: an eighth keeps the
# robot's pass near its time and takes the moon's 2,400-pixel class from 0.74 to 0.10 against
# every pixel pair; the host (tools.data.images) gives it half, for 0.03.
SPARSE_SHARE = 8
# The host's sums over every pixel pair (tools.analysis.pair_sums): (data, labels, regions,
# centres, radius) -> (anchor side, partner), laid out as _Sums keeps them
PairSums = Callable[[np.ndarray, np.ndarray, list, np.ndarray, int], tuple[np.ndarray, np.ndarray]]
# A band's row further than this (plus its sampling noise) from the bands' average at some lag:
# every band keeps its row (on photographs the average missed a band's grain by up to 0.29)
ROW_SPREAD = 0.03
CORR_ANCHORS = 2 * MAX_ANCHORS  # points of the band correlations' own lattice over the whole frame (cheap: no window)


def observed(counts: np.ndarray, centre0: float = 0.0, bin_width: float = 1.0,
             levels: int = 256) -> dict[int, tuple[tuple[int, ...], tuple[int, ...]]]:
    """{label: (lo per band, hi per band)}: the lowest and highest level of every label with
    pixels in a fitter's histograms (labels x bands x bins, FrameFitter.counts). Bins wider
    than a level give the levels their edges cover."""
    out = {}
    occupied = counts > 0
    for label in np.flatnonzero(occupied[:, 0].any(axis=1)):
        first = occupied[label].argmax(axis=1)
        last = counts.shape[2] - 1 - occupied[label, :, ::-1].argmax(axis=1)
        lo = np.floor(centre0 + (first - 0.5) * bin_width + 0.5)
        hi = np.ceil(centre0 + (last + 0.5) * bin_width - 0.5)
        out[int(label)] = (tuple(int(v) for v in np.clip(lo, 0, levels - 1)),
                           tuple(int(v) for v in np.clip(hi, 0, levels - 1)))
    return out


class _Sums:
    """Per region, window position and band: the pair count and the pairs' sums of a, a^2
    (anchor side), b, a b and b^2 (partner side)."""

    def __init__(self, n_regions: int, n_bands: int, positions: int) -> None:
        self.b = n_bands
        self.anchor_side = np.zeros((1 + 2 * n_bands, n_regions, positions))  # n, sum a, sum a^2
        self.partner = np.zeros((3, n_bands, n_regions, positions))  # sum b, sum a b, sum b^2

    def anchors(self, onehot: np.ndarray, anchor: np.ndarray, width: int) -> None:
        """Starts a chunk: onehot (K', n) its anchors' regions, anchor (B, n) their centred values."""
        n = anchor.shape[1]
        own = np.concatenate([np.ones((1, n), np.float32), anchor, anchor * anchor])
        self._onehot = onehot
        # (1 + 2B) K' x n as one matrix: one product per window row (as a stack of 1 + 2B
        # matrices numpy multiplies them one by one, three times slower)
        self._left = (onehot[None] * own[:, None, :]).reshape(-1, n)
        self._repeated = np.repeat(anchor[:, :, None], width, axis=2)  # (B, n, 2R+1): each partner's anchor
        self._stack = np.empty((3,) + self._repeated.shape, np.float32)  # b, a b, b^2 of the kept pairs
        kk, positions = onehot.shape[0], self.anchor_side.shape[2]
        self._side = np.zeros((1 + 2 * self.b, kk, positions))
        self._partner = np.zeros((3, self.b, kk, positions))

    def pairs(self, cols: slice, values: np.ndarray, inside: np.ndarray) -> None:
        """One row of window positions (`cols`): values (B, n, 2R+1) the partners' centred
        values; inside (n, 2R+1) 1 where the partner carries its anchor's label, else 0 (most
        anchors of a segmented frame have some partner off their region, so every value is
        masked, not a few taken back). Each product is (regions x anchors) by (anchors x
        positions), the chunk sized so that BLAS keeps it on one thread: the pass runs beside
        the link on one core, where more BLAS threads only spin and wait their turn."""
        stack = self._stack
        np.multiply(values, inside, out=stack[0])  # planar bands: the mask broadcasts over whole planes
        np.multiply(stack[0], self._repeated, out=stack[1])
        np.multiply(stack[0], values, out=stack[2])
        self._partner[:, :, :, cols] += self._onehot @ stack  # one product per quantity and band
        self._side[:, :, cols] += (self._left @ inside).reshape(self._side.shape[:2] + (-1,))

    def flush(self, present: np.ndarray) -> None:
        """Ends a chunk: its regions' sums into the totals, its buffers let go (memory stays one
        chunk's, however many chunks the frame takes)."""
        self.anchor_side[:, present] += self._side
        self.partner[:, :, present] += self._partner
        self._onehot = self._left = self._repeated = self._stack = self._side = self._partner = None

    def pearson(self, region: int) -> np.ndarray:
        """Per band and window position, the Pearson correlation of one region's pairs, anchors
        and partners each with their own mean and variance (numpy's corrcoef): pooled into one,
        a class on a gradient (a sky, a shaded wall) read its grain up to 0.27 low."""
        n = self.anchor_side[0, region]
        sa, saa = self.anchor_side[1:1 + self.b, region], self.anchor_side[1 + self.b:, region]
        sb, sab, sbb = self.partner[:, :, region]
        with np.errstate(all="ignore"):
            ma, mb = sa / n, sb / n
            va, vb = saa / n - ma * ma, sbb / n - mb * mb
            cov = sab / n - ma * mb
            r = np.where((n >= MIN_PAIRS) & (va > 1e-9) & (vb > 1e-9), cov / np.sqrt(va * vb), 0.0)
        return np.clip(np.nan_to_num(r), -1.0, 1.0)


def measure(
    data: np.ndarray, labels: np.ndarray, models: Mapping[tuple[int, int], Johnson],
    levels: int = 256, max_anchors: int = MAX_ANCHORS, chunk: int = CHUNK, radius: int = RADIUS,
    per_band: bool | None = None, levels_seen: Mapping[int, tuple[tuple[int, ...], tuple[int, ...]]] | None = None,
    corr_points: int | None = None, sparse_budget: int | None = None, pair_sums: PairSums | None = None,
) -> dict[int, Dependence]:
    """Dependence of every label that has a model for each band of `data` (H x W x B pixels);
    `levels_seen` ({label: (lo, hi)}, `observed`) fills in the observed levels; `per_band`
    True keeps one autocorrelation row per band, False their average, None (the robot's
    choice) rows per band when some region's bands differ by more than ROW_SPREAD (one
    packet carries one row count, so the choice is the frame's); `corr_points` bounds the
    band correlations' lattice (default twice the anchors), `sparse_budget` the second pass's
    anchors (default max_anchors // SPARSE_SHARE); `pair_sums` (the host's) gives the grain's
    sums over every pixel pair in place of the anchors."""
    if data.ndim == 2:
        data = data[..., None]
    if data.ndim != 3 or labels.shape != data.shape[:2]:
        raise ValueError(f"data {data.shape} and labels {labels.shape} do not match")
    if max_anchors < 1 or chunk < 1:
        raise ValueError("max_anchors and chunk must be positive")
    check_radius(radius)
    n_bands = data.shape[2]
    regions = sorted({lab for lab, _ in models if all((lab, b) in models for b in range(n_bands))})
    if not regions:
        return {}
    index = np.full(max(int(labels.max(initial=0)), max(regions)) + 2, -1, dtype=np.int64)
    index[regions] = np.arange(len(regions))  # the last entry stays -1: negative labels land there
    centre = np.array([[_median(models[(lab, b)], levels) for b in range(n_bands)] for lab in regions],
                      dtype=np.float32)
    sums = _Sums(len(regions), n_bands, (radius + 1) * (2 * radius + 1))
    # anchors per chunk: at most `chunk`, fewer with many regions (see _Sums.pairs)
    chunk = max(1, min(chunk, PRODUCT_LIMIT // (len(regions) * (2 * radius + 1))))
    if pair_sums is None:
        _anchored(sums, data, labels, index, centre, radius, max_anchors, chunk, sparse_budget)
    else:
        sums.anchor_side[:], sums.partner[:] = pair_sums(data, labels, regions, centre, radius)
    live = np.array([[models[(lab, b)].family is not Family.CONST for b in range(n_bands)] for lab in regions])
    corrs = _band_correlations(data, labels, index, centre,
                               corr_points or CORR_ANCHORS * max_anchors // MAX_ANCHORS, chunk)
    pairs = sums.anchor_side[0]
    grains = [_window(sums.pearson(j), radius, pairs[j]) for j in range(len(regions))]
    shared = [g[keep].mean(axis=0) if keep.any() else np.zeros(g.shape[1]) for g, keep in zip(grains, live)]
    if per_band is None:
        per_band = n_bands > 1 and any(
            keep.any() and bool((np.abs(g[keep] - mean) > ROW_SPREAD + _noise(n, radius)).any())
            for g, keep, mean, n in zip(grains, live, shared, pairs))
    out = {}
    for j, lab in enumerate(regions):
        corr, grain = corrs[j], grains[j]
        rows_out = grain if per_band else shared[j][None]
        seen = (levels_seen or {}).get(lab, ((), ()))
        gaps = _unmeasured(pairs[j], radius)
        out[lab] = Dependence(tuple(corr[np.triu_indices(n_bands, 1)].tolist()),
                              tuple(tuple(row.tolist()) for row in rows_out), radius, *seen,
                              (gaps,) * len(rows_out) if gaps else ())
    return out


def _anchored(sums: _Sums, data: np.ndarray, labels: np.ndarray, index: np.ndarray, centre: np.ndarray,
              radius: int, max_anchors: int, chunk: int, sparse_budget: int | None) -> None:
    """The grain's sums from the anchor lattice, and a second pass for the sparse regions."""
    h, w = labels.shape
    grid = lattice(h, w, radius, max_anchors)
    for rows, col, nx in grid:
        per = max(1, chunk // nx)
        for start in range(0, len(rows), per):
            _chunk(sums, data, labels, rows[start:start + per], col, nx, index, centre, radius)
    sparse = np.flatnonzero(np.median(_pairs(sums, radius), axis=1) < SPARSE_PAIRS)
    met = sums.anchor_side[0][:, radius]  # the lattice's anchors per region: lag (0, 0)
    budget = max_anchors // SPARSE_SHARE if sparse_budget is None else sparse_budget
    extra = sparse_anchors(labels, index, sparse, met, radius, budget, grid)
    if extra is not None:  # the sparse regions' own pixels as anchors, added to their sums
        only, ys, xs = extra
        for start in range(0, len(ys), chunk):
            _points(sums, data, labels, ys[start:start + chunk], xs[start:start + chunk], only, centre, radius)


def _chunk(sums: _Sums, data: np.ndarray, labels: np.ndarray, rows: np.ndarray, col: int, nx: int,
           index: np.ndarray, centre: np.ndarray, radius: int) -> None:
    """One block of anchor rows: per window row dy, the frame's rows below the anchors, read as
    planes (bands x anchors x 2R+1 columns)."""
    width = 2 * radius + 1
    span, step = nx * width, int(rows[1] - rows[0]) if len(rows) > 1 else 1
    r0, r1 = int(rows[0]), int(rows[-1]) + 1
    n_bands = data.shape[2]
    anchor_labels = labels[r0:r1:step, col + radius:col + span:width]  # (ny, nx)
    ny, n = len(anchor_labels), anchor_labels.size
    region, present, onehot = _anchor_regions(anchor_labels, index, len(centre))
    if not present.size:
        return
    measured = region >= 0
    wide_labels = np.repeat(anchor_labels, width, axis=1)
    # every operand full-sized: a broadcast over a short inner axis runs far slower
    centres = np.repeat(centre[np.where(measured, region, 0)].T[:, :, None], width, axis=2)  # (B, n, 2R+1)
    values = np.empty((n_bands, ny, span), dtype=np.float32)
    inside = np.empty(wide_labels.shape, dtype=np.float32)
    for dy in range(radius + 1):
        np.equal(labels[r0 + dy:r1 + dy:step, col:col + span], wide_labels, out=inside, casting="unsafe")
        np.copyto(values, data[r0 + dy:r1 + dy:step, col:col + span].transpose(2, 0, 1), casting="unsafe")
        planes = values.reshape(n_bands, n, width)
        planes -= centres
        if dy == 0:  # the first window row holds the anchors themselves
            sums.anchors(onehot, planes[:, :, radius].copy(), width)
        sums.pairs(slice(dy * width, (dy + 1) * width), planes, inside.reshape(n, width))
    sums.flush(present)


def _anchor_regions(anchor_labels: np.ndarray, index: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(region of each anchor, -1 off the measured ones; the regions present; their one-hot
    rows over the anchors, K' x n)."""
    region = index[np.where(anchor_labels < 0, -1, anchor_labels)].reshape(anchor_labels.size)
    measured = region >= 0
    present = np.flatnonzero(np.bincount(region[measured], minlength=k))
    local = np.zeros(k, np.intp)
    local[present] = np.arange(len(present))
    onehot = np.zeros((len(present), anchor_labels.size), dtype=np.float32)
    onehot[local[region[measured]], np.flatnonzero(measured)] = 1.0
    return region, present, onehot


def _points(sums: _Sums, data: np.ndarray, labels: np.ndarray, ys: np.ndarray, xs: np.ndarray,
            index: np.ndarray, centre: np.ndarray, radius: int) -> None:
    """Anchors at (ys, xs), inside the frame by R: as `_chunk`, but each anchor's window rows
    gathered (the second pass's anchors lie on its regions' own pixels, not on a lattice)."""
    width, n_bands = 2 * radius + 1, data.shape[2]
    anchor_labels = labels[ys, xs]
    region, present, onehot = _anchor_regions(anchor_labels, index, len(centre))
    if not present.size:
        return
    # each anchor's whole window, one gather: (n, R+1, 2R+1) labels, (n, B, R+1, 2R+1) values
    lab = sliding_window_view(labels, (radius + 1, width))[ys, xs - radius]
    val = sliding_window_view(data, (radius + 1, width), axis=(0, 1))[ys, xs - radius]
    centres = np.repeat(centre[np.where(region >= 0, region, 0)].T[:, :, None], width, axis=2)
    planes = np.empty((n_bands, len(ys), width), dtype=np.float32)
    inside = np.empty((len(ys), width), dtype=np.float32)
    for dy in range(radius + 1):
        np.equal(lab[:, dy], anchor_labels[:, None], out=inside, casting="unsafe")
        np.copyto(planes, val[:, :, dy].transpose(1, 0, 2), casting="unsafe")
        planes -= centres
        if dy == 0:
            sums.anchors(onehot, planes[:, :, radius].copy(), width)
        sums.pairs(slice(dy * width, (dy + 1) * width), planes, inside)
    sums.flush(present)


def _pairs(sums: _Sums, radius: int) -> np.ndarray:
    """(regions, window): the pairs each lag holds, the lags (0, dx) counted on both sides."""
    out = _window(sums.anchor_side[0], radius)
    out[:, :radius] *= 2
    return out


def _band_correlations(data: np.ndarray, labels: np.ndarray, index: np.ndarray, centre: np.ndarray,
                       max_points: int, chunk: int) -> np.ndarray:
    """(regions, B, B) band correlation matrices from a lattice over the whole frame, its edges
    included (the window's anchors keep R pixels off them, which biased regions that lie there)."""
    h, w, n_bands = data.shape
    step = max(1, math.ceil(math.sqrt(h * w / max(1, max_points))))
    step += 1 - step % 2  # odd: an even step reads one phase of every 2x2 Bayer and 8x8 JPEG block
    k = len(centre)
    pairs = [(b, c) for b in range(n_bands) for c in range(b + 1)]
    sums = np.zeros((k, 1 + n_bands + len(pairs)))  # n, sum x_b, sum x_b x_c
    cols = np.arange((w - 1) % step // 2, w, step)
    per = max(1, 2 * chunk // len(cols))  # rows of points per block: blocks of about 2 chunks
    for r0 in range(((h - 1) % step) // 2, h, step * per):
        lab = labels[r0:r0 + step * per:step, cols[0]::step].reshape(-1)
        region = index[np.where(lab < 0, -1, lab)]
        inside = region >= 0
        if not inside.any():
            continue
        region = region[inside]
        x = data[r0:r0 + step * per:step, cols[0]::step].reshape(-1, n_bands)[inside].astype(np.float32)
        x -= centre[region]
        columns = np.empty((len(region), sums.shape[1]), np.float32)
        columns[:, 0] = 1.0
        columns[:, 1:1 + n_bands] = x
        for q, (b, c) in enumerate(pairs):
            np.multiply(x[:, b], x[:, c], out=columns[:, 1 + n_bands + q])
        for j in range(sums.shape[1]):  # per column one bincount: no matrix product, no BLAS threads
            sums[:, j] += np.bincount(region, columns[:, j], minlength=k)
    out = []
    for j in range(k):
        s2 = np.zeros((n_bands, n_bands))
        for q, (b, c) in enumerate(pairs):
            s2[b, c] = s2[c, b] = sums[j, 1 + n_bands + q]
        out.append(_pearson_matrix(sums[j, 0], sums[j, 1:1 + n_bands], s2))
    return np.array(out)


def _noise(n: np.ndarray, radius: int) -> np.ndarray:
    """Per window lag, from a region's pair counts per window position `n`: three standard
    errors of a correlation (at most 1 / sqrt(n) each), the most that bands alike in grain
    differ by over the window from sampling alone."""
    return 3.0 / np.sqrt(np.maximum(_window(n[None], radius)[0], 1.0))


def _window(r: np.ndarray, radius: int, n: np.ndarray | None = None) -> np.ndarray:
    """(B, window) in record order from (B, positions): the lags (0, dx) from both sides of the
    anchor (weighted alike: each side a like number of pairs); given the pair counts `n`
    (positions), a side with fewer than MIN_PAIRS is left out rather than averaged in as 0."""
    width = 2 * radius + 1
    right = r[:, radius + 1:width]
    left = r[:, radius - 1::-1][:, :radius]
    if n is None:
        return np.concatenate([0.5 * (right + left), r[:, width:]], axis=1)
    sides = (n[radius + 1:width] >= MIN_PAIRS).astype(int) + (n[radius - 1::-1][:radius] >= MIN_PAIRS)
    return np.concatenate([(right + left) / np.maximum(sides, 1), r[:, width:]], axis=1)


def _unmeasured(n: np.ndarray, radius: int) -> tuple[int, ...]:
    """Window indices of a region's lags with fewer than MIN_PAIRS pairs (on either side, for (0, dx))."""
    width = 2 * radius + 1
    side = n >= MIN_PAIRS
    known = np.concatenate([side[radius + 1:width] | side[radius - 1::-1][:radius], side[width:]])
    return tuple(np.flatnonzero(~known).tolist())


def _median(model: Johnson, levels: int) -> float:
    """The model's median within the levels, in scalar arithmetic (x_of_z's arrays cost more than
    the rest of a small pass); the centre only keeps the float32 sums accurate."""
    g, d, xi, lam = model.gamma, model.delta, model.xi, model.lam
    w = min(max(-g / d, -700.0), 700.0)
    if model.family is Family.CONST:
        x = xi
    elif model.family is Family.SN:
        x = xi + lam * w
    elif model.family is Family.SU:
        x = xi + lam * math.sinh(w)
    elif model.family is Family.SB:
        x = xi + lam / (1.0 + math.exp(-w))
    else:
        x = xi + lam * math.exp(w if lam > 0 else -w)
    return min(max(x, 0.0), levels - 1.0) if math.isfinite(x) else (levels - 1.0 if x > 0 else 0.0)


def _pearson_matrix(n: float, s1: np.ndarray, s2: np.ndarray) -> np.ndarray:
    b = len(s1)
    if n < MIN_PAIRS:
        return np.eye(b)
    mean = s1 / n
    cov = s2 / n - np.outer(mean, mean)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    den = np.outer(sd, sd)
    with np.errstate(all="ignore"):
        r = np.where(den > 1e-9, cov / den, 0.0)
    np.fill_diagonal(r, 1.0)
    return np.clip(np.nan_to_num(r, nan=0.0), -1.0, 1.0)
