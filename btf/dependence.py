"""A region's record beside its band models: the levels it took, its grain and band dependence.

lo, hi  per band, the lowest and highest level the region's pixels took (what synthesis keeps
        every pixel within); () when unknown (records of robots older than the range)
corr    the correlation matrix of the bands' pixel values, upper triangle (row-major)
acf     the autocorrelation of the pixels at every lag of the half-plane window W(radius)
        (`window`), one row shared by the bands (their average) or one row per band
radius  the window's radius R: W(R) holds (0, 1..R) and (dy, -R..R) for dy = 1..R, 2R(R+1)
        lags; the other half follows from r(-h) = r(h)
unmeasured  per acf row, the window indices of the lags too few pixel pairs measured (each
        stored as 0.0, never to be read as "independent"); () when every lag was measured

corr and acf are None when the grain was not measured (the region is then drawn pixel by
pixel). The robot measures the record (btf.fit.dependence), the packet carries it in int8 steps
(radio.packets.dependence), the host synthesizes with it (tools.analysis.fields). Records of the
older layout, autocorrelation at LAGS along rows (dx) and columns (dy), are read by `from_lags`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

RADIUS = 6  # the window the robot measures: 84 lags
MAX_RADIUS = 8
LAGS = (1, 2, 4, 8)  # the older layout's lags along rows and columns


@lru_cache(maxsize=MAX_RADIUS + 1)
def window(radius: int = RADIUS) -> tuple[tuple[int, int], ...]:
    """The half-plane lags (dy, dx) of W(radius) in record order: (0, 1..R), then for
    dy = 1..R the lags (dy, -R..R)."""
    check_radius(radius)
    return tuple([(0, dx) for dx in range(1, radius + 1)]
                 + [(dy, dx) for dy in range(1, radius + 1) for dx in range(-radius, radius + 1)])


def window_size(radius: int) -> int:
    return 2 * radius * (radius + 1)


def check_radius(radius: int) -> None:
    if type(radius) is not int or not 1 <= radius <= MAX_RADIUS:
        raise ValueError(f"window radius {radius!r} outside 1..{MAX_RADIUS}")


def _unit(name: str, values) -> tuple[float, ...]:
    out = tuple(float(v) for v in values)
    if not all(math.isfinite(v) and -1.0 <= v <= 1.0 for v in out):
        raise ValueError(f"dependence {name} values must lie in [-1, 1], got {out}")
    return out


@dataclass(frozen=True, slots=True)
class Dependence:
    """One region's record: observed levels per band, and (when measured) its band
    correlations and autocorrelation on the window W(radius)."""

    corr: tuple[float, ...] | None = None
    acf: tuple[tuple[float, ...], ...] | None = None
    radius: int = RADIUS
    lo: tuple[int, ...] = ()
    hi: tuple[int, ...] = ()
    unmeasured: tuple[tuple[int, ...], ...] = ()

    def __post_init__(self) -> None:
        check_radius(self.radius)
        if (self.corr is None) != (self.acf is None):
            raise ValueError("dependence needs both the band correlations and the autocorrelation, or neither")
        if self.corr is None and not self.lo:
            raise ValueError("dependence holds neither a measurement nor the observed levels")
        if len(self.lo) != len(self.hi) or (self.lo and self.corr is not None
                                             and len(self.lo) != bands_of(len(self.corr))):
            raise ValueError(f"observed levels for {len(self.lo)} and {len(self.hi)} bands do not match the record")
        if any(type(v) is not int for v in self.lo + self.hi) or any(
                not 0 <= a <= b for a, b in zip(self.lo, self.hi)):
            raise ValueError(f"observed levels need 0 <= lo <= hi, got lo {self.lo}, hi {self.hi}")
        if self.corr is None:
            self._check_unmeasured()
            return
        object.__setattr__(self, "corr", _unit("corr", self.corr))
        rows = tuple(_unit("acf", row) for row in self.acf)
        object.__setattr__(self, "acf", rows)
        n = bands_of(len(self.corr))
        if len(rows) not in (1, n) or any(len(r) != window_size(self.radius) for r in rows):
            raise ValueError(f"dependence needs 1 or {n} rows of {window_size(self.radius)} lags "
                             f"(radius {self.radius}), got {[len(r) for r in rows]}")
        self._check_unmeasured()

    def _check_unmeasured(self) -> None:
        gaps = tuple(tuple(row) for row in self.unmeasured)
        if not any(gaps):
            object.__setattr__(self, "unmeasured", ())  # every lag measured, however it was said
            return
        if self.acf is None or len(gaps) != len(self.acf):
            raise ValueError(f"unmeasured lags need one entry per acf row, got {len(gaps)}")
        size = window_size(self.radius)
        for row, gap in zip(self.acf, gaps):
            if any(type(k) is not int for k in gap) or list(gap) != sorted(set(gap)) or not all(
                    0 <= k < size for k in gap):
                raise ValueError(f"unmeasured lags must be increasing window indices below {size}, got {gap}")
            if any(row[k] != 0.0 for k in gap):
                raise ValueError("an unmeasured lag must hold 0.0")
        object.__setattr__(self, "unmeasured", gaps)

    @property
    def n_bands(self) -> int:
        return len(self.lo) if self.corr is None else bands_of(len(self.corr))

    @property
    def measured(self) -> bool:
        """Whether the grain and band correlations were measured (else only the levels)."""
        return self.corr is not None

    @property
    def per_band(self) -> bool:
        return self.acf is not None and len(self.acf) > 1

    def band_acf(self, band: int) -> tuple[float, ...]:
        assert self.acf is not None
        return self.acf[band if len(self.acf) > 1 else 0]

    def known(self, row: int) -> np.ndarray:
        """Per window lag of an acf row, whether it was measured."""
        assert self.acf is not None
        out = np.ones(window_size(self.radius), dtype=bool)
        if self.unmeasured:
            out[list(self.unmeasured[row])] = False
        return out

    def acf_rows(self) -> list[list[float | None]]:
        """The acf rows with None at unmeasured lags (JSON null in stores and documents)."""
        assert self.acf is not None
        return [[None if not k else v for v, k in zip(row, self.known(i))] for i, row in enumerate(self.acf)]

    def matrix(self) -> np.ndarray:
        """The full B x B correlation matrix (identity when not measured)."""
        b = self.n_bands
        m = np.eye(b)
        if self.corr is not None:
            iu = np.triu_indices(b, 1)
            m[iu] = self.corr
            m[(iu[1], iu[0])] = self.corr
        return m

    def levels(self, band: int) -> tuple[int, int] | None:
        """(lo, hi) of a band, None when unknown."""
        return (self.lo[band], self.hi[band]) if self.lo else None

    @classmethod
    def independent(cls, n_bands: int, radius: int = RADIUS) -> Dependence:
        return cls((0.0,) * corr_size(n_bands), ((0.0,) * window_size(radius),), radius)

    @classmethod
    def observed(cls, lo, hi) -> Dependence:
        """Only the observed levels (the grain was not measured)."""
        return cls(lo=tuple(int(v) for v in lo), hi=tuple(int(v) for v in hi))

    @classmethod
    def from_rows(cls, corr, rows, radius: int = RADIUS, lo=(), hi=()) -> Dependence:
        """A record from acf rows holding None at unmeasured lags (`acf_rows`)."""
        acf = tuple(tuple(0.0 if v is None else float(v) for v in row) for row in rows)
        gaps = tuple(tuple(k for k, v in enumerate(row) if v is None) for row in rows)
        return cls(tuple(float(v) for v in corr), acf, radius, tuple(lo), tuple(hi), gaps)

    @classmethod
    def from_lags(cls, corr, dx, dy, lo=(), hi=()) -> Dependence:
        """A record of the older layout (autocorrelation at LAGS along rows and columns) on the
        window of radius MAX_RADIUS, as the separable product r(dy, dx) = r_y(dy) r_x(dx) it stood for."""
        rx, ry = _lag_sequence(_unit("dx", dx)), _lag_sequence(_unit("dy", dy))
        acf = tuple(float(np.clip(ry[abs(a)] * rx[abs(b)], -1.0, 1.0)) for a, b in window(MAX_RADIUS))
        return cls(_unit("corr", corr), (acf,), MAX_RADIUS, tuple(lo), tuple(hi))

    def with_levels(self, lo, hi) -> Dependence:
        return Dependence(self.corr, self.acf, self.radius, tuple(int(v) for v in lo), tuple(int(v) for v in hi),
                          self.unmeasured)


def _lag_sequence(values: tuple[float, ...]) -> np.ndarray:
    """Autocorrelation at lags 0..MAX_RADIUS from its values at LAGS: joined geometrically
    between positive values (exact for exponential decay), linearly otherwise."""
    if len(values) != len(LAGS):
        raise ValueError(f"the older layout has {len(LAGS)} lags per direction, got {len(values)}")
    known_h = (0, *LAGS)
    known_r = (1.0, *values)
    out = np.interp(np.arange(MAX_RADIUS + 1), known_h, known_r)
    for (h0, r0), (h1, r1) in zip(zip(known_h, known_r), zip(known_h[1:], known_r[1:])):
        if r0 > 0.0 and r1 > 0.0:
            for h in range(h0 + 1, min(h1, MAX_RADIUS + 1)):
                out[h] = r0 * (r1 / r0) ** ((h - h0) / (h1 - h0))
    return out


def corr_size(n_bands: int) -> int:
    if n_bands < 1:
        raise ValueError(f"need at least one band, got {n_bands}")
    return n_bands * (n_bands - 1) // 2


def bands_of(n_corr: int) -> int:
    b = (1 + math.isqrt(1 + 8 * n_corr)) // 2
    if corr_size(b) != n_corr:
        raise ValueError(f"{n_corr} correlations are not the upper triangle of a square matrix")
    return b
