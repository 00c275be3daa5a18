"""Peers on the same data: our percentile fit against scipy's MLE Johnson fits, the AS 99
method-of-moments reference, Gaussian and Weibull — time, error, and where each one fails.

Error: L1 between the data's normalized 256-level histogram and the model's level
probabilities (0..2), and the worst quantile error max |Q_model(u) - Q_data(u)| over
u in [0.01, 0.99], both clipped to the sensor's 0..255, in gray levels. MLE fits see the
integers spread uniformly over their level (seeded) and at most 20000 of them, as
tools.analysis.pdfs does; ours reads the histogram of every value.
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np
from scipy import stats

from benchmarks import as99_moment_fit
from benchmarks.common import Context, Section, figure, save
from benchmarks.scenes import field
from btf.fit.fitter import fit_values
from btf.johnson import Family, Johnson
from tools.analysis.pdfs import binned

METHODS = ("percentile", "johnsonsu MLE", "johnsonsb MLE", "moments (AS 99)", "gaussian", "weibull")
U = np.linspace(0.01, 0.99, 99)
MLE_SAMPLE = 20000


@dataclass(frozen=True)
class Outcome:
    seconds: float
    hist_err: float  # nan when failed
    q_err: float
    failure: str = ""


def datasets(ctx: Context) -> dict[str, np.ndarray]:
    """8-bit data sets: field-scene regions, and synthetic shapes that stress a fit."""
    rng = np.random.default_rng(7)
    n = ctx.pick(100_000, 2000)
    img, mask = field(*ctx.pick((480, 640), (60, 80)))
    out = {}
    for label in np.unique(mask)[:ctx.pick(4, 1)]:
        out[f"field label {label}, G"] = img[..., 1][mask == label]

    def px(x):
        return np.clip(np.rint(x), 0, 255).astype(np.uint8)

    su = Johnson(Family.SU, -0.6, 1.6, 110.0, 22.0)
    out["SU (heavy tails)"] = px(su.sample(n, rng, np.float64))
    out["SB (bounded, skewed)"] = px(Johnson(Family.SB, 0.8, 0.9, 20.0, 200.0).sample(n, rng, np.float64))
    out["narrow (sd 0.7 gray)"] = px(rng.normal(120.3, 0.7, n))
    out["40% saturated at 255"] = px(su.sample(n, rng, np.float64) + 254.5 - float(su.ppf(0.6)))
    out["50 pixels"] = px(su.sample(50, rng, np.float64))
    return out


def _errors(values: np.ndarray, probs: np.ndarray, ppf) -> tuple[float, float]:
    h = np.bincount(values, minlength=256) / values.size
    e = float(np.abs(h - probs).sum())
    q = np.clip(ppf(U), 0, 255) - np.quantile(values.astype(np.float64), U)
    return e, float(np.max(np.abs(q)))


def _scipy(values: np.ndarray, rng: np.random.Generator, method: str):
    v = values if values.size <= MLE_SAMPLE else rng.choice(values, MLE_SAMPLE, replace=False)
    x = v.astype(np.float64) + rng.uniform(-0.5, 0.5, v.size)
    if method == "johnsonsu MLE":
        return stats.johnsonsu(*stats.johnsonsu.fit(x))
    if method == "johnsonsb MLE":
        return stats.johnsonsb(*stats.johnsonsb.fit(x))
    if method == "gaussian":
        return stats.norm(*stats.norm.fit(x))
    floor = float(v.min()) - 0.5 - 1e-3
    c, _, scale = stats.weibull_min.fit(x, floc=floor)
    return stats.weibull_min(c, floor, scale)


def evaluate(method: str, values: np.ndarray, rng: np.random.Generator, repeat: int) -> Outcome:
    t0 = time.perf_counter()
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            if method == "percentile":
                model = fit_values(values).model
                for _ in range(repeat - 1):
                    fit_values(values)
                seconds = (time.perf_counter() - t0) / repeat
            else:
                model = as99_moment_fit.fit(values) if method.startswith("moments") else _scipy(values, rng, method)
                seconds = time.perf_counter() - t0
            if isinstance(model, Johnson):
                probs, ppf = model.level_probabilities(), model.ppf
            else:
                probs, ppf = binned(model, 256), model.ppf
            e, q = _errors(values, probs, ppf)
    except Exception as exc:  # a peer's failure is a result to report, whatever it raised
        return Outcome(time.perf_counter() - t0, float("nan"), float("nan"), f"raised {type(exc).__name__}")
    if not (np.isfinite(e) and np.isfinite(q)) or not np.all(np.isfinite(probs)):
        return Outcome(seconds, float("nan"), float("nan"), "NaN")
    h = np.bincount(values, minlength=256)
    if np.any(probs[h > 0] <= 0.0):
        return Outcome(seconds, e, q, "support excludes data")
    if e > 1.0:
        return Outcome(seconds, e, q, "collapsed")
    return Outcome(seconds, e, q)


def run(ctx: Context) -> list[Section]:
    rng = np.random.default_rng(3)
    data = datasets(ctx)
    results = {(d, m): evaluate(m, v, rng, ctx.pick(5, 1)) for d, v in data.items() for m in METHODS}
    lines = ["Cells: histogram L1 / worst quantile error (gray) / time. A failure is named: "
             "raised (an exception), NaN, support excludes data (a level the data holds gets "
             "probability 0), collapsed (histogram L1 above 1).", "",
             "| data | n | " + " | ".join(METHODS) + " |", "|---|---:|" + "---|" * len(METHODS)]
    for d, v in data.items():
        cells = []
        for m in METHODS:
            o = results[(d, m)]
            t = f"{o.seconds * 1e3:.2f} ms" if o.seconds < 1 else f"{o.seconds:.2f} s"
            err = f"{o.hist_err:.3f} / {o.q_err:.1f}" if np.isfinite(o.hist_err) else "—"
            cells.append(f"{err} / {t}" + (f" **{o.failure}**" if o.failure else ""))
        lines.append(f"| {d} | {v.size} | " + " | ".join(cells) + " |")
    lines += ["", "| method | median time | median time / percentile fit | median histogram L1 "
              "| failures |", "|---|---:|---:|---:|---|"]
    ours = np.median([results[(d, "percentile")].seconds for d in data])
    for m in METHODS:
        os_ = [results[(d, m)] for d in data]
        t = float(np.median([o.seconds for o in os_]))
        errs = [o.hist_err for o in os_ if np.isfinite(o.hist_err)]
        fails = [f"{d}: {results[(d, m)].failure}" for d in data if results[(d, m)].failure]
        lines.append(f"| {m} | {t * 1e3:.2f} ms | {t / ours:.0f}x | "
                     f"{np.median(errs) if errs else float('nan'):.3f} | {'; '.join(fails) or 'none'} |")
    lines += ["", _plot(data, results, ctx)]
    return [Section("Peers on the same data: percentile fit, MLE, moments, Gaussian, Weibull", lines)]


def _plot(data, results, ctx: Context) -> str:
    fig, ax = figure(1, 1, (7.5, 5.0))
    ax = ax[0][0]
    markers = "os^vDP"
    for m, mk in zip(METHODS, markers):
        ok = [(results[(d, m)].seconds, results[(d, m)].hist_err) for d in data if not results[(d, m)].failure]
        bad = [(results[(d, m)].seconds, 2.0) for d in data if results[(d, m)].failure]
        sc = ax.scatter([p[0] for p in ok], [max(p[1], 1e-4) for p in ok], marker=mk, label=m, alpha=0.8)
        if bad:
            ax.scatter([p[0] for p in bad], [p[1] for p in bad], marker="x", s=80, color=sc.get_facecolor()[0])
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("time per fit (s)")
    ax.set_ylabel("histogram L1 error (failures plotted at 2 as x)")
    ax.set_title("Peers on the same data: time against error")
    ax.legend(fontsize=7)
    return save(fig, ctx, "peers.png")
