"""Dependence: synthesis time with grain and copula against independent synthesis, and error against time."""
from __future__ import annotations

import time

import numpy as np

from benchmarks.common import Context, paired_times, verdict
from btf.dependence import Dependence
from btf.johnson import Family, Johnson
from hal.interfaces import ViewAngles
from hal.scene import render
from onboard.dependence import measure
from onboard.fit import FrameFitter
from tools.field import empirical_autocorrelation
from tools.synth import synthesize


def _models(n_labels: int) -> dict:
    return {(lab, b): Johnson(Family.SU, 0.4 - 0.1 * b, 1.3, 60.0 + 40 * lab, 18.0)
            for lab in range(n_labels) for b in range(3)}


def speed(ctx: Context) -> list[str]:
    side = ctx.pick(1000, 200)
    lines = ["| mask | independent | correlated | ratio |", "|---|---|---|---|"]
    worst = 0.0
    dep = Dependence((0.9, 0.6, 0.5), (0.7, 0.45, 0.2, 0.05), (0.6, 0.35, 0.15, 0.03))
    for name, n_labels in (("one region", 1), ("four quadrants", 4)):
        mask = np.zeros((side, side), dtype=np.uint8)
        if n_labels == 4:
            mask[side // 2:, :] += 2
            mask[:, side // 2:] += 1
        models = _models(n_labels)
        deps = {lab: dep for lab in range(n_labels)}
        rng = np.random.default_rng(0)
        t = paired_times({
            "ind": lambda: synthesize(mask, models, rng),
            "cor": lambda: synthesize(mask, models, rng, dependence=deps),
        }, repeat=ctx.pick(7, 2))
        r = t["cor"] / t["ind"]
        worst = max(worst, r)
        lines.append(f"| {side}x{side} RGB, {name} | {t['ind'] * 1e3:.1f} ms | {t['cor'] * 1e3:.1f} ms | {r:.2f}x |")
    lines += ["", f"**correlated / independent = {worst:.2f}x** (target <= 3.0x: {verdict(worst, 3.0)})"]
    return lines


def accuracy(ctx: Context) -> list[str]:
    """Error of the synthetic grain on the fake field plate, and the on-board cost of measuring it."""
    size = ctx.pick((480, 640), (120, 160))
    v = render("field", ViewAngles(60.0, 0.0), size, seed=1)
    labels = v.mask.astype(np.int64)
    f = FrameFitter(int(labels.max()) + 1, 3, bins=256)
    f.add(v.image, labels)
    models = {k: r.model for k, r in f.fit(min_count=64).items()}
    lines = ["| anchors | measure time | worst lag 1..8 autocorr error | worst band corr error |",
             "|---|---|---|---|"]
    for anchors in ctx.pick((4096, 16384, 65536), (4096,)):
        t0 = time.perf_counter()
        deps = measure(v.image, labels, models, max_anchors=anchors)
        dt = time.perf_counter() - t0
        out = synthesize(labels, models, np.random.default_rng(1), dependence=deps)
        ac_err = cc_err = 0.0
        for lab in deps:
            inside = labels == lab
            if inside.sum() < 8000:
                continue
            for b in range(3):
                for axis in (0, 1):
                    for lag in range(1, 9):
                        ac_err = max(ac_err, abs(empirical_autocorrelation(out[..., b], inside, lag, axis)
                                                 - empirical_autocorrelation(v.image[..., b], inside, lag, axis)))
            c = [np.corrcoef(x[inside].T.astype(float)) for x in (v.image, out)]
            cc_err = max(cc_err, float(np.abs(c[0] - c[1]).max()))
        lines.append(f"| {anchors} | {dt * 1e3:.1f} ms | {ac_err:.3f} | {cc_err:.3f} |")
    return lines + ["", f"field plate {size[0]}x{size[1]}, regions of at least 8000 pixels; bars 0.1 and 0.05"]


def run(ctx: Context = Context()) -> list[str]:
    return ["### Synthesis time", "", *speed(ctx), "", "### Error against on-board time", "", *accuracy(ctx)]
