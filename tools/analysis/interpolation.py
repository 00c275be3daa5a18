"""Interpolation over view and illumination directions: quantile blending with barycentric weights.

A direction (elevation above the horizon, azimuth) is placed on the azimuthal equidistant
map of the hemisphere, r = (90 - elevation) / 90 at the azimuth: nadir is the centre, the
azimuth wraps without a seam, and along one azimuth the distance is linear in elevation.
View alone gives 2 coordinates, view and light 4. Measured directions are triangulated
(Delaunay, scipy.spatial) and a query gets the barycentric weights of its simplex; the
weights are non-negative, sum to 1 and reproduce the query's position. An angle that no
measured direction varies is taken as the measured one (the scene does not need it), and
directions lying on a line or a plane are triangulated in that line or plane.

Synthesis draws one z per pixel and band, maps it through every neighbour's quantile
function x_of_z and blends with the weights (displacement interpolation, as tools.analysis.synth).
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from btf.johnson import Johnson
from tools.analysis.radiometry import sweep_models
from tools.analysis.synth import ExtrapolationWarning, MissingModels, blend_pixels, fill
from tools.analysis.tiles import Draws, label_counts, region

Models = Mapping[tuple[int, int], Johnson]
_SAME = 1e-9  # degrees: angles closer than this are one angle


@dataclass(frozen=True, slots=True)
class Direction:
    """View (and optionally light) direction in degrees; elevation above the horizon."""

    elevation: float
    azimuth: float = 0.0
    light_elevation: float | None = None
    light_azimuth: float | None = None

    def __post_init__(self) -> None:
        for name in ("elevation", "light_elevation"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and 0.0 <= v <= 90.0):
                raise ValueError(f"{name.replace('_', ' ')} {v:g} outside 0..90 degrees")
        for name in ("azimuth", "light_azimuth"):
            v = getattr(self, name)
            if v is not None and not math.isfinite(v):
                raise ValueError(f"{name.replace('_', ' ')} {v} is not finite")
        if (self.light_elevation is None) != (self.light_azimuth is None):
            raise ValueError("the light needs both its elevation and its azimuth")

    @property
    def has_light(self) -> bool:
        return self.light_elevation is not None

    def angles(self) -> tuple[float, ...]:
        base = (float(self.elevation), float(self.azimuth) % 360.0)
        return base + ((float(self.light_elevation), float(self.light_azimuth) % 360.0) if self.has_light else ())


def parse_direction(text: str) -> Direction:
    """`EL`, `EL,AZ` or `EL,AZ,LIGHT_EL,LIGHT_AZ` in degrees."""
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise ValueError(f"angle {text!r}: expected EL[,AZ[,LIGHT_EL,LIGHT_AZ]] in degrees") from None
    if len(values) not in (1, 2, 4):
        raise ValueError(f"angle {text!r}: give 1, 2 or 4 comma-separated angles, got {len(values)}")
    return Direction(*values)


def _plane(angles: np.ndarray) -> np.ndarray:
    """(n, 2k) map coordinates of (n, 2k) (elevation, azimuth) pairs."""
    out = np.empty_like(angles)
    r = (90.0 - angles[:, 0::2]) / 90.0
    az = np.radians(angles[:, 1::2])
    out[:, 0::2], out[:, 1::2] = r * np.sin(az), r * np.cos(az)
    return out


class DirectionInterpolator:
    """Barycentric weights over a fixed set of measured directions."""

    def __init__(self, directions: Sequence[Direction]) -> None:
        if not directions:
            raise MissingModels("no measured directions to interpolate between")
        lights = {d.has_light for d in directions}
        if len(lights) > 1:
            raise ValueError("some measured directions have illumination angles and some do not")
        self.has_light = lights.pop()
        self.angles = np.array([d.angles() for d in directions], dtype=np.float64)
        spread = self.angles.max(axis=0) - self.angles.min(axis=0)
        self.fixed = spread <= _SAME  # angles the measurements never vary
        self.points = _plane(self.angles)
        self.centre = self.points.mean(axis=0)
        _, s, vt = np.linalg.svd(self.points - self.centre, full_matrices=False)
        rank = int(np.sum(s > 1e-9 * max(1.0, float(s[0]) if s.size else 1.0)))
        self.basis = vt[:rank]
        self.reduced = (self.points - self.centre) @ self.basis.T
        self._tri = None
        if rank >= 2:
            from scipy.spatial import Delaunay, QhullError

            try:
                self._tri = Delaunay(self.reduced)
            except QhullError:
                self._tri = Delaunay(self.reduced, qhull_options="QJ")  # nearly degenerate: joggle

    def _query(self, query: Direction) -> np.ndarray:
        if query.has_light and not self.has_light:
            raise ValueError("the measured directions have no illumination angles; leave out the light")
        q = np.array(query.angles() if self.has_light else query.angles()[:2], dtype=np.float64)
        if self.has_light and not query.has_light:
            if not (self.fixed[2] and self.fixed[3]):
                raise ValueError("the measured directions vary in illumination; give the light's "
                                 "elevation and azimuth")
            q = np.concatenate([q, self.angles[0, 2:]])
        names = ("view elevation", "view azimuth", "light elevation", "light azimuth")
        for k in np.flatnonzero(self.fixed):
            const = self.angles[0, k]
            differs = abs((q[k] - const + 180.0) % 360.0 - 180.0) if k % 2 else abs(q[k] - const)
            if differs > 1e-6 and not (k % 2 and q[k - 1] >= 90.0):  # azimuth at the zenith is no angle
                warnings.warn(f"every measurement has {names[k]} {const:g}; using it instead of {q[k]:g}",
                              ExtrapolationWarning, stacklevel=3)
            q[k] = const
        return q

    def weights(self, query: Direction) -> list[tuple[int, float]]:
        """(index of a measured direction, weight) pairs, weights > 0 summing to 1."""
        q = self._query(query)
        p = _plane(q[None, :])[0]
        x = (p - self.centre) @ self.basis.T
        if np.linalg.norm(p - self.centre - x @ self.basis) > 1e-6:
            warnings.warn("the direction lies off the measured directions' span; using its projection",
                          ExtrapolationWarning, stacklevel=2)
        rank = self.basis.shape[0]
        if rank == 0:
            return [(0, 1.0)]
        if rank == 1:
            return self._along_line(x[0])
        simplex = int(self._tri.find_simplex(x[None, :], tol=1e-9)[0])
        if simplex < 0:
            return self._nearest(x)
        t = self._tri.transform[simplex]
        b = t[:rank] @ (x - t[rank])
        w = np.append(b, 1.0 - b.sum())
        w = np.where(w > 1e-12, w, 0.0)
        w /= w.sum()
        return [(int(i), float(v)) for i, v in zip(self._tri.simplices[simplex], w) if v > 0.0]

    def _along_line(self, x: float) -> list[tuple[int, float]]:
        t = self.reduced[:, 0]
        order = np.argsort(t)
        ts = t[order]
        if x <= ts[0] - 1e-12 or x >= ts[-1] + 1e-12:
            return self._nearest(np.array([x]))
        k = int(np.clip(np.searchsorted(ts, x), 1, len(ts) - 1))
        lo, hi = int(order[k - 1]), int(order[k])
        gap = ts[k] - ts[k - 1]
        w = 1.0 if gap <= 0.0 else float(np.clip((x - ts[k - 1]) / gap, 0.0, 1.0))
        return [(i, v) for i, v in ((lo, 1.0 - w), (hi, w)) if v > 0.0]

    def _nearest(self, x: np.ndarray) -> list[tuple[int, float]]:
        """Weights of the hull point nearest to x: min |sum w_i p_i - x| with w >= 0, sum w = 1."""
        from scipy.optimize import nnls

        big = 1e3  # weight of the sum-to-one row
        a = np.vstack([self.reduced.T, np.full(len(self.reduced), big)])
        w, _ = nnls(a, np.append(x, big))
        w = np.where(w > 1e-9, w, 0.0)
        w /= w.sum()
        warnings.warn(f"the direction lies outside the measured directions; using the nearest point "
                      f"of their hull (between {np.count_nonzero(w)} measured directions)",
                      ExtrapolationWarning, stacklevel=3)
        return [(int(i), float(w[i])) for i in np.flatnonzero(w)]


def capture_direction(c) -> Direction:
    """A stored capture's measured view (and light) direction, to a millionth of a degree."""
    lel, laz = c.illumination
    return Direction(round(c.measured[0], 6), round(c.measured[1] % 360.0, 6),
                     None if lel is None else round(lel, 6), None if laz is None else round(laz % 360.0, 6))


def latest_by_direction(store, robot: str | None = None, space: str | None = None,
                        scene: str | None = None) -> dict[Direction, object]:
    """For every measured direction in a Store, its latest capture."""
    latest: dict[Direction, object] = {}
    for c in store.captures(robot, space, scene):
        d = capture_direction(c)
        if d not in latest or c.id > latest[d].id:
            latest[d] = c
    return latest


def models_by_direction(store, robot: str | None = None, space: str | None = None,
                        scene: str | None = None, exposure_us: float | None = None,
                        normalise: bool = False) -> dict[Direction, dict[tuple[int, int], Johnson]]:
    """For every measured direction in a Store, the models of its latest capture, at its
    exposure or as `tools.analysis.radiometry.sweep_models` brings them to `exposure_us` or normalises them."""
    return sweep_models(store, latest_by_direction(store, robot, space, scene), exposure_us, normalise)


def synthesize_blend(mask: np.ndarray, neighbours: Sequence[tuple[float, Models]],
                     rng: np.random.Generator, levels: int = 256) -> np.ndarray:
    """H x W x B image: one z per pixel and band, x = sum_k w_k x_k(z), rounded and clipped."""
    if mask.ndim != 2:
        raise ValueError(f"mask must be H x W, got shape {mask.shape}")
    if not neighbours:
        raise MissingModels("no models to synthesize from")
    n_bands = max(b for _, models in neighbours for _, b in models) + 1 if any(m for _, m in neighbours) else 0
    if n_bands == 0:
        raise MissingModels("no models to synthesize from")
    labels = list(label_counts(mask))
    for _, models in neighbours:
        missing = sorted({lab for lab in labels for b in range(n_bands) if (lab, b) not in models})
        if missing:
            raise MissingModels(f"mask label(s) {missing} have no models at a neighbouring direction "
                                f"(models exist for labels {sorted({lab for lab, _ in models})})")
    out = np.zeros(mask.shape + (n_bands,), dtype=np.uint8 if levels <= 256 else np.uint16)
    for label in labels:  # in row tiles, one random stream per region and band (tools.analysis.synth.fill)
        where = region(mask, label)
        for b in range(n_bands):
            to_pixels = blend_pixels([(w, models[(label, b)]) for w, models in neighbours], levels)
            draws = Draws(rng.standard_normal, where.count)
            fill(out, b, mask, where, lambda r, sel, k: to_pixels(draws.take(k)))
    return out


def synthesize_at_direction(by_direction: Mapping[Direction, Models], mask: np.ndarray, query: Direction,
                            rng: np.random.Generator, levels: int = 256) -> np.ndarray:
    """An image at `query` blended from the measured directions around it."""
    dirs = list(by_direction)
    weights = DirectionInterpolator(dirs).weights(query)
    return synthesize_blend(mask, [(w, by_direction[dirs[i]]) for i, w in weights], rng, levels)


def requested_direction(angle: str, azimuth: float | None = None, light_elevation: float | None = None,
                        light_azimuth: float | None = None) -> Direction | None:
    """The direction asked for on the command line; None for a lone elevation (the 1-D path)."""
    extra = (azimuth, light_elevation, light_azimuth)
    if "," not in angle and all(v is None for v in extra):
        try:
            value = float(angle)
        except ValueError:
            raise ValueError(f"angle {angle!r}: expected EL[,AZ[,LIGHT_EL,LIGHT_AZ]] in degrees") from None
        if not math.isfinite(value):
            raise ValueError(f"angle {angle!r} is not a finite number of degrees")
        return None
    d = parse_direction(angle)
    if "," in angle and any(v is not None for v in extra):
        raise ValueError(f"angle {angle!r}: give the angles either in --angle or as separate options")
    if "," in angle:
        return d
    return Direction(d.elevation, 0.0 if azimuth is None else azimuth, light_elevation, light_azimuth)
