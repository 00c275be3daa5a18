"""Numerical stability map: the worst quantile error of the fit over the (beta1, beta2) plane,
sample sizes 10 .. 10^6, 8-bit quantization and saturation at 255 — for the percentile fit and
for the AS 99 method-of-moments reference.

Each grid point is a Johnson curve with that (beta1, beta2) (SB and SU shapes solved
numerically, SL on the lognormal line, SN at the normal point), scaled so its 0.1%..99.9%
range spans gray levels 20..235, shifted up until the given fraction lies above 254.5, then
rounded and clipped to 0..255. Error: max over u in [0.01, 0.99] of |Q_model(u) - Q_true(u)|,
both clipped to 0..255, in gray levels (the rounding alone contributes up to 0.5).
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from benchmarks import moments_johnson
from benchmarks.common import Context, Section, figure, save
from benchmarks.johnson_moments import lognormal_beta2, lognormal_omega, solve_shape
from onboard.fit import fit_histogram
from onboard.johnson import Family, Johnson

U = np.linspace(0.01, 0.99, 99)
SATURATION = (0.0, 0.10, 0.25, 0.40)
METHODS = ("percentile", "moments")


@dataclass(frozen=True)
class Point:
    beta1: float
    beta2: float
    where: str  # region name
    curve: Johnson  # scaled to the 8-bit range


def grid(ctx: Context) -> list[Point]:
    b1s = ctx.pick((0.0, 0.1, 0.5, 1.0, 2.0, 4.0), (0.0, 1.0))
    pts = []
    for b1 in b1s:
        ln = lognormal_beta2(b1) if b1 > 0 else 3.0
        cands = [(b1 + 1.1, "near beta2 = beta1 + 1"), (b1 + 1 + 0.5 * (ln - b1 - 1), "SB region"),
                 (ln + 1.0, "SU region"), (ln + 6.0, "SU region, heavy tails")]
        if b1 > 0:
            cands.append((ln, "lognormal line"))
        else:
            cands += [(3.0, "normal point"), (3.05, "near the normal point")]
        for b2, where in cands:
            pts.append(Point(b1, b2, where, _curve(b1, b2)))
    return pts


def _curve(b1: float, b2: float) -> Johnson:
    skew = math.sqrt(b1)
    if b1 == 0.0 and b2 == 3.0:
        std = Johnson.normal(0.0, 1.0)
    elif b1 > 0 and abs(b2 - lognormal_beta2(b1)) < 1e-9:
        std = Johnson(Family.SL, 0.0, 1.0 / math.sqrt(math.log(lognormal_omega(b1))), 0.0, 1.0)
    else:
        family = Family.SU if b2 > (lognormal_beta2(b1) if b1 > 0 else 3.0) else Family.SB
        g, d = solve_shape(family, skew, b2)
        std = Johnson(family, g, d, 0.0, 1.0)
    a, b = (float(v) for v in std.ppf([0.001, 0.999]))
    scale = 215.0 / (b - a)
    return Johnson(std.family, std.gamma, std.delta, 20.0 - a * scale, std.lam * scale)


def _error(model: Johnson, truth_q: np.ndarray) -> float:
    return float(np.max(np.abs(np.clip(model.ppf(U), 0, 255) - truth_q)))


def evaluate(point: Point, sizes, rng: np.random.Generator) -> dict[tuple[str, int, float], tuple[float, str]]:
    """{(method, n, saturation): (error, failure)} for one grid point."""
    out = {}
    raw = point.curve.sample(max(sizes), rng, np.float64)
    for sat in SATURATION:
        shift = 0.0 if sat == 0 else 254.5 - float(point.curve.ppf(1.0 - sat))
        px = np.clip(np.rint(raw + shift), 0, 255).astype(np.uint8)
        truth_q = np.clip(np.rint(point.curve.ppf(U) + shift), 0, 255)
        for n in sizes:
            counts = np.bincount(px[:n], minlength=256)
            for method in METHODS:
                try:
                    with warnings.catch_warnings(), np.errstate(all="ignore"):
                        warnings.simplefilter("ignore")
                        model = (fit_histogram(counts).model if method == "percentile"
                                 else moments_johnson.fit(px[:n]))
                    err = _error(model, truth_q)
                    fail = "" if math.isfinite(err) else "NaN"
                except moments_johnson.MomentFitError as exc:
                    why = "sample at beta2 <= beta1 + 1" if "beta1 + 1" in str(exc) else "SB solve failed"
                    err, fail = float("nan"), f"no curve ({why})"
                except Exception as exc:  # any failure of the fit is the finding
                    err, fail = float("nan"), f"raised {type(exc).__name__}: {exc}"
                out[(method, n, sat)] = (err, fail)
    return out


def run(ctx: Context) -> list[Section]:
    rng = np.random.default_rng(11)
    sizes = ctx.pick((10, 100, 1000, 10_000, 100_000, 1_000_000), (10, 1000))
    points = grid(ctx)
    res = {i: evaluate(p, sizes, rng) for i, p in enumerate(points)}
    lines = [f"{len(points)} points of the (beta1, beta2) plane x {len(sizes)} sample sizes x "
             f"{len(SATURATION)} saturations = {len(points) * len(sizes) * len(SATURATION)} fits per method.", ""]
    for method in METHODS:
        fails = [(points[i], n, s, f) for i, r in res.items() for (m, n, s), (_, f) in r.items()
                 if m == method and f]
        lines += [f"**{method}**: worst quantile error (gray levels) over the grid; failures in brackets.", "",
                  "| n | " + " | ".join(f"{s:.0%} saturated" for s in SATURATION) + " |",
                  "|---:|" + "---:|" * len(SATURATION)]
        for n in sizes:
            cells = []
            for s in SATURATION:
                vals = [r[(method, n, s)] for r in res.values()]
                errs = [e for e, f in vals if not f]
                nf = sum(1 for _, f in vals if f)
                cells.append(f"{max(errs) if errs else float('nan'):.1f}" + (f" [{nf}]" if nf else ""))
            lines.append(f"| {n} | " + " | ".join(cells) + " |")
        kinds: dict[str, int] = {}
        for _, _, _, f in fails:
            kinds[f] = kinds.get(f, 0) + 1
        lines += ["", f"Failures of {method}: " + ("; ".join(f"{k} x{v}" for k, v in sorted(kinds.items()))
                                                   if kinds else "none") + ".", "",
                  _plot(method, points, sizes, res, ctx), ""]
    lines += _where_moments_break(points, sizes, res)
    return [Section("Stability map: worst quantile error over the (beta1, beta2) plane", lines)]


def _where_moments_break(points, sizes, res) -> list[str]:
    """Cells where moments fail or err by more than twice the percentile fit (and > 2 levels)."""
    rows = {}
    for i, p in enumerate(points):
        for n in sizes:
            for s in SATURATION:
                ep, fp = res[i][("percentile", n, s)]
                em, fm = res[i][("moments", n, s)]
                if fm or (em > 2 * ep and em > 2.0):
                    rows.setdefault((p.where, s), []).append(n)
    out = ["Where moments break and percentiles hold (moments fail, or err more than twice the "
           "percentile fit and by more than 2 levels), by region and saturation: sample sizes affected.", "",
           "| region | saturation | sample sizes |", "|---|---:|---|"]
    for (where, s), ns in sorted(rows.items()):
        out.append(f"| {where} | {s:.0%} | {', '.join(str(n) for n in sorted(set(ns)))} |")
    return out + [""]


def _plot(method: str, points, sizes, res, ctx: Context) -> str:
    import matplotlib.colors as mcolors
    fig, axes = figure(len(SATURATION), len(sizes), (3.2, 2.6), sharex=True, sharey=True)
    norm = mcolors.LogNorm(0.3, 100.0)
    b1 = np.array([p.beta1 for p in points])
    b2 = np.array([p.beta2 for p in points])
    line_b1 = np.linspace(0.0, max(b1.max(), 0.1), 100)
    sc = None
    for r, n in enumerate(sizes):
        for c, s in enumerate(SATURATION):
            ax = axes[r][c]
            vals = [res[i][(method, n, s)] for i in range(len(points))]
            ok = np.array([not f for _, f in vals])
            err = np.array([e if not f else np.nan for e, f in vals])
            ax.plot(line_b1, line_b1 + 1, "k-", lw=0.8)
            ax.plot(line_b1, [lognormal_beta2(x) if x > 0 else 3.0 for x in line_b1], "k--", lw=0.6)
            sc = ax.scatter(b1[ok], b2[ok], c=np.clip(err[ok], 0.3, 100), cmap="viridis", norm=norm, s=22)
            if (~ok).any():
                ax.scatter(b1[~ok], b2[~ok], marker="x", color="red", s=40)
            ax.set_yscale("log")
            if r == 0:
                ax.set_title(f"{s:.0%} at 255", fontsize=8)
            if c == 0:
                ax.set_ylabel(f"n={n}\nbeta2", fontsize=8)
            if r == len(sizes) - 1:
                ax.set_xlabel("beta1", fontsize=8)
    fig.subplots_adjust(left=0.07, right=0.9, top=0.95, bottom=0.05, hspace=0.25, wspace=0.12)
    fig.colorbar(sc, cax=fig.add_axes([0.92, 0.2, 0.015, 0.6]), label="worst quantile error (gray)")
    fig.suptitle(f"{method} fit: worst quantile error (red x: failure; solid: beta2 = beta1 + 1, "
                 "dashed: lognormal line)", fontsize=9)
    return save(fig, ctx, f"stability_{method}.png", tight=False)
