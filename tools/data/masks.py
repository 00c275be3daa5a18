"""Label masks from an image for `btf-host mask`: ISODATA, k-means, Felzenszwalb, SLIC.

Labels 0..K-1 are ordered darkest first, so masks are stable across runs and methods.
Memory beyond the image stays near the mask itself: ISODATA labels in bounded chunks, every
relabelling goes through a lookup table row tile by row tile, and the bottom-up methods
(Felzenszwalb, SLIC), whose working memory is hundreds of bytes per pixel, segment even
tiles of at most `SEGMENT_TILE` pixels a side (1024 and 2048). Their segments are merged into K
classes by k-means on mean colours over the whole image; an image within one tile is segmented
whole; in a larger one no segment crosses a tile border (Felzenszwalb's classes show no seam,
SLIC's class borders partly follow the tile borders where its superpixels are cut).
"""
from __future__ import annotations

import math
import warnings

import numpy as np

from btf.fit.isodata import IsodataParams, isodata
from tools.analysis.tiles import label_counts, row_tiles

METHODS = ("isodata", "kmeans", "felzenszwalb", "slic")
# Tile sides: Felzenszwalb holds ~340 bytes a pixel and its tiles do not show; SLIC ~130, and
# its class borders follow tile borders where superpixels are cut, so it gets larger tiles.
SEGMENT_TILE = {"felzenszwalb": 1024, "slic": 2048}


def relabel(labels: np.ndarray, table: np.ndarray) -> np.ndarray:
    """uint8 table[labels], row tile by row tile (no full-size index copy)."""
    lut = np.asarray(table).astype(np.uint8)
    out = np.empty(labels.shape, dtype=np.uint8)
    for r in row_tiles(labels.shape[0], int(np.prod(labels.shape[1:], dtype=np.int64))):
        out[r] = lut[labels[r]]
    return out


def _rank(centres: np.ndarray) -> np.ndarray:
    """Class of each centre: 0 for the darkest (sum of bands), ties by index."""
    order = np.argsort(centres.sum(axis=1), kind="stable")
    rank = np.empty(len(order), np.int64)
    rank[order] = np.arange(len(order))
    return rank


def _distinct_ranks(centres: np.ndarray) -> np.ndarray:
    """Class of each centre, darkest first, centres of one colour in one class: k-means splits
    identical pixels between centres when the image has fewer colours than classes."""
    distinct, inverse = np.unique(centres, axis=0, return_inverse=True)
    return _rank(distinct)[inverse.reshape(-1)]


def _compact_rank(labels: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Table from raw labels to ordered classes, after dropping labels no pixel uses."""
    used = np.array(list(label_counts(labels)), np.int64)
    table = np.zeros(len(centres), np.int64)
    table[used] = _distinct_ranks(centres[used])
    return table


def _isodata(image: np.ndarray, k: int, seed: int) -> np.ndarray:
    res = isodata(image, IsodataParams(k=k, seed=seed))
    return relabel(res.labels, _rank(res.centres))


def _kmeans(image: np.ndarray, k: int, seed: int) -> np.ndarray:
    import cv2

    cv2.setRNGSeed(seed)
    px = image.reshape(-1, image.shape[2]).astype(np.float32)  # what cv2.kmeans takes
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 20, 0.5)
    _, lab, centres = cv2.kmeans(px, k, None, crit, 3, cv2.KMEANS_PP_CENTERS)
    del px
    lab = lab.reshape(image.shape[:2])
    return relabel(lab, _compact_rank(lab, centres.astype(np.float64)))


def _bounds(size: int, tile: int, step: float) -> list[int]:
    """Tile borders along one axis: as few even tiles as fit `tile`, snapped to multiples of
    `step` (SLIC's grid of superpixel seeds) so no superpixel's seed cell is cut in two."""
    parts = math.ceil(size / tile)
    cuts = {0, size}
    for k in range(1, parts):
        cut = round(round(size * k / parts / step) * step)
        if 0 < cut < size:
            cuts.add(cut)
    return sorted(cuts)


def _segment_tiles(image: np.ndarray, method: str, scale: float, segments: int, tile: int) -> np.ndarray:
    """int32 segment ids over the image, segmented tile by tile (ids unique across tiles)."""
    from skimage.segmentation import felzenszwalb, slic

    h, w = image.shape[:2]
    step = math.sqrt(h * w / segments)  # SLIC's superpixel side over the whole image
    rows, cols = _bounds(h, tile, step), _bounds(w, tile, step)
    out = np.empty((h, w), np.int32)
    n = 0
    for r0, r1 in zip(rows, rows[1:]):
        for c0, c1 in zip(cols, cols[1:]):
            part = image[r0:r1, c0:c1]
            if method == "felzenszwalb":
                with warnings.catch_warnings():  # more than three bands are meant: a multi-spectral image
                    warnings.filterwarnings("ignore", "Got image with third dimension", RuntimeWarning)
                    seg = felzenszwalb(part, scale=scale, sigma=0.8, min_size=20)
            else:  # superpixels of the whole image's size
                share = max(1, round(segments * (r1 - r0) * (c1 - c0) / (h * w)))
                seg = slic(part, n_segments=share, compactness=10, start_label=0)
            out[r0:r1, c0:c1] = seg + n
            n += int(seg.max()) + 1
    return out


def _merge_segments(image: np.ndarray, segments: np.ndarray, k: int, seed: int) -> np.ndarray:
    """Merge bottom-up segments into k classes by clustering their mean colours."""
    from scipy.cluster.vq import kmeans2

    n = int(segments.max()) + 1
    counts = np.zeros(n)
    bands = image.shape[2]
    sums = np.zeros((n, bands))
    for r in row_tiles(*segments.shape):
        seg = segments[r].ravel()
        counts += np.bincount(seg, minlength=n)
        px = image[r].reshape(-1, bands)
        for c in range(bands):  # integer sums: exact in any order
            sums[:, c] += np.bincount(seg, px[:, c].astype(np.float64), n)
    means = sums / np.maximum(counts, 1)[:, None]
    present = counts > 0
    if len(np.unique(means[present], axis=0)) <= k:  # no more colours than classes: one class each
        table = np.zeros(n, np.int64)
        table[present] = _distinct_ranks(means[present])
        return relabel(segments, table)
    centres, cls = kmeans2(means[present], k, minit="++", seed=seed)
    full = np.zeros(n, np.int64)
    full[present] = cls
    classes = np.zeros(k, np.int64)
    used = np.unique(cls)
    classes[used] = _rank(centres[used])
    return relabel(segments, classes[full])


def segment(image: np.ndarray, method: str, k: int, seed: int = 0, scale: float = 100.0,
            segments: int = 400, tile: int | None = None) -> np.ndarray:
    """A uint8 mask of `image` (H x W x bands uint8: three for colour, or a multi-spectral
    image's own) with classes 0..K-1, darkest first; Felzenszwalb and SLIC segment tiles of at
    most `tile` (default SEGMENT_TILE) pixels a side."""
    if method == "isodata":
        return _isodata(image, k, seed)
    if method == "kmeans":
        return _kmeans(image, k, seed)
    if method not in METHODS:
        raise ValueError(f"unknown mask method {method!r}; expected one of {', '.join(METHODS)}")
    tile = SEGMENT_TILE[method] if tile is None else tile
    if tile < 16:
        raise ValueError(f"segment tiles must be at least 16 pixels a side, got {tile}")
    return _merge_segments(image, _segment_tiles(image, method, scale, segments, tile), k, seed)
