"""The BTF of one robot's sweep of one scene, as numbers: for each region (label) and band, the
model at every measured direction, its moments on the sensor's levels, and the curve the
interpolation draws between the measured directions.

The models are those `btf-host synth --angle` interpolates: each capture's regions at its own
exposure (`tools.analysis.radiometry.sweep_models`), the latest capture per measured elevation
when the sweep varied the elevation alone (`synth --angle EL`, `tools.analysis.synth.neighbours`),
else per measured direction (`synth --angle EL,AZ[,LIGHT_EL,LIGHT_AZ]`,
`tools.analysis.interpolation.DirectionInterpolator`). Weights come from that same code, and an
interpolated distribution is the quantile blend synthesis draws from, x(z) = sum w_k x_k(z)
rounded and clipped to the levels: its level probabilities are exact (`blend_probabilities`).

Moments are those of the level probabilities (mean and standard deviation in levels, skewness,
kurtosis beta2 with 3 for a normal): finite for every model, unlike a heavy-tailed SU's own.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from btf.johnson import Z_CLIP, Johnson, normal_cdf
from tools.analysis.interpolation import Direction, DirectionInterpolator, capture_direction, latest_by_direction
from tools.analysis.radiometry import sweep_models
from tools.analysis.synth import ExtrapolationWarning, neighbours

AXES = ("elevation", "azimuth", "light_elevation", "light_azimuth")
AXIS_TITLES = {"elevation": "view elevation", "azimuth": "view azimuth", "light_elevation": "light elevation",
               "light_azimuth": "light azimuth"}
BISECTIONS = 56  # halvings of [-Z_CLIP, Z_CLIP]: thresholds to ~1e-15 on the normal scale
CURVE_POINTS = 61  # interpolated points along a series, between its first and last measured angle
VARY_DEG = 1.5  # angles nearer than this are one pose (a tracker's jitter, a hand-placed capture)


@dataclass(frozen=True, slots=True)
class Moments:
    """Of a distribution over levels: mean and sd in levels; skewness and kurtosis (beta2)
    dimensionless, None for a point mass (no spread to divide by)."""

    mean: float
    sd: float
    skewness: float | None
    kurtosis: float | None

    def as_dict(self) -> dict[str, float | None]:
        return {"mean": self.mean, "sd": self.sd, "skewness": self.skewness, "kurtosis": self.kurtosis}


def moments(p: np.ndarray) -> Moments:
    """Moments of level probabilities p[k] (level k = 0 .. len(p) - 1)."""
    p = np.clip(np.asarray(p, dtype=np.float64), 0.0, None)
    total = float(p.sum())
    if not total > 0.0:
        raise ValueError("level probabilities sum to zero")
    p = p / total
    k = np.arange(p.size, dtype=np.float64)
    mean = float(k @ p)
    d = k - mean
    var = float((d * d) @ p)
    if var <= 1e-12:
        return Moments(mean, 0.0, None, None)
    sd = math.sqrt(var)
    return Moments(mean, sd, float((d ** 3) @ p) / sd ** 3, float((d ** 4) @ p) / var ** 2)


def _between(t: np.ndarray) -> np.ndarray:
    """Probabilities of (-inf, t0], (t0, t1], ..., (t_last, inf) for increasing t on the normal
    scale; intervals above the median from the upper tail (no 1 - Phi cancellation)."""
    cdf, sf = normal_cdf(t), normal_cdf(-t)
    lo = np.concatenate(([-np.inf], t))
    below = np.concatenate((cdf, [1.0])) - np.concatenate(([0.0], cdf))
    above = np.concatenate(([1.0], sf)) - np.concatenate((sf, [0.0]))
    return np.clip(np.where(lo >= 0.0, above, below), 0.0, None)


def blend_probabilities(weighted: Sequence[tuple[float, Johnson]], levels: int, exact: bool = True) -> np.ndarray:
    """Level probabilities of the pixels `tools.analysis.synth.blend_pixels` draws: x(z) =
    sum w_k x_k(z), rounded and clipped. x is non-decreasing in z, so level k takes z in
    [t_(k-1), t_k) with x(t_k) = k + 1/2: each t_k found by bisection (`exact`), or read off
    x on a fine grid of z (to ~1e-5, for drawing). One model alone is its own level_probabilities."""
    live = [(float(w), m) for w, m in weighted if w > 0.0]
    if not live:
        raise ValueError("no model with a positive weight")
    if len(live) == 1:
        return live[0][1].level_probabilities(levels)

    def x(z: np.ndarray) -> np.ndarray:
        out = np.zeros(z.shape)
        for w, m in live:
            out += w * m.x_of_z(z)
        return out

    half = np.arange(levels - 1, dtype=np.float64) + 0.5
    if not exact:
        return _between(_thresholds_on_grid(x, half))
    x_lo, x_hi = x(np.array([-Z_CLIP, Z_CLIP]))
    t = np.where(half < x_lo, -Z_CLIP, Z_CLIP)
    inner = np.flatnonzero((half >= x_lo) & (half < x_hi))
    if inner.size:
        a, b, target = np.full(inner.size, -Z_CLIP), np.full(inner.size, Z_CLIP), half[inner]
        for _ in range(BISECTIONS):
            mid = 0.5 * (a + b)
            below = x(mid) < target
            a, b = np.where(below, mid, a), np.where(below, b, mid)
        t[inner] = 0.5 * (a + b)
    return _between(t)


_GRID_Z = np.concatenate(([-Z_CLIP], np.linspace(-9.0, 9.0, 4097), [Z_CLIP]))


def _thresholds_on_grid(x, half: np.ndarray) -> np.ndarray:
    """sup {z: x(z) < h} for each h, x linear between the grid's points."""
    xs = x(_GRID_Z)
    j = np.searchsorted(xs, half, side="left")  # the first grid point where x reaches h
    inside = (j > 0) & (j < xs.size)
    k = np.clip(j, 1, xs.size - 1)
    x0, x1, z0, z1 = xs[k - 1], xs[k], _GRID_Z[k - 1], _GRID_Z[k]
    with np.errstate(divide="ignore", invalid="ignore"):
        frac = np.where(x1 > x0, (half - x0) / (x1 - x0), 1.0)
    return np.where(inside, z0 + np.clip(frac, 0.0, 1.0) * (z1 - z0), np.where(j == 0, -Z_CLIP, Z_CLIP))


def exact_l1(p: np.ndarray, q: np.ndarray) -> float:
    """Sum over the sensor's levels of |p - q|: 0 for the same distribution, 2 for disjoint ones."""
    return float(np.abs(np.asarray(p) - np.asarray(q)).sum())


def axis_value(d: Direction, axis: str) -> float | None:
    return getattr(d, axis)


@dataclass
class Btf:
    """One robot's BTF of one scene in one feature space: point i is a measured direction,
    its capture, its models (at the capture's exposure) and their pixel counts."""

    robot: str
    scene: str
    space: str
    band_names: tuple[str, ...]
    levels: int
    directions: list[Direction]
    captures: list[Any]  # tools.store.rows.StoredCapture
    models: list[dict[tuple[int, int], Johnson]]
    counts: list[dict[tuple[int, int], int]]
    varied: tuple[str, ...]  # the axes the sweep varied (commanded ones where the robot says)
    poses: list[dict[str, float | None]]  # per point, its nominal angle on each axis
    stored: int = 0  # captures of the robot, scene and space: more than the points where a direction was taken again
    _interpolators: dict = field(default_factory=dict, repr=False)
    _probs: dict = field(default_factory=dict, repr=False)

    @property
    def one_dimensional(self) -> bool:
        """Only the elevation varied: `synth --angle EL` interpolates along it."""
        return self.varied == ("elevation",)

    @property
    def main_axis(self) -> str:
        return self.varied[0] if self.varied else "elevation"

    def regions(self) -> list[tuple[int, int]]:
        return sorted({key for m in self.models for key in m})

    def band_name(self, band: int) -> str:
        return self.band_names[band] if band < len(self.band_names) else str(band)

    def at(self, label: int, band: int) -> list[int]:
        """The points that have a model of (label, band)."""
        return [i for i, m in enumerate(self.models) if (label, band) in m]

    def nominal(self, i: int, axis: str) -> float | None:
        """Point i's angle on `axis` as the sweep meant it: its group's (`_groups`) first angle."""
        return self.poses[i][axis]

    def probabilities(self, i: int, label: int, band: int) -> np.ndarray:
        key = (i, label, band)
        if key not in self._probs:
            self._probs[key] = self.models[i][(label, band)].level_probabilities(self.levels)
        return self._probs[key]

    def interpolator(self, points: tuple[int, ...]) -> DirectionInterpolator:
        if points not in self._interpolators:
            self._interpolators[points] = DirectionInterpolator([self.directions[i] for i in points])
        return self._interpolators[points]

    def weights(self, label: int, band: int, query: Direction, without: int | None = None) -> list[tuple[int, float]]:
        """(point, weight) of the interpolation at `query` from the points with (label, band)
        (but `without`), by the code `synth --angle` runs for this sweep. Warns
        ExtrapolationWarning where the query lies outside them."""
        idx = tuple(i for i in self.at(label, band) if i != without)
        if not idx:
            raise ValueError(f"no measured model of label {label} band {band} to interpolate from")
        if self.one_dimensional:
            els = [self.directions[i].elevation for i in idx]
            lo, hi, w = neighbours(els, query.elevation)
            pairs = [(idx[els.index(lo)], 1.0 - w), (idx[els.index(hi)], w)] if lo != hi else [(idx[els.index(lo)], 1.0)]
            return [(i, v) for i, v in pairs if v > 0.0]
        return [(idx[k], v) for k, v in self.interpolator(idx).weights(query)]

    def predicted(self, label: int, band: int, weighted: list[tuple[int, float]], exact: bool = True) -> np.ndarray:
        """Level probabilities of the interpolation with these (point, weight) pairs."""
        if len(weighted) == 1:
            return self.probabilities(weighted[0][0], label, band)
        return blend_probabilities([(w, self.models[i][(label, band)]) for i, w in weighted], self.levels, exact)

    def series(self, label: int, band: int, axis: str) -> dict[tuple, list[int]]:
        """The points of (label, band) grouped by their nominal angles on the other varied axes,
        each group ordered along `axis`: the lines of a plot against `axis`."""
        out: dict[tuple, list[int]] = {}
        others = [a for a in self.varied if a != axis]
        for i in self.at(label, band):
            out.setdefault(tuple(self.nominal(i, a) for a in others), []).append(i)
        for pts in out.values():
            pts.sort(key=lambda i: axis_value(self.directions[i], axis) or 0.0)
        return dict(sorted(out.items(), key=lambda kv: tuple(v or 0.0 for v in kv[0])))

    def series_name(self, axis: str, key: tuple) -> str:
        others = [a for a in self.varied if a != axis]
        return ", ".join(f"{AXIS_TITLES[a]} {v:g}°" for a, v in zip(others, key)) or "measured"


@dataclass(frozen=True, slots=True)
class CurvePoint:
    angle: float  # on the curve's axis, degrees
    probabilities: np.ndarray
    moments: Moments


def curve(btf: Btf, label: int, band: int, axis: str, points: list[int], key: tuple,
          n: int = CURVE_POINTS) -> list[CurvePoint]:
    """The interpolated distribution along `axis` from the series' first to its last measured
    angle (and at every measured one), the other varied axes held at the series' `key`."""
    values = sorted({float(axis_value(btf.directions[i], axis)) for i in points})
    if len(values) < 2:
        return []
    grid = np.union1d(np.linspace(values[0], values[-1], n), values)
    fixed = dict(zip([a for a in btf.varied if a != axis], key))
    base = btf.directions[points[0]]
    out = []
    with warnings.catch_warnings():
        # the series' nominal angles may lie a tracker's jitter off the measured ones' hull
        warnings.simplefilter("ignore", ExtrapolationWarning)
        for angle in grid:
            q = {a: fixed.get(a, axis_value(base, a)) for a in AXES}
            q[axis] = float(angle)
            p = btf.predicted(label, band, btf.weights(label, band, Direction(**q)), exact=False)
            out.append(CurvePoint(float(angle), p, moments(p)))
    return out


def _view_angles(c: Any, commanded: bool) -> dict[str, float | None]:
    view = c.commanded if commanded else c.measured
    lel, laz = c.illumination
    return {"elevation": view[0], "azimuth": (view[1] or 0.0) % 360.0, "light_elevation": lel,
            "light_azimuth": None if laz is None else laz % 360.0}


def _groups(values: list[float | None]) -> dict[float | None, float | None]:
    """Each angle -> the first of its group: angles less than VARY_DEG above a group's first are in it."""
    out: dict[float | None, float | None] = {None: None}
    first = None
    for v in sorted({v for v in values if v is not None}):
        if first is None or v - first >= VARY_DEG:
            first = v
        out[v] = first
    return out


def poses_of(caps: list) -> tuple[tuple[str, ...], list[dict[str, float | None]]]:
    """(the axes the captures varied, each capture's nominal angle per axis): commanded view
    angles where every capture has them, else measured ones, grouped within VARY_DEG."""
    commanded = all(c.commanded[0] is not None for c in caps)
    raw = [_view_angles(c, commanded) for c in caps]
    groups = {a: _groups([r[a] for r in raw]) for a in AXES}
    poses = [{a: groups[a][r[a]] for a in AXES} for r in raw]
    return tuple(a for a in AXES if len(set(groups[a].values()) - {None}) > 1), poses


def sources(store: Any, robot: str | None = None, scene: str | None = None) -> list[tuple[str, str, str]]:
    """(robot, scene, feature space) of every BTF the database holds, the filters applied."""
    return sorted({(c.robot, c.scene, c.space) for c in store.captures(robot=robot, scene=scene)})


def load(store: Any, robot: str, scene: str, space: str) -> Btf:
    """The BTF of one robot, scene and feature space (ValueError when it has no captures)."""
    caps = store.captures(robot=robot, space=space, scene=scene)
    if not caps:
        raise ValueError(f"no captures of robot {robot} scene {scene!r} in space {space}")
    varied, _ = poses_of(caps)
    if varied in ((), ("elevation",)):
        latest = store.latest_by_angle(robot=robot, space=space, scene=scene)
    else:
        latest = latest_by_direction(store, robot=robot, space=space, scene=scene)
    models = sweep_models(store, latest)
    order = sorted(latest, key=lambda k: tuple(v or 0.0 for v in capture_direction(latest[k]).angles()))
    chosen = [latest[k] for k in order]
    names = max((c.band_names for c in chosen), key=len)
    return Btf(robot, scene, space, names, max(c.levels for c in chosen), [capture_direction(c) for c in chosen],
               chosen, [models[k] for k in order],
               [{key: r.count for key, r in store.models(c.id).items()} for c in chosen], varied, poses_of(chosen)[1],
               len(caps))
