"""Dependence: synthesis time with grain and copula against independent synthesis, error against
on-board time, and what `[features] dependence` costs the robot per capture (bytes and time)."""
from __future__ import annotations

import time

import numpy as np

from benchmarks.common import Context, paired_times, verdict
from btf.dependence import Dependence
from btf.fit.dependence import measure
from btf.fit.features import FeatureSpace, FeatureSpec, compute
from btf.fit.fitter import FrameFitter
from btf.johnson import Family, Johnson
from hal.interfaces import ViewAngles
from hal.scene import render
from radio.packets import encode_models
from tools.analysis.fields import empirical_autocorrelation
from tools.analysis.synth import synthesize


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


def _grid_mask(h: int, w: int, side: int) -> np.ndarray:
    """side x side blocks labelled 0..side^2-1: the most regions a 16-label robot sends."""
    rows = np.minimum(np.arange(h) * side // h, side - 1)
    cols = np.minimum(np.arange(w) * side // w, side - 1)
    return (rows[:, None] * side + cols[None, :]).astype(np.uint8)


def robot_cost(ctx: Context) -> list[str]:
    """Bytes and time per capture with and without `[features] dependence`, on the capture path's
    own steps (features, the 16-label fitter, the dependence pass, the MODELS body)."""
    lines = ["| frame | regions | MODELS body without | with | added | capture time without | with | added |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    spec = FeatureSpec(FeatureSpace.RGB)
    cases = ctx.pick([((120, 160), "scene"), ((480, 640), "scene"), ((480, 640), "grid")], [((60, 80), "scene")])
    worst_time = worst_bytes = 0.0
    for size, kind in cases:
        v = render("field", ViewAngles(60.0, 0.0), size, seed=1)
        labels = v.mask if kind == "scene" else _grid_mask(*size, 4)
        fitter = FrameFitter(16, 3, bins=256)

        def capture(with_dependence: bool):
            feats = compute(v.image, spec)
            fitter.reset()
            fitter.add(feats.data, labels)
            results = fitter.fit(min_count=64)
            dep = (measure(feats.data, labels, {k: r.model for k, r in results.items()}, feats.levels)
                   if with_dependence else None)
            return encode_models(results, robot_id=1, seq=1, time=0.0, commanded=(60.0, 0.0),
                                 measured=(60.0, 0.0), feature_space="rgb", bands=feats.band_names,
                                 levels=feats.levels, dependence=dep)

        sizes = {flag: len(capture(flag)) for flag in (False, True)}
        t = paired_times({"off": lambda: capture(False), "on": lambda: capture(True)}, repeat=ctx.pick(15, 2))
        regions = len(np.unique(labels))
        worst_time, worst_bytes = max(worst_time, t["on"] / t["off"]), max(worst_bytes, sizes[True] / sizes[False])
        lines.append(
            f"| {size[0]}x{size[1]} RGB field{'' if kind == 'scene' else ', 4x4 grid mask'} | {regions} | "
            f"{sizes[False]} B | {sizes[True]} B | +{sizes[True] - sizes[False]} B "
            f"(+{100 * (sizes[True] / sizes[False] - 1):.0f}%) | {t['off'] * 1e3:.1f} ms | {t['on'] * 1e3:.1f} ms | "
            f"+{(t['on'] - t['off']) * 1e3:.1f} ms ({t['on'] / t['off']:.2f}x) |")
    return lines + [
        "", "Capture time: features, the 16-label fitter, the dependence pass (on) and the MODELS body; the "
        "scene's true mask (or the grid) stands for segmentation, which dependence does not change. Best of "
        "paired rounds.", "",
        f"**worst: {worst_bytes:.2f}x the bytes, {worst_time:.2f}x the on-board time of a capture**"]


def run(ctx: Context = Context()) -> list[str]:
    return ["### Synthesis time", "", *speed(ctx), "", "### Error against on-board time", "", *accuracy(ctx),
            "", "### Cost per capture on the robot: `[features] dependence`", "", *robot_cost(ctx)]
