"""Scoring one fit against the true curve it came from, and every fit of one grid point.

Three figures, all in what an 8-bit sensor sees:
- worst quantile error: max over u in [0.01, 0.99] of |Q_fit(u) - Q_true(u)| in gray levels,
  only where Q_true(u) lies inside the uncensored levels (0.5..254.5); Q_fit clipped to 0..255.
- W1: the Wasserstein-1 distance between the two curves clipped to 0..255, the mean over u of
  |Q_fit(u) - Q_true(u)| (midpoint rule, 2000 points), in gray levels.
- histogram L1: sum over levels of |p_fit - p_true| (tails folded into the end levels), 0..2.
Sampled histograms draw n pixels; the "expected" size uses the noise-free counts
(benchmarks.model_histograms.expected_histogram) of the largest n.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from enum import Enum

import numpy as np
from scipy.optimize import minimize

from benchmarks import as99_moment_fit
from benchmarks.model_histograms import expected_histogram, histogram_l1
from benchmarks.stability_grid import SATURATIONS, Point, Saturation
from btf.codec import z_for_count
from btf.fit.fitter import fit_histogram, histogram_percentiles, plain_fit
from btf.johnson import Family, Johnson, normal_cdf
from btf.percentile import model_from_percentiles

U = np.linspace(0.01, 0.99, 99)
U_W1 = (np.arange(2000) + 0.5) / 2000
METHODS = ("percentile", "uncensored", "moments")  # "uncensored": the percentile fit, censor=False


@dataclass(frozen=True)
class Size:
    n: int
    expected: bool = False

    @property
    def label(self) -> str:
        return f"{self.n} (expected counts)" if self.expected else str(self.n)


@dataclass(frozen=True)
class Score:
    worst: float = math.nan
    w1: float = math.nan
    l1: float = math.nan
    fallback: bool = False
    failure: str = ""  # empty when the fit gave finite figures


@dataclass(frozen=True)
class Truth:
    q: np.ndarray  # Q_true(U)
    inside: np.ndarray  # where Q_true(U) is an uncensored level
    q_w1: np.ndarray  # Q_true(U_W1) clipped to 0..255
    p: np.ndarray  # level probabilities

    @classmethod
    def of(cls, curve: Johnson) -> Truth:
        q = curve.ppf(U)
        return cls(q, (q > 0.5) & (q < 254.5), np.clip(curve.ppf(U_W1), 0, 255), curve.level_probabilities(256))


def score(model: Johnson, truth: Truth, fallback: bool = False) -> Score:
    err = np.abs(np.clip(model.ppf(U), 0, 255) - truth.q)[truth.inside]
    worst = float(err.max()) if err.size else 0.0
    w1 = float(np.mean(np.abs(np.clip(model.ppf(U_W1), 0, 255) - truth.q_w1)))
    l1 = float(np.abs(model.level_probabilities(256) - truth.p).sum())
    if not all(math.isfinite(v) for v in (worst, w1, l1)):
        return Score(failure="NaN")
    return Score(worst, w1, l1, fallback)


def fit_and_score(method: str, counts: np.ndarray, truth: Truth) -> Score:
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            if method == "moments":
                return score(as99_moment_fit.fit_counts(counts), truth)
            r = fit_histogram(counts, censor=method == "percentile")
            return score(r.model, truth, r.fallback)
    except as99_moment_fit.MomentFitError as exc:
        why = "sample at beta2 <= beta1 + 1" if "beta1 + 1" in str(exc) else "SB solve failed"
        return Score(failure=f"no curve ({why})")
    except Exception as exc:  # any failure of the fit is the finding
        return Score(failure=f"raised {type(exc).__name__}: {exc}")


Key = tuple[str, Size, Saturation]


def evaluate(point: Point, sizes: list[Size], rng: np.random.Generator,
             saturations: tuple[Saturation, ...] = SATURATIONS) -> dict[Key, Score]:
    """{(method, size, saturation): score} for one grid point. Every saturation translates the
    same draw, so the columns differ by the saturation alone."""
    n_max = max(s.n for s in sizes)
    raw = point.curve.sample(n_max, rng, np.float64)
    out: dict[Key, Score] = {}
    for sat in saturations:
        curve = sat.apply(point.curve)
        truth = Truth.of(curve)
        # one end saturating is a translation: the translated draw is the draw of the moved curve
        px = np.clip(np.rint(raw + (curve.xi - point.curve.xi)), 0, 255).astype(np.int64)
        for size in sizes:
            counts = expected_histogram(curve, size.n) if size.expected else np.bincount(px[:size.n], minlength=256)
            for method in METHODS:
                out[(method, size, sat)] = fit_and_score(method, counts, truth)
    return out


# -- why a grid point is bad: the 8-bit floor, the fitter, or the grid --------------------------


class Cause(Enum):
    FLOOR = "a: 8-bit floor"  # the fit is within a level of what the quantized curve itself gives
    FITTER = "b: fitter"  # a fit from the same 8-bit counts reaches the floor; ours does not
    GRID = "c: grid"  # the scaling folds mass into the end levels, or the curve is finer than float64
    OPEN = "open"  # none of the above shown


@dataclass(frozen=True)
class Diagnosis:
    """One grid point's true curve, the best an 8-bit answer can do, and what the fit does, all
    from the noise-free counts of `n` pixels (deterministic, so anyone can repeat it)."""
    point: Point
    n: int
    levels90: int  # fewest levels holding 90% of the mass
    peak: tuple[int, float]  # the fullest level and its mass
    at_bound: bool  # the fullest level is the first or last occupied one
    outside: float  # true mass beyond -0.5 .. 255.5, folded into the end levels
    true_percentiles: tuple[float, ...]  # the four the fitter reads, x(-3z) .. x(3z), of the true curve
    read: tuple[float, ...]  # the four the fitter read from the counts
    gap: float  # smallest gap between the four true percentiles, gray
    floor: float  # worst quantile error of the curve's own histogram, read as the fitter reads it
    exact: float  # worst quantile error of the percentile formulas fed the true quantiles
    fit: Score  # our fit of the counts
    piles: float  # our fit of the counts cut to the occupied levels (end piles read as censored)
    plain: float  # the plain percentile fit (the count's z, unshifted, no rule) of the counts
    refined: float  # our fits refined by histogram L1 (Nelder-Mead, their own families)
    remedy: float  # the error of the remedy `why` names (the first of the three to reach the floor)
    cause: Cause
    why: str


def diagnose(point: Point, n: int) -> Diagnosis:
    c, truth = point.curve, Truth.of(point.curve)
    counts = expected_histogram(c, n)
    occ = np.flatnonzero(counts)
    f0, f1 = int(occ[0]), int(occ[-1])
    peak = int(truth.p.argmax())
    floor = float(np.abs(histogram_percentiles(counts, U) - truth.q)[truth.inside].max(initial=0.0))
    z = z_for_count(n)
    true_pct = c.ppf(np.array([normal_cdf(k * z) for k in (-3, -1, 1, 3)]))
    with warnings.catch_warnings(), np.errstate(all="ignore"):
        warnings.simplefilter("ignore")
        exact = score(model_from_percentiles(tuple(true_pct), z, n), truth).worst
        fit = fit_histogram(counts)
        piled = fit_histogram(counts[f0:f1 + 1], lo=float(f0)).model
        plain = score(plain_fit(counts), truth).worst
        refined = score(min((_refined(m, counts) for m in (fit.model, piled)),
                            key=lambda m: histogram_l1(m, counts)), truth).worst
    got, piles = score(fit.model, truth, fit.fallback), score(piled, truth).worst
    outside = float(c.cdf(-0.5) + (1.0 - c.cdf(255.5)))
    gap = float(np.diff(true_pct).min())
    # the cheapest remedy (for the fitter) that reaches the floor, else the best of them
    remedies = [(piles, f"the pile at level {peak} read as censored"), (refined, "refined by histogram L1")]
    best, how = next((r for r in remedies if r[0] <= floor + 1.0), min(remedies, key=lambda r: r[0]))
    if outside > 0.01:
        cause, why = Cause.GRID, f"the scaling folds {outside:.1%} of the mass into the end levels"
    elif got.worst <= floor + 1.0:
        cause, why = Cause.FLOOR, "within a level of the quantized curve's own quantiles"
    elif exact > 1.0:
        cause, why = Cause.GRID, (f"two true percentiles {gap:.0e} gray apart: even the exact quantiles "
                                  f"miss by {exact:.0f}; numerically a point mass plus a spread")
    elif best <= floor + 1.0:
        cause, why = Cause.FITTER, f"{how}: {best:.1f}"
    else:
        cause, why = Cause.OPEN, f"best remedy tried ({how}) {best:.1f}"
    levels90 = int(np.searchsorted(np.cumsum(np.sort(truth.p)[::-1]), 0.9) + 1)
    return Diagnosis(point, n, levels90, (peak, float(truth.p[peak])), peak in (f0, f1), outside,
                     tuple(float(x) for x in true_pct), tuple(fit.percentiles), gap, floor, exact, got, piles,
                     plain, refined, best, cause, why)


def _refined(model: Johnson, counts: np.ndarray) -> Johnson:
    """`model` moved by Nelder-Mead to a local minimum of the histogram L1, in its own family:
    what the 8-bit counts alone can pin down (a reference, far too slow for the robot)."""
    if model.family is Family.CONST:
        return model
    sign = 1.0 if model.lam > 0 else -1.0

    def build(v: np.ndarray) -> Johnson:
        return Johnson(model.family, float(v[0]), float(np.exp(v[1])), float(v[2]), sign * float(np.exp(v[3])))

    def loss(v: np.ndarray) -> float:
        try:
            return histogram_l1(build(v), counts)
        except ValueError:
            return 2.0
    v0 = np.array([model.gamma, math.log(model.delta), model.xi, math.log(abs(model.lam))])
    best = minimize(loss, v0, method="Nelder-Mead", options={"maxiter": 3000, "xatol": 1e-7, "fatol": 1e-10})
    return build(best.x) if best.fun < loss(v0) else model
