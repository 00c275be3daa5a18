"""The measured pixel correlations -> the normal-score (latent) correlations synthesis draws with.

Each band's pixels are level(Z) for its map (tools.analysis.levelmap), so the pixel correlation
of two bands, or of a band with itself at a lag, is a known increasing function g(rho) of the
latent correlation rho (`pixel_corr`, rounding and truncation included: NORTA).

grain   per lag, the rho whose pixel autocorrelation equals the measured one; a row shared by
        the bands is matched by their average g. g of a band with itself reaches 1 at rho = 1,
        so every measured value is reachable.
bands   the valid correlation matrix R whose pixel correlations g_ij(R_ij) come nearest the
        measured ones, least squares in the pixel domain over valid matrices (R = normalised
        L L^T). Matching each pair alone and then projecting the latent matrix to the nearest
        valid one moves the entries where g is steepest, near |rho| = 1, and loses up to 0.2
        of pixel correlation there. Where the marginals cannot reach a measured value at all
        (the comonotone bound of two curves lies below it) the residual says by how much.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np
from scipy.optimize import least_squares

from tools.analysis.levelmap import LevelMap, pixel_corr

GRID = np.concatenate((np.linspace(-0.999, 0.95, 1951), np.linspace(0.95, 0.99999, 2000)[1:]))


def _live(maps: list[LevelMap]) -> list[LevelMap]:
    return [m for m in maps if m.sd > 0] or maps


@lru_cache(maxsize=4096)
def curve(a: LevelMap, b: LevelMap) -> np.ndarray:
    """Pixel correlation of bands a and b (or of a band with itself) at each latent rho of GRID,
    non-decreasing (as in exact arithmetic: the series' rounding guarded)."""
    g = np.maximum.accumulate(pixel_corr(a, b, GRID, same=a is b))
    g.flags.writeable = False
    return g


def grain_curve(maps: list[LevelMap]) -> np.ndarray:
    """The bands' average pixel autocorrelation at each latent rho of GRID (non-decreasing)."""
    return np.mean([curve(m, m) for m in _live(maps)], axis=0)


def latent_acf(pixel_acf: np.ndarray, curve: np.ndarray) -> np.ndarray:
    """Latent autocorrelation per lag for a pixel autocorrelation, through `grain_curve`."""
    return np.interp(np.clip(pixel_acf, curve[0], curve[-1]), curve, GRID)


def _matrix(params: np.ndarray, n: int) -> np.ndarray:
    low = np.zeros((n, n))
    low[np.tril_indices(n)] = params
    low /= np.linalg.norm(low, axis=1, keepdims=True)
    return low @ low.T


def _nearest_valid(m: np.ndarray, floor: float = 1e-3) -> np.ndarray:
    w, v = np.linalg.eigh(0.5 * (m + m.T))
    m = (v * np.maximum(w, floor)) @ v.T
    d = np.sqrt(np.diag(m))
    return m / np.outer(d, d)


def latent_bands(measured: np.ndarray, maps: list[LevelMap]) -> tuple[np.ndarray, np.ndarray]:
    """(latent correlation matrix, the pixel correlation matrix it gives) for the measured
    B x B pixel correlation matrix; bands without spread are drawn independently."""
    n = len(maps)
    live = np.array([m.sd > 0 for m in maps])
    pairs = [(i, j) for i, j in zip(*np.triu_indices(n, 1)) if live[i] and live[j]]
    start = np.eye(n)
    curves = {(i, j): curve(maps[i], maps[j]) for i, j in pairs}
    for (i, j), g in curves.items():  # pairwise inversion: the starting point
        start[i, j] = start[j, i] = np.interp(np.clip(measured[i, j], g[0], g[-1]), g, GRID)
    if not pairs:
        return np.eye(n), np.eye(n)
    start = _nearest_valid(start)

    slopes = [np.gradient(g, GRID) for g in curves.values()]
    rows, cols = np.tril_indices(n)
    at = np.full((n, n), -1)
    at[rows, cols] = np.arange(len(rows))  # each parameter's place in its row of the factor
    first, second = (np.array(side) for side in zip(*curves))  # each pair's bands
    pair = np.arange(len(first))[:, None]

    def residual(p: np.ndarray) -> np.ndarray:
        r = _matrix(p, n)
        return np.array([np.interp(r[i, j], GRID, g) - measured[i, j] for (i, j), g in curves.items()])

    def jacobian(p: np.ndarray) -> np.ndarray:
        # r_ij = u_i . u_j with u the factor's rows made unit: d r_ij / d row_i = (u_j - r_ij u_i) / |row_i|,
        # in closed form where differences cost a residual per parameter (6 bands: 21)
        low = np.zeros((n, n))
        low[rows, cols] = p
        norm = np.linalg.norm(low, axis=1)
        u = low / norm[:, None]
        r = np.einsum("kc,kc->k", u[first], u[second])
        slope = np.array([np.interp(v, GRID, d) for v, d in zip(r, slopes)])
        jac = np.zeros((len(first), len(p)))
        for a, b in ((first, second), (second, first)):  # a pair's two rows hold parameters of their own
            place = at[a]
            live = place >= 0
            part = slope[:, None] * (u[b] - r[:, None] * u[a]) / norm[a][:, None]
            jac[np.broadcast_to(pair, place.shape)[live], place[live]] = part[live]
        return jac

    p0 = np.linalg.cholesky(start + 1e-9 * np.eye(n))[np.tril_indices(n)]
    # a matrix the marginals cannot reach (a multi-spectral camera's bands at 0.98 and more) leaves a
    # flat valley the fit crawls along: 20 steps a parameter end within 1e-3 of where 200 do (6 bands:
    # 0.5 s against 22 s with differenced slopes), and 3 colour bands settle in a few
    fit = least_squares(residual, p0, jac=jacobian, method="trf", xtol=1e-10, ftol=1e-10, max_nfev=20 * len(p0))
    latent = _matrix(fit.x, n)
    for k in np.flatnonzero(~live):  # nothing to correlate with a constant band
        latent[k, :] = latent[:, k] = 0.0
    np.fill_diagonal(latent, 1.0)
    latent = _nearest_valid(latent, 1e-6)
    reached = np.eye(n)
    for i, j in pairs:
        reached[i, j] = reached[j, i] = float(pixel_corr(maps[i], maps[j], latent[i, j]))
    return latent, reached


def corrected(latent: np.ndarray, measured: np.ndarray, drawn: np.ndarray, maps: list[LevelMap],
              reach: float) -> np.ndarray:
    """One Newton step on a draw's latent band matrix: each pair whose drawn pixel correlation
    misses the measured one (and which the marginals can reach within `reach`) moves by the miss
    over the slope of its pixel curve, then the nearest valid matrix. One realisation of a long
    grain through heavy-tailed maps scatters the pixel correlation by up to 0.05 even when its
    latent sample correlation is exact; this takes that scatter out."""
    out = latent.copy()
    for i, j in zip(*np.triu_indices(len(maps), 1)):
        if maps[i].sd <= 0 or maps[j].sd <= 0:
            continue
        g = curve(maps[i], maps[j])
        if abs(float(np.interp(latent[i, j], GRID, g)) - measured[i, j]) > reach:
            continue  # out of the marginals' reach: a step would only push toward the bound
        slope = float(np.interp(latent[i, j], GRID, np.gradient(g, GRID)))
        if slope > 1e-3:
            out[i, j] = out[j, i] = float(np.clip(latent[i, j] + (measured[i, j] - drawn[i, j]) / slope,
                                                  GRID[0], GRID[-1]))
    return _nearest_valid(out, 1e-6)
