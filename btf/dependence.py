"""A region's grain and band dependence: the record robot and host share.

corr  the correlation matrix of the bands' pixel values, upper triangle (row-major);
dx    the autocorrelation of the pixels at horizontal lags LAGS (band average);
dy    the same at vertical lags.
The robot measures it (btf.fit.dependence), the packet carries it in int8 steps
(radio.packets.dependence), the host synthesizes with it (tools.analysis.fields).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

LAGS = (1, 2, 4, 8)


@dataclass(frozen=True, slots=True)
class Dependence:
    """One region's dependence: band correlations (upper triangle, row-major) and autocorrelation at LAGS."""

    corr: tuple[float, ...]
    dx: tuple[float, ...]
    dy: tuple[float, ...]

    def __post_init__(self) -> None:
        for name in ("corr", "dx", "dy"):
            values = getattr(self, name)
            if not all(math.isfinite(v) and -1.0 <= v <= 1.0 for v in values):
                raise ValueError(f"dependence {name} values must lie in [-1, 1], got {values}")
        if len(self.dx) != len(LAGS) or len(self.dy) != len(LAGS):
            raise ValueError(f"dependence needs {len(LAGS)} lags per direction")
        bands_of(len(self.corr))  # a triangle of some band count

    @property
    def n_bands(self) -> int:
        return bands_of(len(self.corr))

    def matrix(self) -> np.ndarray:
        """The full B x B correlation matrix."""
        b = self.n_bands
        m = np.eye(b)
        iu = np.triu_indices(b, 1)
        m[iu] = self.corr
        m[(iu[1], iu[0])] = self.corr
        return m

    @classmethod
    def independent(cls, n_bands: int) -> Dependence:
        return cls((0.0,) * corr_size(n_bands), (0.0,) * len(LAGS), (0.0,) * len(LAGS))


def corr_size(n_bands: int) -> int:
    if n_bands < 1:
        raise ValueError(f"need at least one band, got {n_bands}")
    return n_bands * (n_bands - 1) // 2


def bands_of(n_corr: int) -> int:
    b = (1 + math.isqrt(1 + 8 * n_corr)) // 2
    if corr_size(b) != n_corr:
        raise ValueError(f"{n_corr} correlations are not the upper triangle of a square matrix")
    return b
