"""A region's grain sums over every pixel pair, for the host's dependence pass.

The robot reads a region's autocorrelation from a lattice of a few thousand anchors
(btf.fit.dependence), in fixed memory. The host has the whole photograph and reads every pair
instead: per region and window lag, the pair count and the sums of a, a^2 (anchor) and b, a b,
b^2 (partner) that `measure` turns into Pearson correlations, each from zero-padded FFT
correlations of the region's masked values over its bounding box. The anchors missed the
photograph's own autocorrelation by up to 0.20 on a scattered class (the rocket's specks) and
0.02-0.08 on the others; every pair misses it by nothing.

A box larger than BLOCK_PIXELS is read as blocks of anchor rows, each with its partners' R
rows below, spread evenly over the box up to BLOCK_PIXELS anchor pixels in all: memory and time
stay bounded on a large photograph, and its sums still come from millions of anchors.
"""
from __future__ import annotations

import numpy as np
import scipy.fft as sfft

from tools.analysis.tiles import workers

BLOCK_PIXELS = 1 << 21  # anchor pixels read per region: every one of a 2 MP box


def every_pair(data: np.ndarray, labels: np.ndarray, regions: list[int], centre: np.ndarray,
               radius: int) -> tuple[np.ndarray, np.ndarray]:
    """(anchor side (1 + 2B, K, positions): n, sum a, sum a^2; partner (3, B, K, positions):
    sum b, sum a b, sum b^2) for regions (K labels) of data (H x W x B), values centred on
    `centre` (K x B), positions the half-plane window's rows dy = 0..R by dx = -R..R."""
    n_bands = data.shape[2]
    positions = (radius + 1) * (2 * radius + 1)
    side = np.zeros((1 + 2 * n_bands, len(regions), positions))
    partner = np.zeros((3, n_bands, len(regions), positions))
    for j, lab in enumerate(regions):
        inside = labels == lab
        rows, cols = np.flatnonzero(inside.any(axis=1)), np.flatnonzero(inside.any(axis=0))
        if rows.size == 0:
            continue
        box = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
        for anchors in _blocks(box[0].stop - box[0].start, box[1].stop - box[1].start, radius):
            part = slice(box[0].start + anchors.start, min(box[0].stop, box[0].start + anchors.stop + radius))
            s, p = _block(data[part, box[1]], inside[part, box[1]], anchors.stop - anchors.start,
                          centre[j], radius)
            side[:, j] += s
            partner[:, :, j] += p
    return side, partner


def _blocks(h: int, w: int, radius: int) -> list[slice]:
    """Anchor rows of a box: all of them, or blocks spread evenly up to BLOCK_PIXELS pixels."""
    if h * w <= BLOCK_PIXELS:
        return [slice(0, h)]
    rows = min(h, max(4 * radius, BLOCK_PIXELS // (4 * w)))  # a quarter of the budget a block, taller than the window
    count = max(1, min(h // rows, BLOCK_PIXELS // (rows * w)))
    starts = np.linspace(0, h - rows, count).astype(int)
    return [slice(int(s), int(s) + rows) for s in np.unique(starts)]


def _block(values: np.ndarray, inside: np.ndarray, anchor_rows: int, centre: np.ndarray,
           radius: int) -> tuple[np.ndarray, np.ndarray]:
    """One block's sums: anchors in its first `anchor_rows` rows, partners anywhere in it. The
    transforms are float32, every band in one call: the sums come out within about 1e-6 of
    their size (values centred on the region's median), the pair counts exact once rounded."""
    h, w, n_bands = values.shape
    shape = (sfft.next_fast_len(h + radius, real=True), sfft.next_fast_len(w + radius, real=True))
    threads = workers(shape[0] * shape[1])
    dy = np.repeat(np.arange(radius + 1), 2 * radius + 1)
    dx = np.tile(np.arange(-radius, radius + 1), radius + 1)
    at = (slice(None), dy % shape[0], dx % shape[1])
    back = (slice(None), (-dy) % shape[0], (-dx) % shape[1])  # sum_p x(p) m(p + h) = sum_q m(q) x(q - h)
    # m, then v and v^2 per band (centred, 0 off the region), zero-padded to the transform's grid
    planes = np.zeros((1 + 2 * n_bands,) + shape, np.float32)
    mask, v, q = planes[0, :h, :w], planes[1:1 + n_bands, :h, :w], planes[1 + n_bands:, :h, :w]
    mask[inside] = 1.0
    np.subtract(np.moveaxis(values, 2, 0), centre.astype(np.float32)[:, None, None], out=v)
    v *= mask
    np.multiply(v, v, out=q)
    forward = sfft.rfft2(planes, workers=threads)

    def corr(fa: np.ndarray, fb: np.ndarray) -> np.ndarray:  # sum_p a(p) b(p + h), circular, at the lags
        return sfft.irfft2(np.conj(fa) * fb, shape, workers=threads)[at].astype(np.float64)
    m_b, v_b, q_b = forward[0:1], forward[1:1 + n_bands], forward[1 + n_bands:]
    if anchor_rows >= h:  # anchors and partners one set: half the transforms
        m_a, v_a = m_b, v_b
        first = sfft.irfft2(forward[1:] * np.conj(m_b), shape, workers=threads, overwrite_x=True)
        own, partners = first[back].astype(np.float64), first[at].astype(np.float64)
    else:
        planes[:, anchor_rows:] = 0.0
        anchors = sfft.rfft2(planes, workers=threads)
        m_a, v_a, q_a = anchors[0:1], anchors[1:1 + n_bands], anchors[1 + n_bands:]
        own, partners = corr(np.concatenate([v_a, q_a]), m_b), corr(m_a, np.concatenate([v_b, q_b]))
    side = np.concatenate([np.rint(corr(m_a, m_b)), own])
    partner = np.stack([partners[:n_bands], corr(v_a, v_b), partners[n_bands:]])
    return side, partner
