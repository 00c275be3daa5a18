"""A region's grain, measured as the pixel autocorrelation on the half-plane window W(R), as a
non-negative power spectrum: what synthesis draws each field from (tools.analysis.fields).

1. The window's latent values (the measured pixel values through the grain curve,
   tools.analysis.latent) on both halves, r(-h) = r(h), and r(0) = 1.
2. Beyond the window the autocorrelation is unknown. A model fitted to the window continues it:
   two anisotropic exponentials a_i exp(-sqrt(h' M_i h)), a short and a long scale each with its
   own orientation and aspect, plus the nugget 1 - a_1 - a_2 at h = 0. Each length is at most
   RING and each aspect about MAX_ASPECT at most (`bounded_rates`): six lags cannot tell a long
   length, which left free runs away along the window's longer axis. It is positive definite
   and continues a diagonal grain diagonally, with no plaid and no ringing.
3. On a ring of at most RING x RING lags: alternating projections, the spectrum clipped at zero
   <-> the window reset to its values; then the spectrum tilted (`_refit`: S exp(sum of the
   window's cosines), the tilt fitted by damped Gauss-Newton) so that the pixel autocorrelation
   it implies (the latent one through the grain curve) comes nearest the measured window in
   least squares, lag 0 held at 1. Projections alone cannot get there where a marginal fits
   its region poorly (the latent window is then not extendable); the refit takes brick's worst
   lag from 0.22 to 0.04.
4. On the synthesis grid the spectrum is interpolated linearly along each axis, periodically
   in frequency (`amplitude`): non-negative by construction; it multiplies the autocorrelation
   by about sinc^2(lag / RING), 0.996 at lag 8. The zero frequency's power goes to the eight
   frequencies around it: a draw fixes its mean, and on a box near RING that power was a
   quarter of the whole, every lag's autocorrelation short by up to 0.14.

Lags the robot could not measure (too few pixel pairs: `known`) take no part in the model's
fit, the projections or the refit; the model and the spectrum continue them.

So the spectrum is non-negative by clipping (the projections) and by construction (an
exponential in the refit, linear interpolation of non-negative values); it is scaled to unit variance.
"""
from __future__ import annotations

import math

import numpy as np
import scipy.fft as sfft
from scipy.linalg import cho_factor, cho_solve
from scipy.optimize import least_squares

from btf.dependence import window
from tools.analysis.latent import GRID, latent_acf

RING = 128
MAX_ASPECT = 4.0  # an exponential's long axis over its short one
PROJECTIONS = 15
REFIT_ITERATIONS = 60  # damped Gauss-Newton steps; records settle in 12-30
RIDGE = 1e-4  # the refit's pull of its tilt towards none, against the window's squared misses
MAX_LOG = 60.0  # a tilted spectrum's largest log: a ring's sum of e^60 still fits a float
LOG_BOUND = 150.0  # a log-rate's reach: its rate squared twice (e^600) still fits a float


def full_window(radius: int, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lags (M, 2), values (M,)) over the whole square |dy|, |dx| <= R, origin first."""
    half = np.array(window(radius), dtype=np.int64)
    return np.concatenate(([[0, 0]], half, -half)), np.concatenate(([1.0], values, values))


def bounded_rates(c: np.ndarray) -> tuple[float, float, float]:
    """The inverse squared lengths Q = M'M of one exponential, M = [[e^c0, 0], [c1, e^c2]],
    as (Q00, Q01, Q11), raised so that no length exceeds RING and the long axis is at most
    sqrt(1 + MAX_ASPECT^2) times the short one (the floor is the fastest rate over
    MAX_ASPECT^2). Six lags cannot tell a long length: left free, a window a little longer
    one way sends that length to thousands of pixels, all the component's power on one line of
    the spectrum (streaks along that axis). Scalar arithmetic: the model's fit calls it a
    thousand times a record."""
    clamp = lambda v: min(max(float(v), -LOG_BOUND), LOG_BOUND)  # noqa: E731
    a, b, e = math.exp(clamp(c[0])), float(c[1]), math.exp(clamp(c[2]))
    q00, q01, q11 = a * a + b * b, b * e, e * e
    half_gap = 0.5 * (q00 - q11)
    fastest = 0.5 * (q00 + q11) + math.sqrt(half_gap * half_gap + q01 * q01)
    floor = 1.0 / RING ** 2 + fastest / MAX_ASPECT ** 2
    return q00 + floor, q01, q11 + floor


def _model(p: np.ndarray, lags: np.ndarray) -> np.ndarray:
    return _models(p[None], lags)[0]


def _models(ps: np.ndarray, lags: np.ndarray) -> np.ndarray:
    """The model at each row of parameters `ps` (K x 8), K x len(lags), in one pass over the lags."""
    y, x = lags[:, 0], lags[:, 1]
    yy, xy, xx = y * y, 2.0 * x * y, x * x
    rates = np.empty((2, len(ps), 3))
    weights = np.empty((2, len(ps), 1))
    for k, p in enumerate(ps):
        share, split = 0.5 * (1.0 + math.tanh(0.5 * p[0])), 0.5 * (1.0 + math.tanh(0.5 * p[1]))  # logistic
        weights[:, k, 0] = share * split, share * (1 - split)
        rates[0, k], rates[1, k] = bounded_rates(p[2:5]), bounded_rates(p[5:8])
    form = rates[..., 0:1] * yy + rates[..., 1:2] * xy + rates[..., 2:3] * xx
    return (weights * np.exp(-np.sqrt(np.maximum(form, 0.0)))).sum(axis=0)


def _forward_differences(p: np.ndarray, lags: np.ndarray) -> np.ndarray:
    """d model / d p by forward differences with least_squares' own steps, all nine points in
    one pass: the fit spent most of its time in Python overhead evaluating them one by one."""
    h = np.sqrt(np.finfo(float).eps) * np.where(p >= 0, 1.0, -1.0) * np.maximum(1.0, np.abs(p))
    step = (p + h) - p
    values = _models(np.vstack([p, p + np.diag(step)]), lags)
    return ((values[1:] - values[0]) / step[:, None]).T


def _fit_model(radius: int, latent: np.ndarray, known: np.ndarray | None = None) -> np.ndarray:
    """The two-exponential model's parameters fitted to the window's known lags (lag 0 left out)."""
    lags = np.array(window(radius), dtype=np.float64)
    r1 = float(np.clip(np.max(latent[:2]), 0.05, 0.95))
    fast, slow = np.log(-np.log(r1) + 1e-3), np.log(-np.log(0.999) * 4)
    p0 = np.array([2.0, 0.0, fast, 0.0, fast, slow, 0.0, slow])
    if known is not None:
        lags, latent = lags[known], latent[known]
    return least_squares(lambda p: _model(p, lags) - latent, p0, jac=lambda p: _forward_differences(p, lags),
                         method="trf", max_nfev=400).x


def _ring_lags(ny: int, nx: int) -> np.ndarray:
    y = np.where(np.arange(ny) <= ny // 2, np.arange(ny), np.arange(ny) - ny)
    x = np.where(np.arange(nx) <= nx // 2, np.arange(nx), np.arange(nx) - nx)
    yy, xx = np.meshgrid(y, x, indexing="ij")
    return np.stack([yy.ravel(), xx.ravel()], axis=1).astype(np.float64)


def _projected(radius: int, latent: np.ndarray, ny: int, nx: int, known: np.ndarray | None = None) -> np.ndarray:
    """Full ny x nx non-negative spectrum (mean 1) on a ring: the window's known lags kept, the rest extended."""
    lags, vals = full_window(radius, latent)
    if known is not None:
        lags, vals = lags[_full_known(known)], vals[_full_known(known)]
    iy, ix = lags[:, 0] % ny, lags[:, 1] % nx
    r = _model(_fit_model(radius, latent, known), _ring_lags(ny, nx)).reshape(ny, nx)
    r[iy, ix] = vals
    for _ in range(PROJECTIONS):
        r = sfft.ifft2(np.maximum(sfft.fft2(r).real, 0.0)).real
        r[iy, ix] = vals
    s = np.maximum(sfft.fft2(r).real, 0.0)
    total = s.mean()  # r(0) of the result
    return s / total if total > 0 else np.ones_like(s)


def _flat_lags(lags: np.ndarray, ny: int, nx: int) -> tuple[np.ndarray, ...]:
    """Flat indices on the ny x nx ring of the lags h, of -h, and of every h_i + h_j and h_i - h_j
    (m x m): gathered by (row, column) pairs, the 2 m^2 sums were most of each refit step."""
    def flat(dy: np.ndarray, dx: np.ndarray) -> np.ndarray:
        return (dy % ny) * nx + dx % nx
    dy, dx = lags[:, 0], lags[:, 1]
    return (flat(dy, dx), flat(-dy, -dx), flat(dy[:, None] + dy[None, :], dx[:, None] + dx[None, :]),
            flat(dy[:, None] - dy[None, :], dx[:, None] - dx[None, :]))


def _refit(radius: int, target: np.ndarray, start: np.ndarray, curve: np.ndarray,
           known: np.ndarray | None = None, reference: np.ndarray | None = None) -> np.ndarray:
    """The spectrum, tilted from `reference` (else `start`), whose pixel autocorrelation over
    the window's known lags comes nearest `target` in least squares, lag 0 held at 1.

    The tilt is S = base exp(c_0 + sum_j c_j cos(2 pi k.h_j)) over the known lags h_j: of all
    spectra that meet the window, the one nearest the base in relative entropy has this form,
    so the base's shape stays wherever the window asks nothing (a band keeps the bands' shared
    spectrum but for what its own row measures) and S > 0 by construction. A small ridge on c
    keeps a window no spectrum can meet (a marginal that fits its region poorly) finite. The
    unknowns are the lags, not the frequencies: r(h_i) and its slopes in c,
    (r(h_i + h_j) + r(h_i - h_j)) / 2, all come from one inverse transform, so damped
    Gauss-Newton steps (Levenberg-Marquardt) converge in a few tens of transforms."""
    ny, nx = start.shape
    lags = np.array(window(radius), dtype=np.int64)
    goal = np.asarray(target, dtype=np.float64)
    if known is not None:
        lags, goal = lags[known], goal[known]
    lags, goal = np.concatenate(([[0, 0]], lags)), np.concatenate(([1.0], goal))
    m = len(lags)
    base = np.maximum(reference if reference is not None else start, 0.0) + 1e-3  # no frequency stuck at 0
    log_half = np.log(base[:, :nx // 2 + 1])
    at, mirror, plus, minus = _flat_lags(lags, ny, nx)
    slope = np.gradient(curve, GRID)
    weight = np.full(m, math.sqrt(2.0))  # each lag of the half stands for h and -h
    weight[0] = 10.0  # unit variance
    cells = np.concatenate((at, mirror))  # h and -h (lag 0 twice)

    def half_spectrum(c: np.ndarray) -> np.ndarray:
        tilt = np.bincount(cells, np.concatenate((0.5 * c, 0.5 * c)), ny * nx).reshape(ny, nx)
        return np.exp(np.minimum(log_half + sfft.rfft2(tilt).real, MAX_LOG))

    def evaluate(c: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        r = sfft.irfft2(half_spectrum(c), s=(ny, nx)).ravel()
        at_lags = r[at]
        p, dp = np.interp(at_lags, GRID, curve), np.interp(at_lags, GRID, slope)
        p[0], dp[0] = at_lags[0], 1.0  # lag 0 stays latent
        res = weight * (p - goal)
        jac = (weight * dp)[:, None] * (0.5 * (r.take(plus) + r.take(minus)))
        return res, jac, float(res @ res + RIDGE * (c @ c))

    c = np.zeros(m)
    c[0] = -math.log(float(base.mean()))
    res, jac, cost = evaluate(c)
    damping, grow = 1e-3, 2.0
    for _ in range(REFIT_ITERATIONS):
        if damping > 1e12:  # no step, however short, lowers the cost: it is as low as it goes
            break
        normal = jac.T @ jac
        normal[np.diag_indices(m)] += RIDGE
        gradient = jac.T @ res + RIDGE * c
        try:
            # Cholesky, as solve(assume_a="pos") does, without its per-call overhead (a third of the refit)
            step = -cho_solve(cho_factor(normal + damping * np.diag(np.diag(normal))), gradient)
        except (np.linalg.LinAlgError, ValueError):
            damping, grow = damping * grow, grow * 2.0
            continue
        res_t, jac_t, cost_t = evaluate(c + step)
        # the gain ratio: the cost's fall over the fall the linear model promised (Nielsen's rule)
        promised = -float(step @ gradient) - 0.5 * float(step @ (normal @ step))
        if math.isfinite(cost_t) and cost_t < cost and promised > 0:
            gain = (cost - cost_t) / (2.0 * promised)
            settled = cost - cost_t <= 1e-9 * cost or float(np.abs(step).max()) < 1e-7
            c, res, jac, cost = c + step, res_t, jac_t, cost_t
            damping, grow = damping * max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3), 2.0
            if settled:
                break
        else:
            damping, grow = damping * grow, grow * 2.0
    half = half_spectrum(c)
    s = np.empty((ny, nx))
    s[:, :half.shape[1]] = half
    rest = np.arange(half.shape[1], nx)  # the other half: S(k) = S(-k)
    s[:, rest] = half[(-np.arange(ny)) % ny][:, (-rest) % nx]
    mean = s.mean()
    return s / mean if math.isfinite(mean) and mean > 0 else base / base.mean()


def ring_spectrum(radius: int, pixel_acf: tuple[float, ...], curve: np.ndarray, ny: int, nx: int,
                  known: np.ndarray | None = None, reference: np.ndarray | None = None) -> np.ndarray:
    """The spectrum on a ring of ny x nx (at most RING each) for a measured pixel
    autocorrelation row, through the bands' grain `curve`; `known` (None: all) marks the lags
    measured, the others left to the fit. With none known the pixels are independent. A band
    of several is refined from the bands' shared spectrum (`reference`) and held near it
    beyond what its own row asks: fitted apart, two bands' spectra differed in detail no row
    measured, and bands that correlate 0.98 cannot then reach it (their correlation is at
    most the spectra's overlap, mean sqrt(S_i S_j), which fell to 0.86)."""
    acf = np.asarray(pixel_acf, dtype=np.float64)
    if known is not None and not np.any(known):
        return np.ones((ny, nx))
    known = None if known is None or np.all(known) else np.asarray(known, dtype=bool)
    start = reference if reference is not None else _projected(radius, latent_acf(acf, curve), ny, nx, known)
    return _refit(radius, acf, start, curve, known, reference)


def _full_known(known: np.ndarray) -> np.ndarray:
    """`known` over full_window's lags: the origin, then the window and its mirror."""
    return np.concatenate(([True], known, known))


def _axis_weights(n: int, g: int) -> np.ndarray:
    """(n, g): periodic linear interpolation from g frequencies to n."""
    if n == g:
        return np.eye(n, dtype=np.float32)
    pos = np.arange(n) * (g / n)
    i0 = np.floor(pos).astype(np.int64)
    f = (pos - i0).astype(np.float32)
    w = np.zeros((n, g), np.float32)
    w[np.arange(n), i0 % g] += 1 - f
    w[np.arange(n), (i0 + 1) % g] += f
    return w


def amplitude(small: np.ndarray, ny: int, nx: int) -> np.ndarray:
    """sqrt(S) on the rfft half of the ny x nx grid (nx // 2 + 1 columns), float32, S of mean 1
    over the whole grid: the ring's spectrum interpolated along each axis (a ring of no power
    stands for white noise, as `ring_spectrum` gives for one)."""
    wy, wx = _axis_weights(ny, small.shape[0]), _axis_weights(nx, small.shape[1])[:nx // 2 + 1]
    s = wy @ small.astype(np.float32) @ wx.T
    weights = np.full(s.shape[1], 2.0)  # the other half of the grid mirrors these columns
    weights[0] = 1.0
    if nx % 2 == 0:
        weights[-1] = 1.0
    mean = float(s.sum(axis=0, dtype=np.float64) @ weights) / (ny * nx)
    if not (math.isfinite(mean) and mean > 0.0):
        s, mean = np.ones_like(s), 1.0
    _mean_power_to_longest_waves(s)
    return np.sqrt(np.maximum(s / np.float32(mean), 0.0), dtype=np.float32)


def _mean_power_to_longest_waves(s: np.ndarray) -> None:
    """The zero frequency's power moved, in place, to the eight frequencies around it (in
    proportion to theirs). A draw fixes its mean, so that power would be lost; its variance is then
    scaled back, and every lag's autocorrelation fell by (1 - r) p0 / (1 - p0). On a box near
    RING (a 128-pixel image) p0 is a quarter of the power: a grain measured at 0.52 came back at
    0.38. The measured window is already the mean-removed correlation: the longest waves keep it."""
    ny = s.shape[0]
    # the half grid's cells for the full grid's (0, +-1), (+-1, 0), (+-1, +-1), with how many each stands for
    cells = (np.array([0, 1, ny - 1, 1, ny - 1]), np.array([1, 0, 0, 1, 1]))
    counts = np.array([2.0, 1.0, 1.0, 2.0, 2.0])
    around = float(s[cells].astype(np.float64) @ counts)
    moved = float(s[0, 0])
    if moved <= 0.0:
        return
    if around > 0.0:
        s[cells] *= np.float32(1.0 + moved / around)
    else:
        s[cells] = np.float32(moved / counts.sum())
    s[0, 0] = 0.0
