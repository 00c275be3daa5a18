"""Scoring one fit against the true curve it came from, and every fit of one grid point.

Three figures, all in what an 8-bit sensor sees:
- worst quantile error: max over u in [0.01, 0.99] of |Q_fit(u) - Q_true(u)| in gray levels,
  only where Q_true(u) lies inside the uncensored levels (0.5..254.5); Q_fit clipped to 0..255.
- W1: the Wasserstein-1 distance between the two curves clipped to 0..255, the mean over u of
  |Q_fit(u) - Q_true(u)| (midpoint rule, 2000 points), in gray levels.
- histogram L1: sum over levels of |p_fit - p_true| (tails folded into the end levels), 0..2.
Sampled histograms draw n pixels; the "expected" size uses the noise-free counts
(onboard.censor.expected_histogram) of the largest n.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from benchmarks import moments_johnson
from benchmarks.stability_grid import SATURATIONS, Point, Saturation
from onboard.censor import expected_histogram
from onboard.fit import fit_histogram
from onboard.johnson import Johnson

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
                return score(moments_johnson.fit_counts(counts), truth)
            r = fit_histogram(counts, censor=method == "percentile")
            return score(r.model, truth, r.fallback)
    except moments_johnson.MomentFitError as exc:
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
