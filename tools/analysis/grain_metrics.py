"""Figures that judge a synthesized texture beside its photograph, region by region.

acf2d       the Pearson autocorrelation of one band at every lag of a half-plane window,
            over the pairs of pixels both inside the region (each end's own mean and variance),
            all lags at once from zero-padded FFTs of the masked values (`pair_pearson`, which
            synthesis reads its own draws with, tools.analysis.imposed)
acf_gap     the worst |acf(synthesis) - acf(photograph)| over the window's lags and the bands
plaid       the share of a region's spectral power on the kx = 0 and ky = 0 axes after a Hann
            window, over the largest square inside the region (the mask's own edges would
            otherwise put power on the axes); a separable field piles power there
outside     the share of synthesized pixels outside the region's observed levels per band
unseen      the share of synthesized pixels whose colour (every band at once, in bins of 1/32 of
            the depth, one bin of slack) the region's photograph never shows: marginals within
            their levels can still pair into a colour the region never had
band_gap    the worst |corr(synthesis) - corr(photograph)| of the bands' correlation matrix
"""
from __future__ import annotations

import numpy as np
import scipy.fft as sfft
from scipy import ndimage

from btf.dependence import window

MIN_PAIRS = 32


def region_pairs(inside: np.ndarray, shape: tuple[int, int], lags: np.ndarray,
                 dtype: type = np.float32) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(the mask in `dtype`, its rfft2 on `shape`, its pairs at each lag, at least 1): what
    `pair_pearson` reads a region's values against."""
    m = inside.astype(dtype)
    fm = sfft.rfft2(m, shape)
    n = sfft.irfft2(fm * np.conj(fm), shape)[lags[:, 0] % shape[0], lags[:, 1] % shape[1]]
    return m, fm, np.maximum(np.rint(n), 1.0)


def pair_pearson(v: np.ndarray, fm: np.ndarray, n: np.ndarray, shape: tuple[int, int], lags: np.ndarray) -> np.ndarray:
    """Each lag's Pearson correlation of v (zero outside the region) over the region's pairs, each
    end with its own mean and variance, from zero-padded FFT products (NaN where an end does not
    vary); fm, n: the region's `region_pairs` on `shape`. Sums stay in v's precision."""
    at, back = (lags[:, 0] % shape[0], lags[:, 1] % shape[1]), (-lags[:, 0] % shape[0], -lags[:, 1] % shape[1])

    def at_lags(spectrum: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # a box of sums at a time
        sums = sfft.irfft2(spectrum, shape)
        return sums[at].astype(np.float64), sums[back].astype(np.float64)
    fv = sfft.rfft2(v, shape)
    sab, _ = at_lags(fv * np.conj(fv))
    first = at_lags(np.conj(fv) * fm)  # sums of the pairs' first ends (at h) and second ends (at -h)
    del fv
    squares = at_lags(np.conj(sfft.rfft2(v * v, shape)) * fm)
    ma, mb = first[0] / n, first[1] / n
    va, vb = squares[0] / n - ma * ma, squares[1] / n - mb * mb
    # a variance under this share of the mean square is the sums' rounding, not spread
    rounding = 1e-5 if v.dtype == np.float32 else 1e-12
    varies = (va > rounding * squares[0] / n) & (vb > rounding * squares[1] / n)
    with np.errstate(all="ignore"):
        return np.where(varies, (sab / n - ma * mb) / np.sqrt(np.abs(va * vb)), np.nan)


def acf2d(values: np.ndarray, inside: np.ndarray, radius: int = 8) -> np.ndarray:
    """Pearson autocorrelation of `values` (H x W) at window(radius), pairs inside `inside`
    (0 at a lag of fewer than MIN_PAIRS pairs)."""
    lags = np.array(window(radius))
    shape = tuple(sfft.next_fast_len(n + radius + 1) for n in values.shape)
    m, fm, n = region_pairs(inside, shape, lags, np.float64)
    v = np.where(inside, values.astype(np.float64), 0.0)
    v -= v[inside].mean() if inside.any() else 0.0
    r = pair_pearson(v * m, fm, n, shape, lags)
    return np.clip(np.where((n >= MIN_PAIRS) & np.isfinite(r), r, 0.0), -1.0, 1.0)


def acf_gap(photo: np.ndarray, synth: np.ndarray, inside: np.ndarray, radius: int = 8) -> float:
    """Worst gap of the 2-D autocorrelation over |dy|, |dx| <= radius and the bands."""
    return max(float(np.abs(acf2d(synth[..., b], inside, radius) - acf2d(photo[..., b], inside, radius)).max())
               for b in range(photo.shape[2]))


def largest_square(inside: np.ndarray) -> tuple[slice, slice] | None:
    """The largest axis-aligned square of pixels all inside (None for an empty region)."""
    if not inside.any():
        return None
    # chessboard distance to the nearest outside pixel (the frame's edge counts as outside)
    d = ndimage.distance_transform_cdt(np.pad(inside, 1), metric="chessboard")[1:-1, 1:-1]
    y, x = np.unravel_index(int(np.argmax(d)), d.shape)
    k = int(d[y, x]) - 1
    return slice(y - k, y + k + 1), slice(x - k, x + k + 1)


def axis_share(values: np.ndarray, square: tuple[slice, slice]) -> float:
    """Share of the Hann-windowed spectral power (zero frequency left out) on the two axes,
    averaged over the bands."""
    shares = []
    for b in range(values.shape[2]):
        v = values[square + (b,)].astype(np.float64)
        v -= v.mean()
        h, w = v.shape
        p = np.abs(np.fft.fft2(v * np.hanning(h)[:, None] * np.hanning(w)[None, :])) ** 2
        p[0, 0] = 0.0
        total = p.sum()
        shares.append((p[0, :].sum() + p[:, 0].sum()) / total if total > 0 else 0.0)
    return float(np.mean(shares))


def plaid(photo: np.ndarray, synth: np.ndarray, inside: np.ndarray, min_side: int = 32) -> float | None:
    """Plaid index: the synthesis's axis share over the photograph's, on the largest square
    inside the region; None when that square is under `min_side` pixels a side."""
    square = largest_square(inside)
    if square is None or square[0].stop - square[0].start < min_side:
        return None
    base = axis_share(photo, square)
    return axis_share(synth, square) / base if base > 0 else None


def outside(photo: np.ndarray, synth: np.ndarray, inside: np.ndarray) -> float:
    """Share of the region's synthesized pixel values outside the photograph's levels there."""
    bad = total = 0
    for b in range(photo.shape[2]):
        p, s = photo[..., b][inside], synth[..., b][inside]
        bad += int(np.count_nonzero((s < p.min()) | (s > p.max())))
        total += s.size
    return bad / total if total else 0.0


COLOUR_BINS = 32  # per band, over the depth


def unseen(photo: np.ndarray, synth: np.ndarray, inside: np.ndarray, levels: int = 256) -> float | None:
    """Share of the region's synthesized pixels in colour bins (with their neighbours) that none of
    the photograph's pixels there fall in; None for one band, or more than three."""
    bands = photo.shape[2]
    if not 2 <= bands <= 3:
        return None
    step = max(1, levels // COLOUR_BINS)
    span = levels // step + 2  # a bin and its neighbours, shifted off zero

    weights = span ** np.arange(bands)  # a bin's key: its index per band in base `span`

    def keys(img: np.ndarray) -> np.ndarray:
        return (img[inside].astype(np.int64) // step + 1) @ weights
    near = np.stack(np.meshgrid(*[(-1, 0, 1)] * bands, indexing="ij"), -1).reshape(-1, bands) @ weights
    grown = np.unique((np.unique(keys(photo))[:, None] + near[None]).ravel())
    drawn = keys(synth)
    return float(np.mean(~np.isin(drawn, grown))) if drawn.size else 0.0


def band_gap(photo: np.ndarray, synth: np.ndarray, inside: np.ndarray) -> float:
    """Worst gap of the bands' pixel correlation matrix over the region (0 for one band)."""
    if photo.shape[2] < 2:
        return 0.0
    with np.errstate(invalid="ignore", divide="ignore"):  # a flat band correlates with nothing: 0
        c = [np.nan_to_num(np.corrcoef(x[inside].T.astype(np.float64))) for x in (photo, synth)]
    return float(np.abs(c[0] - c[1]).max())


def empirical_autocorrelation(values: np.ndarray, mask: np.ndarray, lag: int, axis: int) -> float:
    """Pearson correlation of values at pixel pairs `lag` apart along `axis`, both inside `mask`."""
    v = np.asarray(values, dtype=np.float64)
    if axis == 1:
        a, b, ma, mb = v[:, :-lag], v[:, lag:], mask[:, :-lag], mask[:, lag:]
    elif axis == 0:
        a, b, ma, mb = v[:-lag], v[lag:], mask[:-lag], mask[lag:]
    else:
        raise ValueError(f"axis must be 0 or 1, got {axis}")
    both = ma & mb
    x, y = a[both], b[both]
    if x.size < 2 or x.std() == 0 or y.std() == 0:
        return 0.0
    return float(np.corrcoef(x, y)[0, 1])
