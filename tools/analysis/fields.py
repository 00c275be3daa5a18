"""Correlated Gaussian fields for synthesis: the grain (autocorrelation) and the joint colour.

A region's bands share one spatial autocorrelation (measured at `btf.fit.dependence.LAGS`
along rows and columns). It is modelled as separable, r(dy, dx) = r_y(dy) r_x(dx); each 1-D
sequence is the measured lags joined log-linearly (exact for exponential decay), continued
past the last lag with the decay rate of the last two, and made a valid autocorrelation by
alternating projections (non-negative spectrum <-> the measured values). White noise drawn
straight in the frequency domain, shaped by the spectrum's square root and transformed
once, gives a unit-variance stationary field; B such fields mixed by the Cholesky factor
of the band copula give z with both the grain and the cross-band correlation. Each band
then goes through its Johnson quantile function, so every marginal stays exact.
"""
from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
import scipy.fft as sfft

from btf.dependence import LAGS, Dependence
from btf.johnson import Family, Johnson, normal_ppf
from tools.analysis.tiles import Region, row_tiles

_PROJECTIONS = 12
_NODES = 48  # Gauss-Hermite nodes per axis for the pixel moments
_BISECT = 30


def nearest_correlation(m: np.ndarray, floor: float = 1e-6) -> np.ndarray:
    """The nearest valid correlation matrix: symmetric, unit diagonal, eigenvalues >= floor."""
    m = np.asarray(m, dtype=np.float64)
    if m.ndim != 2 or m.shape[0] != m.shape[1] or not np.all(np.isfinite(m)):
        raise ValueError(f"need a finite square matrix, got shape {m.shape}")
    a = 0.5 * (m + m.T)
    np.fill_diagonal(a, 1.0)
    for _ in range(50):
        w, v = np.linalg.eigh(a)
        if w.min() >= floor * 0.5:
            break
        a = (v * np.maximum(w, floor)) @ v.T
        d = np.sqrt(np.diag(a))
        a = a / np.outer(d, d)
        np.fill_diagonal(a, 1.0)
    return np.clip(a, -1.0, 1.0)


def cholesky(dep: Dependence) -> np.ndarray:
    """Lower factor L with L L^T = the copula (projected to a valid one when quantization broke it)."""
    return np.linalg.cholesky(nearest_correlation(dep.matrix()))


def blend(lo: Dependence, hi: Dependence, weight: float) -> Dependence:
    """Angle blend: a convex mix of correlation matrices is one, so linear mixing stays valid."""
    if not 0.0 <= weight <= 1.0:
        raise ValueError(f"blend weight must lie in [0, 1], got {weight}")
    if lo.n_bands != hi.n_bands:
        raise ValueError(f"cannot blend {lo.n_bands}-band and {hi.n_bands}-band dependence")
    mix = lambda a, b: tuple(float(np.clip((1 - weight) * x + weight * y, -1, 1)) for x, y in zip(a, b))  # noqa: E731
    return Dependence(mix(lo.corr, hi.corr), mix(lo.dx, hi.dx), mix(lo.dy, hi.dy))


def _moments(g1: np.ndarray, g2: np.ndarray, w: np.ndarray) -> tuple[float, float, float, float]:
    m1, m2 = float(w @ g1), float(w @ g2)
    return m1, m2, math.sqrt(max(float(w @ g1**2) - m1 * m1, 0.0)), math.sqrt(max(float(w @ g2**2) - m2 * m2, 0.0))


def _pixel_corr(a: Johnson, b: Johnson, rho: float, levels: int) -> float:
    """Pearson correlation of pixels x_a(Z1), x_b(Z2) (clipped to the levels) when corr(Z1, Z2) = rho."""
    x, w = _gauss_hermite()
    top = levels - 1
    g1 = np.clip(a.x_of_z(x), 0, top)
    m1, m2, s1, s2 = _moments(g1, np.clip(b.x_of_z(x), 0, top), w)
    if s1 == 0.0 or s2 == 0.0:
        return 0.0
    z2 = rho * x[:, None] + math.sqrt(max(1.0 - rho * rho, 0.0)) * x[None, :]
    e = float(w @ (g1[:, None] * np.clip(b.x_of_z(z2), 0, top)) @ w)
    return (e - m1 * m2) / (s1 * s2)


@lru_cache(maxsize=1)
def _gauss_hermite() -> tuple[np.ndarray, np.ndarray]:
    x, w = np.polynomial.hermite_e.hermegauss(_NODES)
    return x, w / w.sum()


@lru_cache(maxsize=4096)
def latent_rho(a: Johnson, b: Johnson, target: float, levels: int = 256) -> float:
    """The normal-score correlation whose pixels, through models a and b, correlate by `target`
    (moment matching, NORTA); clipped to the reachable range when the target lies beyond it."""
    if a.family is Family.CONST or b.family is Family.CONST:
        return 0.0
    lo, hi = -0.999, 0.999
    if target >= _pixel_corr(a, b, hi, levels):
        return hi
    if target <= _pixel_corr(a, b, lo, levels):
        return lo
    for _ in range(_BISECT):  # pixel correlation increases with rho for increasing maps
        mid = 0.5 * (lo + hi)
        if _pixel_corr(a, b, mid, levels) < target:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def latent(dep: Dependence, models: tuple[Johnson, ...], levels: int = 256) -> Dependence:
    """Measured pixel correlations -> the normal-score correlations synthesis draws with."""
    n = len(models)
    if dep.n_bands != n:
        raise ValueError(f"dependence has {dep.n_bands} bands, models {n}")
    iu = zip(*np.triu_indices(n, 1))
    corr = tuple(latent_rho(models[i], models[j], r, levels) for (i, j), r in zip(iu, dep.corr))
    live = [m for m in models if m.family is not Family.CONST] or list(models)
    lag = lambda r: float(np.mean([latent_rho(m, m, r, levels) for m in live]))  # noqa: E731
    return Dependence(corr, tuple(lag(r) for r in dep.dx), tuple(lag(r) for r in dep.dy))


def _target(lags: tuple[float, ...], n: int) -> np.ndarray:
    """Autocorrelation at 0..n-1 on a ring of n: measured lags joined log-linearly, decaying tail."""
    known_h = np.array((0, *LAGS), dtype=np.float64)
    known_r = np.array((1.0, *lags), dtype=np.float64).clip(-0.99, 0.999)
    h = np.minimum(np.arange(n), n - np.arange(n)).astype(np.float64)  # ring distance
    r = np.interp(h, known_h, known_r)
    for i in range(len(known_h) - 1):
        a, b = known_r[i], known_r[i + 1]
        if a > 0.02 and b > 0.02:  # both clearly positive: geometric between them
            seg = (h > known_h[i]) & (h < known_h[i + 1])
            t = (h[seg] - known_h[i]) / (known_h[i + 1] - known_h[i])
            r[seg] = a * (b / a) ** t
    last, prev, step = known_r[-1], known_r[-2], known_h[-1] - known_h[-2]
    q = (last / prev) ** (1.0 / step) if 0.0 < last < prev else 0.5
    tail = h > known_h[-1]
    r[tail] = last * np.minimum(q, 0.95) ** (h[tail] - known_h[-1])
    return r


@lru_cache(maxsize=64)
def spectrum(lags: tuple[float, ...], n: int) -> np.ndarray:
    """Non-negative power spectrum (mean 1) whose autocorrelation best matches `lags` on a ring of n."""
    want = _target(lags, n)
    fixed = np.zeros(n, dtype=bool)
    fixed[:max(LAGS) + 1] = True
    fixed[n - max(LAGS):] = True
    fixed &= np.minimum(np.arange(n), n - np.arange(n)) < n // 2 + 1
    r = want.copy()
    for _ in range(_PROJECTIONS):
        s = np.maximum(np.fft.rfft(r).real, 0.0)
        r = np.fft.irfft(s, n)
        r[fixed] = want[fixed]
    s = np.maximum(np.fft.rfft(r).real, 0.0)
    total = (2.0 * s.sum() - s[0] - (s[-1] if n % 2 == 0 else 0.0)) / n  # = r(0) of the result
    return s / total if total > 0 else np.ones_like(s)


def _fast(n: int) -> int:
    return sfft.next_fast_len(max(n, 2 * max(LAGS) + 2), real=True)


def gaussian_fields(shape: tuple[int, int], dep: Dependence, rng: np.random.Generator) -> np.ndarray:
    """B x H x W float32 standard normal fields with the region's grain and band copula.
    Beyond the B fields themselves it holds the spectrum's amplitude and one band's transform."""
    h, w = shape
    ny, nx = _fast(h), _fast(w)
    k = np.arange(ny)
    full_y = np.sqrt(spectrum(dep.dy, ny))[np.minimum(k, ny - k)]  # all ny frequencies of the y axis
    sx = np.sqrt(spectrum(dep.dx, nx))
    n_bands = dep.n_bands
    out = np.empty((n_bands, h, w), dtype=np.float32)
    # the spectrum's square root once for all bands (float32, half a band's transform)
    amplitude = [(r, _amplitude(full_y[r], sx, nx, ny)) for r in row_tiles(ny, nx // 2 + 1)]
    for b in range(n_bands):
        white = _white(rng, (ny, nx // 2 + 1))
        for r, amp in amplitude:
            white[r] *= amp
        out[b] = sfft.irfft2(white, s=(ny, nx), workers=-1, overwrite_x=True)[:h, :w]
        del white
    if n_bands > 1:
        low = cholesky(dep).astype(np.float32)
        # Band b mixes fields 0..b (lower factor); updating from the last band reuses the originals.
        for r in row_tiles(h, w):
            for b in range(n_bands - 1, -1, -1):
                out[b, r] *= low[b, b]
                for j in range(b):
                    out[b, r] += low[b, j] * out[j, r]
    return out


@lru_cache(maxsize=1)
def _normal_table() -> np.ndarray:
    """2**16 equiprobable standard normal quantiles (float32, scaled to unit variance)."""
    z = normal_ppf((np.arange(1 << 16) + 0.5) / (1 << 16)).astype(np.float64)
    z /= np.sqrt(np.mean(z * z))
    table = z.astype(np.float32)
    table.flags.writeable = False
    return table


def _white(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """Complex64 white noise, unit variance per part: 16-bit uniform draws through the normal
    table (four times faster here than numpy's float32 normals). Every pixel of the inverse
    transform sums all the coefficients, so the field is Gaussian whatever the parts' shape;
    the table keeps even a white field's pixels normal to 2**-16 in probability."""
    draws = rng.integers(0, 1 << 16, shape + (2,), dtype=np.uint16)
    return np.take(_normal_table(), draws).view(np.complex64)[..., 0]


def _amplitude(fy: np.ndarray, sx: np.ndarray, nx: int, ny: int) -> np.ndarray:
    """Rows `fy` of the spectrum's square root scaled for one inverse transform of white noise."""
    amp = (fy[:, None] * sx[None, :]).astype(np.float32)
    # Columns 0 and Nyquist keep only their real part after the transform: twice the power.
    amp[:, 0] *= math.sqrt(2.0)
    if nx % 2 == 0:
        amp[:, -1] *= math.sqrt(2.0)
    amp *= np.float32(math.sqrt(ny * nx / 2.0))
    return amp


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


def region_fields(where: Region, dep: Dependence, rng: np.random.Generator) -> np.ndarray:
    """B x h x w correlated z over the region's bounding box (pixels outside the region unused)."""
    h, w = where.rows.stop - where.rows.start, where.cols.stop - where.cols.start
    if not where.count:
        return np.zeros((dep.n_bands, 0, 0), dtype=np.float32)
    return gaussian_fields((h, w), dep, rng)
