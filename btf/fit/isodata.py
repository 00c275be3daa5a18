"""Ball & Hall ISODATA clustering of pixel feature vectors, shared by robot and host.

Clusters are found on a bounded, seeded pixel subsample (fixed memory, at most
`iterations` passes), then every pixel is given its nearest centre in bounded
chunks. Follows Tou & Gonzalez's statement of the algorithm: discard small
clusters, split clusters with a large spread, merge close pairs.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

CHUNK_PIXELS = 1 << 16
MAX_LABELS = 255  # labels travel as uint8


def _dot(x: np.ndarray, m: np.ndarray) -> np.ndarray:
    """x @ m of float32 pixels by a few centres: einsum's own loop, several times faster than
    a BLAS call on such thin matrices (and no BLAS threads contending for the cores)."""
    return np.einsum("ij,jk->ik", x, m)


@dataclass(frozen=True)
class IsodataParams:
    k: int = 4  # desired number of clusters
    min_samples: int = 50  # clusters with fewer subsample members are dissolved
    split_std: float = 10.0  # split a cluster whose largest per-band std exceeds this
    merge_distance: float = 15.0  # merge centres closer than this
    max_merges: int = 2  # merges per iteration
    iterations: int = 8
    subsample: int = 20000
    seed: int = 0
    init_clusters: int | None = None  # starting count, default k
    split_gain: float = 0.5  # new centres at +-gain * std along the widest band

    def __post_init__(self) -> None:
        if not 1 <= self.k <= 128:
            raise ValueError(f"isodata: k must be in 1..128, got {self.k}")
        if self.min_samples < 1:
            raise ValueError(f"isodata: min_samples must be >= 1, got {self.min_samples}")
        if not (np.isfinite(self.split_std) and self.split_std > 0):
            raise ValueError(f"isodata: split_std must be positive, got {self.split_std}")
        if not (np.isfinite(self.merge_distance) and self.merge_distance >= 0):
            raise ValueError(f"isodata: merge_distance must be >= 0, got {self.merge_distance}")
        if self.max_merges < 0 or self.iterations < 1:
            raise ValueError("isodata: max_merges must be >= 0 and iterations >= 1")
        if self.subsample < 1:
            raise ValueError(f"isodata: subsample must be >= 1, got {self.subsample}")
        if self.init_clusters is not None and not 1 <= self.init_clusters <= self.max_clusters:
            raise ValueError(f"isodata: init_clusters must be in 1..{self.max_clusters}")
        if not 0 < self.split_gain <= 1:
            raise ValueError(f"isodata: split_gain must be in (0, 1], got {self.split_gain}")

    @property
    def max_clusters(self) -> int:
        return min(2 * self.k, MAX_LABELS)


@dataclass(frozen=True)
class IsodataResult:
    centres: np.ndarray  # n_clusters x bands, float64
    labels: np.ndarray  # data's leading shape, uint8; label i is centres[i]


def _pixels(data: np.ndarray) -> np.ndarray:
    data = np.asarray(data)
    if data.ndim < 2 or data.shape[-1] < 1 or data.size == 0:
        raise ValueError(f"isodata: data must be (..., bands) and non-empty, got shape {data.shape}")
    if not (np.issubdtype(data.dtype, np.integer) or np.issubdtype(data.dtype, np.floating)):
        raise ValueError(f"isodata: data must be numeric, got {data.dtype}")
    x = data.reshape(-1, data.shape[-1])
    if np.issubdtype(x.dtype, np.floating) and not np.all(np.isfinite(x)):
        raise ValueError("isodata: data contains NaN or inf")
    return x


def subsample(x: np.ndarray, size: int, seed: int) -> np.ndarray:
    """A seeded sample of `size` rows (all rows if fewer), float64, in original order.

    Drawn with replacement: O(size) time and memory whatever the frame size.
    """
    if len(x) <= size:
        return x.astype(np.float64)
    idx = np.random.default_rng(seed).integers(0, len(x), size)
    return x[np.sort(idx)].astype(np.float64)


def _nearest(x: np.ndarray, c: np.ndarray) -> np.ndarray:
    d = (c * c).sum(axis=1)[None, :] - 2.0 * (x @ c.T)
    return np.argmin(d, axis=1)


def _init(x: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """k-means++ seeding; stops early when every sample already sits on a centre."""
    centres = [x[rng.integers(len(x))]]
    d2 = ((x - centres[0]) ** 2).sum(axis=1)
    while len(centres) < n and d2.sum() > 0:
        centres.append(x[rng.choice(len(x), p=d2 / d2.sum())])
        d2 = np.minimum(d2, ((x - centres[-1]) ** 2).sum(axis=1))
    return np.array(centres)


def _update(x: np.ndarray, c: np.ndarray, min_samples: int) -> tuple[np.ndarray, np.ndarray]:
    """Assign, dissolve clusters under `min_samples` (keeping at least one), recompute means."""
    lab = _nearest(x, c)
    counts = np.bincount(lab, minlength=len(c))
    keep = counts >= min_samples
    if not keep.any():
        keep = counts == counts.max()
    while not keep.all():  # dissolving can empty no kept cluster, but be sure
        c = c[keep]
        lab = _nearest(x, c)
        counts = np.bincount(lab, minlength=len(c))
        keep = counts > 0
    sums = np.stack([np.bincount(lab, weights=x[:, b], minlength=len(c)) for b in range(x.shape[1])], 1)
    return sums / counts[:, None], lab


def _split(x: np.ndarray, c: np.ndarray, lab: np.ndarray, p: IsodataParams) -> np.ndarray:
    n = len(c)
    counts = np.bincount(lab, minlength=n)
    dist = np.sqrt(((x - c[lab]) ** 2).sum(axis=1))
    mean_d = np.bincount(lab, weights=dist, minlength=n) / counts
    overall = dist.mean()
    out = []
    room = p.max_clusters - n
    for j in range(n):
        members = x[lab == j]
        std = members.std(axis=0)
        b = int(np.argmax(std))
        big = mean_d[j] > overall and counts[j] > 2 * (p.min_samples + 1)
        if room > 0 and std[b] > p.split_std and (big or n <= p.k / 2):
            step = np.zeros(c.shape[1])
            step[b] = p.split_gain * std[b]
            out += [c[j] + step, c[j] - step]
            room -= 1
        else:
            out.append(c[j])
    return np.array(out)


def _merge(c: np.ndarray, lab: np.ndarray, p: IsodataParams) -> np.ndarray:
    n = len(c)
    if n < 2 or p.max_merges == 0:
        return c
    counts = np.bincount(lab, minlength=n).astype(np.float64)
    d = np.sqrt(((c[:, None, :] - c[None, :, :]) ** 2).sum(axis=2))
    i, j = np.triu_indices(n, 1)
    order = np.argsort(d[i, j], kind="stable")
    used = np.zeros(n, bool)
    merged, merges = [], 0
    for o in order:
        a, b = i[o], j[o]
        if d[a, b] >= p.merge_distance or merges >= p.max_merges:
            break
        if used[a] or used[b]:
            continue
        used[a] = used[b] = True
        merged.append((c[a] * counts[a] + c[b] * counts[b]) / (counts[a] + counts[b]))
        merges += 1
    if not merges:
        return c
    return np.vstack([c[~used]] + merged)


def fit_centres(samples: np.ndarray, p: IsodataParams) -> np.ndarray:
    """ISODATA on a (n, bands) float sample; returns centres sorted lexicographically."""
    x = np.asarray(samples, dtype=np.float64)
    rng = np.random.default_rng(p.seed)
    c = _init(x, min(p.init_clusters or p.k, len(x)), rng)
    for it in range(1, p.iterations + 1):
        before = c
        c, lab = _update(x, c, p.min_samples)
        if it == p.iterations:
            break
        n = len(c)
        tried_split = n <= p.k / 2 or (it % 2 == 1 and n < 2 * p.k)
        if tried_split:
            split = _split(x, c, lab, p)
            if len(split) > n:
                c = split
                continue
        merged = _merge(c, lab, p)
        still = len(before) == n and np.abs(before - c).max() < 1e-3 and len(merged) == n
        if still and (tried_split or len(_split(x, c, lab, p)) == n):
            break  # nothing moved, split or merged: further passes would repeat this one
        c = merged
    c, _ = _update(x, c, p.min_samples)
    return c[np.lexsort(c.T[::-1])]


def _distance_matrix(centres: np.ndarray) -> np.ndarray:
    """[-2c, |c|^2] so that [x, 1] @ m is |x - c|^2 - |x|^2: one product, no broadcast add."""
    c = centres
    return np.vstack([-2.0 * c.T, (c * c).sum(axis=1)[None, :]]).astype(np.float32)


def _nearest_f32(x: np.ndarray, m: np.ndarray, out: np.ndarray) -> None:
    b = x.shape[1]
    for a in range(0, len(x), CHUNK_PIXELS):
        chunk = x[a:a + CHUNK_PIXELS]
        xb = np.ones((len(chunk), b + 1), dtype=np.float32)
        xb[:, :b] = chunk
        out[a:a + CHUNK_PIXELS] = np.argmin(_dot(xb, m), axis=1)


_CELL = np.arange(32) * 8 + 3.5
_GRID = np.stack(np.meshgrid(_CELL, _CELL, _CELL, indexing="ij"), -1).reshape(-1, 3)
_GRID_SQ = (_GRID * _GRID).sum(axis=1)
_CELL_RADIUS = np.sqrt(3) * 3.5
_SUB = np.stack(np.meshgrid(*[np.arange(8)] * 3, indexing="ij"), -1).reshape(-1, 3)


def _colour_lut(c: np.ndarray) -> np.ndarray:
    """Label per 8x8x8 colour cell, or 255 where the cell straddles a decision boundary.

    For p in a cell with centre q, |p-ci|^2 - |p-cj|^2 differs from its value at q by
    at most 2*|p-q|*|ci-cj|; a cell whose margin beats that bound for every rival
    centre has one label for all its colours.
    """
    d = (c * c).sum(axis=1)[None, :] - 2.0 * (_GRID @ c.T)  # + |q|^2, common to all centres
    best = np.argmin(d, axis=1)
    rows = np.arange(len(d))
    sep = np.sqrt(((c[:, None, :] - c[None, :, :]) ** 2).sum(axis=2))
    margin = d - d[rows, best][:, None] - 2 * _CELL_RADIUS * sep[best] - 1e-6 * (1 + _GRID_SQ[:, None])
    margin[rows, best] = np.inf
    lut = best.astype(np.uint8)
    lut[(margin <= 0).any(axis=1)] = 255
    return lut


class Labeller:
    """Nearest-centre labelling with tables built once for a set of centres.

    Centres are a property of the scene, so the tables are built once and every frame
    of the scene only looks labels up. 8-bit data with 3 bands gets a label for each of
    the 2^24 colours (16 MB), built from a 32^3 table of colour cells and an exact 8^3
    sub-table only for the cells that straddle a decision boundary; a frame is then one
    lookup per pixel, its three bytes read as one word. 8-bit data with 1 or 2 bands
    tabulates every value. Other data goes through a float32 distance matmul.
    `names[i]` is the label written for centre i (default i), e.g. a palette id.
    """

    def __init__(self, centres: np.ndarray, names: np.ndarray | None = None) -> None:
        c = np.asarray(centres, dtype=np.float64)
        if c.ndim != 2 or c.shape[1] < 1 or not 1 <= len(c) <= MAX_LABELS or not np.all(np.isfinite(c)):
            raise ValueError(f"isodata: centres must be a finite (1..{MAX_LABELS}, bands) array, got {c.shape}")
        self.centres = c
        self.names = np.arange(len(c), dtype=np.uint8) if names is None else np.asarray(names, np.uint8)
        if self.names.shape != (len(c),):
            raise ValueError(f"isodata: {len(self.names)} names for {len(c)} centres")
        self._m = _distance_matrix(c)
        self._table: np.ndarray | None = None  # 1-2 bands: label per value
        self._colours: np.ndarray | None = None  # 3 bands: label per colour r + 256 g + 65536 b

    @property
    def bands(self) -> int:
        return self.centres.shape[1]

    def _general(self, x: np.ndarray, out: np.ndarray) -> None:
        if len(self.centres) == 1:
            out[:] = self.names[0]
        else:
            _nearest_f32(x, self._m, out)
            out[:] = self.names[out]

    def _build_small(self) -> np.ndarray:
        b = self.bands
        grid = np.stack(np.meshgrid(*[np.arange(256)] * b, indexing="ij"), -1).reshape(-1, b)
        table = np.empty(len(grid), dtype=np.uint8)
        self._general(grid, table)
        return table

    def _build_colour(self) -> None:
        coarse = _colour_lut(self.centres) if len(self.centres) > 1 else np.zeros(32768, np.uint8)
        unsure = np.flatnonzero(coarse == 255)
        n = len(self.centres)
        # Blocks 0..n-1 are constant (one per centre), then one exact block per unsure cell.
        fine = np.empty((n + len(unsure)) * 512, dtype=np.uint8)
        fine[:n * 512] = np.repeat(self.names, 512)
        block = coarse.astype(np.intp)
        block[unsure] = n + np.arange(len(unsure))
        cells = np.stack([unsure >> 10, (unsure >> 5) & 31, unsure & 31], 1) * 8
        step = max(1, CHUNK_PIXELS // 512)
        for a in range(0, len(unsure), step):
            colours = (cells[a:a + step, None, :] + _SUB[None]).reshape(-1, 3)
            lo = (n + a) * 512
            self._general(colours, fine[lo:lo + len(colours)])
        # Every colour's label, laid out as a little-endian word of its bytes r, g, b reads:
        # (b cell, b offset, g cell, g offset, r cell, r offset); one blue cell at a time.
        blocks, cell_block = fine.reshape(-1, 8, 8, 8), block.reshape(32, 32, 32)
        table = np.empty((32, 8, 32, 8, 32, 8), dtype=np.uint8)
        for b in range(32):
            table[b] = blocks[cell_block[:, :, b]].transpose(4, 1, 3, 0, 2)
        self._colours = table.reshape(-1)

    def _assign_colours(self, x: np.ndarray, out: np.ndarray) -> None:
        """Labels of (n, 3) uint8 pixels: each pixel's bytes r, g, b and the next one's r read
        as one little-endian word, masked to 24 bits, looked up (the last pixel on its own)."""
        if not x.flags.c_contiguous:
            x = np.ascontiguousarray(x)
        n = len(x)
        words = np.ndarray((n - 1,), dtype="<u4", buffer=x.reshape(-1), strides=(3,))
        key = np.empty(min(CHUNK_PIXELS, n), dtype=np.uint32)
        for a in range(0, n - 1, CHUNK_PIXELS):
            w = words[a:a + CHUNK_PIXELS]
            k = key[:len(w)]
            np.bitwise_and(w, 0xFFFFFF, out=k)
            np.take(self._colours, k, out=out[a:a + len(w)])
        r, g, b = (int(v) for v in x[-1])
        out[-1] = self._colours[r | g << 8 | b << 16]

    def assign(self, data: np.ndarray) -> np.ndarray:
        """Label (uint8) of the nearest centre for every pixel of (..., bands) data, in bounded chunks."""
        x = _pixels(data)
        if x.shape[1] != self.bands:
            raise ValueError(f"isodata: centres shape {self.centres.shape} does not fit data with {x.shape[1]} bands")
        out = np.empty(len(x), dtype=np.uint8)
        if x.dtype != np.uint8 or self.bands > 3 or len(self.centres) == 1:
            self._general(x, out)
        elif self.bands < 3:
            if self._table is None:
                self._table = self._build_small()
            for a in range(0, len(x), CHUNK_PIXELS):
                chunk = x[a:a + CHUNK_PIXELS]
                key = chunk[:, 0].astype(np.intp)
                if self.bands == 2:
                    key = (key << 8) | chunk[:, 1]
                np.take(self._table, key, out=out[a:a + CHUNK_PIXELS])
        else:
            if self._colours is None:
                self._build_colour()
            self._assign_colours(x, out)
        return out.reshape(np.shape(data)[:-1])


def assign(data: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Nearest-centre label (uint8) for every pixel, in bounded chunks.

    For one frame: 8-bit colour pixels in cells off every decision boundary are looked
    up, the rest go through the distance matmul (building the exact sub-tables of a
    `Labeller` only pays off over several frames of a scene).
    """
    x = _pixels(data)
    c = np.asarray(centres, dtype=np.float64)
    if c.ndim != 2 or c.shape[1] != x.shape[1] or not 1 <= len(c) <= MAX_LABELS:
        raise ValueError(f"isodata: centres shape {c.shape} does not fit data with {x.shape[1]} bands")
    if x.dtype != np.uint8 or x.shape[1] != 3 or len(c) == 1:
        return Labeller(c).assign(data)
    m = _distance_matrix(c)
    lut = _colour_lut(c)
    out = np.empty(len(x), dtype=np.uint8)
    for a in range(0, len(x), CHUNK_PIXELS):
        chunk = x[a:a + CHUNK_PIXELS]
        key = (chunk[:, 0] >> 3).astype(np.uint16) << 10  # 15-bit cell index fits uint16
        key |= (chunk[:, 1] >> 3).astype(np.uint16) << 5
        key |= chunk[:, 2] >> 3
        lab = lut[key]
        unsure = np.flatnonzero(lab == 255)
        if len(unsure):
            fix = np.empty(len(unsure), dtype=np.uint8)
            _nearest_f32(chunk[unsure], m, fix)
            lab[unsure] = fix
        out[a:a + CHUNK_PIXELS] = lab
    return out.reshape(np.shape(data)[:-1])


def nearest_centres(sample: np.ndarray, centres: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each sample row's nearest centre and its distance to it."""
    x = np.asarray(sample, dtype=np.float64)
    c = np.asarray(centres, dtype=np.float64)
    d = (c * c).sum(axis=1)[None, :] - 2.0 * (x @ c.T)  # the squared distance less |x|^2
    nearest = np.argmin(d, axis=1)
    d2 = np.take_along_axis(d, nearest[:, None], axis=1)[:, 0] + np.einsum("ij,ij->i", x, x)
    return nearest, np.sqrt(np.maximum(d2, 0.0))


def spread(sample: np.ndarray, centres: np.ndarray) -> float:
    """Mean distance from each sample row to its nearest centre: how well centres fit data."""
    return float(nearest_centres(sample, centres)[1].mean())


def light_gain(sample: np.ndarray, centres: np.ndarray, rounds: int = 2, start: float = 1.0) -> float:
    """The one gain g over all bands for which g * centres fit the sample best (least squares,
    each row against its nearest scaled centre, `rounds` times from `start`): how much brighter
    the view is than the one the centres were fitted on. Clipped to [1/4, 4]."""
    x = np.asarray(sample, dtype=np.float64)
    c = np.asarray(centres, dtype=np.float64)
    g = start
    for _ in range(rounds):
        near = c[_nearest(x, g * c)]
        energy = float((near * near).sum())
        if energy <= 0.0:
            return 1.0
        g = min(max(float((x * near).sum()) / energy, 0.25), 4.0)
    return g


def _label_counts(labels: np.ndarray, n: int) -> np.ndarray:
    """Pixels per label, in chunks: bincount of the whole map would copy it as intp."""
    counts = np.zeros(n, np.int64)
    for a in range(0, len(labels), CHUNK_PIXELS):
        counts += np.bincount(labels[a:a + CHUNK_PIXELS], minlength=n)
    return counts


def isodata(data: np.ndarray, params: IsodataParams = IsodataParams()) -> IsodataResult:
    """Cluster `data` (..., bands) and label every pixel; no empty cluster is returned."""
    x = _pixels(data)
    c = fit_centres(subsample(x, params.subsample, params.seed), params)
    labels = assign(data, c)
    counts = _label_counts(labels.reshape(-1), len(c))
    if (counts == 0).any():  # a centre may lose its last member in the full assignment
        c = c[counts > 0]
        labels = assign(data, c)
    return IsodataResult(centres=c, labels=labels)
