"""Correlated fields for synthesis: a region's grain (2-D autocorrelation) and joint colour.

Per stored record (cached, `grain_of`): each band's map from z to its levels
(tools.analysis.levelmap), the latent band correlation matrix (tools.analysis.latent) and the
non-negative spectrum of the grain on a ring (tools.analysis.spectrum), one shared by the bands
or one per band. Per call (`draw`), for each band:

1. random-phase noise (Galerne et al.): every coefficient of the rfft half-grid has the
   amplitude of the spectrum exactly and a uniform phase, 8 random bits, through a table of
   256 unit phasors: no normal draws, a byte per two pixels; the field is Gaussian by the
   central limit theorem and its periodogram is the spectrum;
2. per-band spectra are mixed before the amplitude, so each band keeps its own spectrum and
   the bands their correlation (less the coherence their spectra lose, corrected for);
3. exact sample moments in the frequency domain: the bands' covariance over the grid is read
   off the coefficients (Parseval) and a matrix folded into them makes it the target exactly
   (`correction`: lower-triangular for bands of one spectrum, the least-mixing map for bands
   of their own), so one realisation of a long grain does not scatter the band correlation;
   the mean is the zero-frequency coefficient, set to the table's offset;
4. one inverse real FFT per field (float32, scipy.fft sizes from next_fast_len), the output
   already the index of each pixel's level in its band's z table.
A region that does not fill its grid has its moments made exact over its own pixels after the
transform instead (two passes more), and when it is scattered over its box, its own pairs'
autocorrelation imposed on the draw (tools.analysis.imposed).
"""
from __future__ import annotations

import threading
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import scipy.fft as sfft
from scipy.linalg import blas

from btf.dependence import MAX_RADIUS, Dependence
from btf.fit.dependence import ROW_SPREAD
from tools.analysis.imposed import MIN_PIXELS, impose, lag_acf
from tools.analysis.latent import grain_curve, latent_bands
from tools.analysis.levelmap import Z_SPAN, LevelMap
from tools.analysis.spectrum import RING, amplitude, ring_spectrum
from tools.analysis.tiles import MAX_THREADS, in_parallel, one_blas_thread, split_rows, streams, workers

_PHASES = np.exp(2j * np.pi * np.arange(256) / 256).astype(np.complex64)
_PHASES.flags.writeable = False
PHASE_CHUNK = 1 << 16  # coefficients given their random bits at a time; a multiple of 8
MIN_EXACT = 64  # fewer region pixels than this: the moments are left to chance
KEEP_BYTES = 64 << 20  # a workspace up to this size stays for the next call (no page faults)
_WORK = threading.local()


@dataclass(frozen=True, eq=False)
class Grain:
    """What a region's correlated fields need beyond their random numbers (cached per record)."""

    latent: np.ndarray  # B x B latent band correlation
    reached: np.ndarray  # the pixel band correlation that latent gives
    rings: tuple[np.ndarray, ...]  # ring spectra (mean 1): one shared, or one per band

    @property
    def n_bands(self) -> int:
        return len(self.latent)


@lru_cache(maxsize=256)
def grain_of(dep: Dependence, maps: tuple[LevelMap, ...]) -> Grain:
    """A measured record through its bands' maps: latent band matrix and grain spectra."""
    if not dep.measured or dep.n_bands != len(maps):
        raise ValueError(f"a measured record of {len(maps)} band(s) is needed for correlated fields")
    with one_blas_thread():
        latent, reached = latent_bands(dep.matrix(), list(maps))
        if not dep.per_band:
            rings = (ring_spectrum(dep.radius, dep.acf[0], grain_curve(list(maps)), RING, RING, dep.known(0)),)
        else:  # each band refined from their shared spectrum (lags unmeasured in any band left out of it)
            known = [dep.known(b) for b in range(len(maps))]
            mean = np.mean(dep.acf, axis=0)
            shared = ring_spectrum(dep.radius, tuple(mean.tolist()), grain_curve(list(maps)), RING, RING,
                                   np.logical_and.reduce(known))
            # a band within ROW_SPREAD of the bands' mean at every lag it measured takes the shared spectrum
            rings = tuple(shared if np.abs(np.asarray(row) - mean)[k].max(initial=0.0) <= ROW_SPREAD else
                          ring_spectrum(dep.radius, row, grain_curve([m]), RING, RING, k, reference=shared)
                          for m, row, k in zip(maps, dep.acf, known))
    for r in rings:
        r.flags.writeable = False
    return Grain(latent, reached, rings)


def blend(lo: Grain, hi: Grain, weight: float) -> Grain:
    """Angle blend: the spectra and latent matrices mixed linearly (a convex mix of spectra is a
    spectrum, of correlation matrices a correlation matrix), so the latent grain blends linearly."""
    if not 0.0 <= weight <= 1.0:
        raise ValueError(f"blend weight must lie in [0, 1], got {weight}")
    if lo.n_bands != hi.n_bands:
        raise ValueError(f"cannot blend {lo.n_bands}-band and {hi.n_bands}-band grain")
    rings_lo, rings_hi = lo.rings, hi.rings
    if len(rings_lo) != len(rings_hi):  # one shared against per band: the shared one serves every band
        rings_lo, rings_hi = (rings_lo * lo.n_bands)[:lo.n_bands], (rings_hi * hi.n_bands)[:hi.n_bands]
    mix = lambda a, b: (1.0 - weight) * a + weight * b  # noqa: E731
    return Grain(mix(lo.latent, hi.latent), mix(lo.reached, hi.reached),
                 tuple(mix(a, b) for a, b in zip(rings_lo, rings_hi)))


def grid_of(h: int, w: int) -> tuple[int, int]:
    """The FFT grid of a box: fast lengths, at least twice the longest lag anyone looks at."""
    fast = lambda n: sfft.next_fast_len(max(n, 2 * MAX_RADIUS + 2), real=True)  # noqa: E731
    return fast(h), fast(w)


@dataclass(frozen=True, eq=False)
class _Shaping:
    amps: tuple[np.ndarray, ...]  # per row: sqrt(S) * scale * N on the half grid, float32
    mixing: np.ndarray | None  # lower factor mixing the phases before per-band amplitudes
    weights: np.ndarray  # per half-grid column: 1 for the columns irfft keeps real, else 2
    power: float  # a field's variance under one amplitude and unit phasors, zero frequency left out


@lru_cache(maxsize=8)
def _shaping(grain: Grain, grid: tuple[int, int], scale: float) -> _Shaping:
    ny, nx = grid
    amps = tuple(amplitude(r, ny, nx) * np.float32(scale * ny * nx) for r in grain.rings)
    weights = np.full(nx // 2 + 1, 2.0)
    weights[0] = 1.0
    if nx % 2 == 0:
        weights[-1] = 1.0
    mixing = None
    if len(amps) > 1:  # coherence the differing spectra lose: asked-for / overlap, then valid
        n = len(amps)
        overlap = np.array([[float((amps[i] * amps[j]).sum(axis=0, dtype=np.float64) @ weights)
                             for j in range(n)] for i in range(n)])
        d = np.sqrt(np.diag(overlap))
        want = grain.latent / (overlap / np.outer(d, d))
        w, v = np.linalg.eigh(0.5 * (want + want.T))
        want = (v * np.maximum(w, 1e-6)) @ v.T
        d = np.sqrt(np.diag(want))
        mixing = np.linalg.cholesky(want / np.outer(d, d))
    a = amps[0].astype(np.float64)
    power = (float((a * a).sum(axis=0) @ weights) - a[0, 0] ** 2) / (ny * nx) ** 2
    for a in amps:
        a.flags.writeable = False
    return _Shaping(amps, mixing, weights, power)


@lru_cache(maxsize=8)
def _targets(grain: Grain, grid: tuple[int, int], scale: float) -> tuple[np.ndarray, ...]:
    """Per band, the latent autocorrelation within 2 MAX_RADIUS of its drawn spectrum (what
    a fragmented region's draw is held to)."""
    amps = _shaping(grain, grid, scale).amps
    return tuple(lag_acf(amps[b if len(amps) > 1 else 0], grid[1], 2 * MAX_RADIUS) for b in range(grain.n_bands))


def _workspace(n_bands: int, ny: int, nx: int) -> tuple[np.ndarray, np.ndarray]:
    """(spectra B x ny x (nx/2 + 1) complex64, fields B x ny x nx float32) for this thread: kept
    between calls up to KEEP_BYTES, so repeated synthesis does not fault in fresh pages."""
    key = (n_bands, ny, nx)
    kept = getattr(_WORK, "buffers", None)
    if kept is not None and kept[0] == key:
        return kept[1], kept[2]
    _WORK.buffers = None
    buffers = (key, np.empty((n_bands, ny, nx // 2 + 1), np.complex64), np.empty((n_bands, ny, nx), np.float32))
    if n_bands * ny * nx * 8 <= KEEP_BYTES:
        _WORK.buffers = buffers
    return buffers[1], buffers[2]


def _phases(rng: np.random.Generator, e: np.ndarray) -> None:
    """e (ny x nc) <- unit phasors with uniform phase; the columns irfft keeps real made
    Hermitian in themselves."""
    ny, nc = e.shape
    flat = e.reshape(-1)
    for start in range(0, flat.size, PHASE_CHUNK):
        part = flat[start:start + PHASE_CHUNK]
        # 8 random bits a coefficient, straight from the bit generator (twice as fast as rng.bytes)
        bits = rng.bit_generator.random_raw((part.size + 7) // 8).view(np.uint8)[:part.size]
        _PHASES.take(bits, out=part, mode="wrap")  # "raise" would buffer `out`
    k = np.arange(1, (ny + 1) // 2)
    for c in ((0, nc - 1) if nc > 1 else (0,)):
        e[ny - k, c] = np.conj(e[k, c])
        e[0, c] = 1.0 if e[0, c].real >= 0 else -1.0
        if ny % 2 == 0:
            e[ny // 2, c] = 1.0 if e[ny // 2, c].real >= 0 else -1.0


def _gram(spectra: np.ndarray, weights: np.ndarray, n: int, diagonal: np.ndarray | None = None) -> np.ndarray:
    """Covariance over the grid of the fields the half-grid spectra stand for (Parseval);
    `diagonal`, when known (random phases under one amplitude), is not summed again."""
    b = len(spectra)
    edges = sorted({0, len(weights) - 1})
    # as many blocks on any machine: the sums, and so the draw, do not depend on the core count
    blocks = split_rows(slice(0, spectra[0].shape[0]), MAX_THREADS)
    sums = np.zeros((len(blocks), b, b))

    def block(k: int) -> None:  # a block of rows, summed on a thread
        part = [s[blocks[k]] for s in spectra]
        for i in range(b):
            for j in range(i + 1):
                if i != j or diagonal is None:
                    edge = sum((2.0 - weights[c]) * float(np.vdot(part[j][:, c], part[i][:, c]).real) for c in edges)
                    sums[k, i, j] = 2.0 * float(np.vdot(part[j], part[i]).real) - edge
    in_parallel(block, len(blocks), spectra[0].size)
    g = np.tril(sums.sum(axis=0)) / (n * n)
    g = g + np.tril(g, -1).T
    if diagonal is not None:
        g[np.diag_indices(b)] = diagonal
    return g


def _fold(spectra: list[np.ndarray], t: np.ndarray) -> None:
    """spectra <- t spectra, in place from the last band down (lower-triangular t), through
    copies of the originals for a full t."""
    full = bool(np.triu(t, 1).any())
    blocks = split_rows(slice(0, spectra[0].shape[0]), MAX_THREADS)  # BLAS rounds a block's tail its own way

    def block(k: int) -> None:  # a block of rows on a thread: rows never mix
        flats = [s[blocks[k]].reshape(-1) for s in spectra]
        if full:
            originals = [f.copy() for f in flats]
            for i, flat in enumerate(flats):
                flat *= np.complex64(t[i, i])
                for j in range(len(flats)):
                    if j != i:
                        blas.caxpy(originals[j], flat, a=np.complex64(t[i, j]))
            return
        for i in range(len(flats) - 1, -1, -1):
            flats[i] *= np.complex64(t[i, i])
            for j in range(i):
                blas.caxpy(flats[j], flats[i], a=np.complex64(t[i, j]))
    in_parallel(block, len(blocks), spectra[0].size)


def draw(grain: Grain, shape: tuple[int, int], rng: np.random.Generator, scale: float = 1.0,
         offset: float = 0.0, inside: np.ndarray | None = None) -> list[np.ndarray]:
    """B fields (h x w float32) with the grain and latent band correlation, each pixel
    z * scale + offset (z standard normal); sample moments exact over the pixels `inside`
    (an h x w mask; None: the whole box). The fields are views of this thread's workspace:
    valid until its next call."""
    with one_blas_thread():
        return _draw(grain, shape, rng, scale, offset, inside)


def _draw(grain: Grain, shape: tuple[int, int], rng: np.random.Generator, scale: float, offset: float,
          inside: np.ndarray | None) -> list[np.ndarray]:
    h, w = shape
    grid = grid_of(h, w)
    ny, nx = grid
    shaping = _shaping(grain, grid, float(scale))
    n_bands = grain.n_bands
    spectra, fields = _workspace(n_bands, ny, nx)
    bands = streams(rng, n_bands)  # a stream per band: a seed gives one field on any number of threads
    in_parallel(lambda b: _phases(bands[b], spectra[b]), n_bands, ny * nx)
    if shaping.mixing is not None:
        _fold(spectra, shaping.mixing)

    def shape(b: int) -> None:
        spectra[b] *= shaping.amps[b if len(shaping.amps) > 1 else 0]
        spectra[b, 0, 0] = 0.0
    in_parallel(shape, n_bands, ny * nx)
    whole = inside is None and grid == (h, w)
    own = shaping.mixing is not None  # bands of their own spectra: any correction mixes them
    low = np.linalg.cholesky(grain.latent + 1e-9 * np.eye(n_bands))
    if whole:  # exact over the grid, which is the region
        known = None if own else np.full(n_bands, shaping.power)
        gram = _gram(spectra, shaping.weights, ny * nx, known) + 1e-12 * scale * scale * np.eye(n_bands)
        _fold(spectra, correction(gram / (scale * scale), grain.latent, own))
    elif not own:  # mixed here, made exact over the region's pixels below
        _fold(spectra, low)
    for b in range(n_bands):
        spectra[b, 0, 0] = offset * ny * nx
    fragmented = inside is not None and int(np.count_nonzero(inside)) >= MIN_PIXELS
    keep = [s.copy() for s in spectra] if fragmented else None
    out = [fields[b, :h, :w] for b in range(n_bands)]

    # the inverse real FFT in two steps, both into the workspace (irfft2 allocates twice): the
    # columns of every band at once, then blocks of rows, so no thread waits on a third band;
    # as many blocks on any machine, so a seed draws one field whatever the core count
    blocks = split_rows(slice(0, ny), MAX_THREADS)

    def redraw() -> None:
        columns = sfft.ifft(spectra, axis=1, overwrite_x=True, workers=workers(ny * nx))

        def rows(i: int) -> None:
            b, r = divmod(i, len(blocks))
            np.fft.irfft(columns[b, blocks[r]], n=nx, axis=1, out=fields[b, blocks[r]])
        in_parallel(rows, n_bands * len(blocks), ny * nx)
        if not whole:
            exact_moments(out, inside, grain.latent * (scale * scale), offset, own)

    redraw()
    if keep is not None:  # a region scattered over its box: its own pairs' grain imposed
        impose(spectra, keep, out, inside, _targets(grain, grid, float(scale)), nx, scale, offset, redraw)
    return out


def correction(now: np.ndarray, want: np.ndarray, least_mixing: bool = False) -> np.ndarray:
    """A matrix T with T now T^T = want (covariances). Lower-triangular by default (in place
    and cheap); `least_mixing`, the one nearest the identity (the optimal transport map
    now^-1/2 (now^1/2 want now^1/2)^1/2 now^-1/2): where every band has its own spectrum, a
    triangular one built on a nearly singular matrix mixed them wholesale and took up to 0.19
    off a band's autocorrelation."""
    b = len(now)

    def ridge(m: np.ndarray) -> np.ndarray:  # relative to the matrix: any units
        return 1e-9 * max(float(np.trace(m)) / b, 1e-300) * np.eye(b)
    if not least_mixing:
        return np.linalg.cholesky(want + ridge(want)) @ np.linalg.inv(np.linalg.cholesky(now + ridge(now)))
    vals, vecs = np.linalg.eigh(now + ridge(now))
    root = (vecs * np.sqrt(np.maximum(vals, 1e-12))) @ vecs.T
    inv_root = (vecs / np.sqrt(np.maximum(vals, 1e-12))) @ vecs.T
    vals, vecs = np.linalg.eigh(root @ want @ root)
    middle = (vecs * np.sqrt(np.maximum(vals, 0.0))) @ vecs.T
    return inv_root @ middle @ inv_root


def _affine(fields: list[np.ndarray], t: np.ndarray, shift: np.ndarray) -> None:
    """fields_i <- sum_(j <= i) t_ij fields_j + shift_i in place (t lower triangular), from the
    last band down so every band still reads the others' originals; views (a crop of a larger
    grid) take a temporary, contiguous fields BLAS."""
    if np.triu(t, 1).any():  # a full t: each band from copies of the originals
        originals = [f.copy() for f in fields]
        for i, f in enumerate(fields):
            np.multiply(originals[0], np.float32(t[i, 0]), out=f)
            for j in range(1, len(fields)):
                f += originals[j] * np.float32(t[i, j])
            f += np.float32(shift[i])
        return
    flat = [f.reshape(-1) if f.flags.c_contiguous else None for f in fields]
    scratch = None
    for i in range(len(fields) - 1, -1, -1):
        fields[i] *= np.float32(t[i, i])
        for j in range(i):
            if flat[i] is not None and flat[j] is not None:
                blas.saxpy(flat[j], flat[i], a=np.float32(t[i, j]))
            else:
                scratch = np.multiply(fields[j], np.float32(t[i, j]), out=scratch)
                fields[i] += scratch
        fields[i] += np.float32(shift[i])


def exact_moments(fields: list[np.ndarray], inside: np.ndarray | None, target: np.ndarray, offset: float,
                  least_mixing: bool = False) -> None:
    """fields (B, each h x w) <- T (fields - mean) + offset in place, with the mean and T from
    the pixels `inside` (None: all), so their sample covariance there is `target` (T from
    `correction`)."""
    b = len(fields)
    weight = None if inside is None else inside.astype(np.float32)
    n = fields[0].size if weight is None else float(weight.sum())
    if n < max(MIN_EXACT, b + 2):
        return
    for f in fields:
        f -= np.float32(offset)  # centred: float32 products stay accurate
    ops = [] if weight is None else [weight]
    spec = "ij,ij->" if weight is None else "ij,ij,ij->"
    mean = np.array([float(np.einsum("ij,ij->" if ops else "ij->", f, *ops, dtype=np.float64)) / n for f in fields])
    cov = np.array([[float(np.einsum(spec, fields[i], fields[j], *ops, dtype=np.float64)) / n for j in range(b)]
                    for i in range(b)]) - np.outer(mean, mean)
    try:
        t = correction(cov, target, least_mixing)
    except np.linalg.LinAlgError:
        t = np.eye(b)
    _affine(fields, t, offset - t @ mean)


def remix(fields: list[np.ndarray], old: np.ndarray, new: np.ndarray, offset: float, least_mixing: bool = False) -> None:
    """Fields drawn with latent band correlation `old` (each z * scale + offset) made to carry
    `new` in place: z <- T z (`correction`)."""
    with one_blas_thread():
        t = correction(old, new, least_mixing)
        _affine(fields, t, offset * (1.0 - t.sum(axis=1)))


def index_units(bits: int) -> tuple[float, float]:
    """(scale, offset) that turn z into the index of a z table of 2**bits bins."""
    s = (1 << bits) / (2 * Z_SPAN)
    return s, Z_SPAN * s
