"""Leave one angle out: how well the interpolation in use predicts a measured model from the
others, against the nearest measured angle alone (the baseline an interpolation must beat).

For each region, band and measured direction with measured neighbours on both sides (along the
elevation for a sweep of elevations; inside the other directions' hull, within a tracker's
jitter, for one over several angles), the direction's model is predicted from the other
directions by `Btf.weights` (the code `synth --angle` runs) and compared with the measured one
by the exact L1 between their level probabilities over the sensor's levels, as the fit's own
benchmarks compare models and histograms. The baseline is the model of the nearest other
direction (on the hemisphere's map the interpolation works on; of two equally near, the better).
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from tools.analysis.btf_view import AXIS_TITLES, Btf, exact_l1, moments
from tools.analysis.synth import ExtrapolationWarning

JITTER = 0.5 / 90.0  # half a degree on the map: a prediction this near the left-out direction is at it
_TIE = 1e-9


@dataclass(frozen=True, slots=True)
class LooRow:
    label: int
    band: int
    point: int  # the left-out point of the Btf
    interpolated: float  # exact L1 of the interpolation from the others
    nearest: float  # exact L1 of the nearest other direction's model
    nearest_point: int
    neighbours: tuple[tuple[int, float], ...]  # (point, weight) of the interpolation

    @property
    def better(self) -> bool:
        return self.interpolated < self.nearest


def _positions(btf: Btf, idx: tuple[int, ...]) -> np.ndarray:
    """Where the points lie on the map the interpolation works on (elevation alone for a sweep
    of elevations, in degrees / 90 like the map)."""
    if btf.one_dimensional:
        return np.array([[btf.directions[i].elevation / 90.0] for i in idx])
    return btf.interpolator(idx).points


def _interior(btf: Btf, pos: np.ndarray, k: int, weights: list[tuple[int, float]], where: dict[int, int]) -> bool:
    """Whether the interpolation at point k stands between measured neighbours: at least two
    carry weight and their blend of positions is the left-out one (within JITTER)."""
    if len([w for _, w in weights if w > 0.0]) < 2:
        return False
    at = sum(w * pos[where[i]] for i, w in weights)
    return float(np.linalg.norm(at - pos[k])) <= JITTER


def leave_one_out(btf: Btf, label: int | None = None, band: int | None = None) -> list[LooRow]:
    """One row per interior (region, band, direction), for the given region and band or all."""
    rows = []
    for lab, b in btf.regions():
        if label not in (None, lab) or band not in (None, b):
            continue
        idx = tuple(btf.at(lab, b))
        if len(idx) < 3:
            continue
        pos = _positions(btf, idx)
        where = {i: k for k, i in enumerate(idx)}
        for k, i in enumerate(idx):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", ExtrapolationWarning)  # outside: not interior
                weights = btf.weights(lab, b, btf.directions[i], without=i)
            if not _interior(btf, pos, k, weights, where):
                continue
            measured = btf.probabilities(i, lab, b)
            predicted = btf.predicted(lab, b, weights)
            dist = np.linalg.norm(pos - pos[k], axis=1)
            dist[k] = np.inf
            near = [idx[j] for j in np.flatnonzero(dist <= dist.min() + _TIE)]
            errors = {j: exact_l1(btf.probabilities(j, lab, b), measured) for j in near}
            best = min(near, key=lambda j: (errors[j], j))
            rows.append(LooRow(lab, b, i, exact_l1(predicted, measured), errors[best], best, tuple(weights)))
    return rows


@dataclass(frozen=True, slots=True)
class LooSummary:
    interior: int  # rows
    better: int  # where the interpolation beats the nearest angle
    interpolated_mean: float
    nearest_mean: float

    def as_dict(self) -> dict:
        return {"interior": self.interior, "interpolation_better": self.better,
                "interpolated_mean_l1": self.interpolated_mean, "nearest_mean_l1": self.nearest_mean}


def summary(rows: list[LooRow]) -> LooSummary:
    if not rows:
        return LooSummary(0, 0, 0.0, 0.0)
    return LooSummary(len(rows), sum(r.better for r in rows), float(np.mean([r.interpolated for r in rows])),
                      float(np.mean([r.nearest for r in rows])))


def angle_text(btf: Btf, i: int) -> str:
    """A point's angles on the sweep's varied axes, e.g. '45.0°' or '45.0° / az 90.0°'."""
    d = btf.directions[i]
    axes = btf.varied or ("elevation",)
    short = {"elevation": "", "azimuth": "az ", "light_elevation": "light el ", "light_azimuth": "light az "}
    return " / ".join(f"{short[a]}{getattr(d, a):.1f}°" for a in axes)


def why_not(btf: Btf, row: LooRow) -> str:
    """Why the nearest angle predicts a point better than the interpolation, from the models."""
    lab, b = row.label, row.band
    around = [btf.probabilities(i, lab, b) for i, _ in row.neighbours]
    apart = max(exact_l1(p, q) for p in around for q in around)
    if apart <= 1.5 * row.nearest:
        return (f"flat here: its neighbours differ by L1 {apart:.3f}, within the fits' own scatter "
                f"(L1 {row.nearest:.3f} to the nearest), so any of them predicts it as well")
    here = moments(btf.probabilities(row.point, lab, b))
    near = [moments(p) for p in around]
    for name in ("mean", "sd"):
        v, vs = getattr(here, name), [getattr(m, name) for m in near]
        if not min(vs) - 0.05 * here.sd <= v <= max(vs) + 0.05 * here.sd:
            return (f"the BTF turns here: the {name} {v:.1f} lies outside its neighbours' "
                    f"{min(vs):.1f}..{max(vs):.1f}, which no blend of them reaches")
    if row.interpolated <= 1.1 * row.nearest:
        return f"a near tie (L1 {row.interpolated:.3f} against {row.nearest:.3f})"
    families = sorted({btf.models[i][(lab, b)].family.value for i, _ in row.neighbours}
                      | {btf.models[row.point][(lab, b)].family.value})
    return (f"the distribution changes shape unevenly between its neighbours (families {', '.join(families)}): "
            "not linearly in angle there")


def loo_json(btf: Btf, rows: list[LooRow]) -> list[dict]:
    """The rows as `btf --json` and the page give them."""
    out = []
    for r in rows:
        d, n = btf.directions[r.point], btf.directions[r.nearest_point]
        out.append({"label": r.label, "band": r.band, "band_name": btf.band_name(r.band),
                    "direction": _direction_json(d), "angle": angle_text(btf, r.point),
                    "interpolated_l1": _finite(r.interpolated), "nearest_l1": _finite(r.nearest),
                    "nearest": _direction_json(n), "nearest_angle": angle_text(btf, r.nearest_point),
                    "interpolation_better": r.better,
                    "neighbours": [{"angle": angle_text(btf, i), "weight": w} for i, w in r.neighbours],
                    "why_not": None if r.better else why_not(btf, r)})
    return out


def table_json(btf: Btf) -> dict:
    """One robot and scene's BTF as `btf-host btf --json` gives it: a row per region, band and
    measured direction (its model, pixels, moments and leave-one-out figures), and the summary."""
    loo = leave_one_out(btf)
    by = {(r.label, r.band, r.point): r for r in loo}
    rows = []
    for label, band in btf.regions():
        for i in btf.at(label, band):
            m, c, r = btf.models[i][(label, band)], btf.captures[i], by.get((label, band, i))
            rows.append({"label": label, "band": band, "band_name": btf.band_name(band), "angle": angle_text(btf, i),
                         "direction": _direction_json(btf.directions[i]),
                         "capture": {"id": c.id, "sequence": c.sequence, "incarnation": c.incarnation},
                         "family": m.family.value, "gamma": m.gamma, "delta": m.delta, "xi": m.xi, "lam": m.lam,
                         "pixels": btf.counts[i].get((label, band)),
                         **moments(btf.probabilities(i, label, band)).as_dict(),
                         "interpolated_l1": None if r is None else r.interpolated,
                         "nearest_l1": None if r is None else r.nearest,
                         "nearest_angle": None if r is None else angle_text(btf, r.nearest_point)})
    return {"robot": btf.robot, "scene": btf.scene, "space": btf.space, "levels": btf.levels,
            "bands": list(btf.band_names), "varied": list(btf.varied), "directions": len(btf.directions),
            "captures": btf.stored,
            "rows": rows, "leave_one_out": {"summary": summary(loo).as_dict(), "rows": loo_json(btf, loo)}}


def _direction_json(d) -> dict:
    return {a: getattr(d, a) for a in AXIS_TITLES}


def _finite(v: float) -> float:
    if not math.isfinite(v):
        raise ValueError(f"leave-one-out figure {v} is not finite")
    return v
