"""Dependence on the robot: the 2-D grain's error against the anchors it costs, the pass's time
against the fit's at 1 MP, and what `[features] dependence` adds to a capture (bytes and time)."""
from __future__ import annotations

import time

import numpy as np

from benchmarks import texture_cases
from benchmarks.common import Context, paired_times, verdict
from btf.dependence import Dependence, window
from btf.fit.dependence import MAX_ANCHORS, measure, observed
from btf.fit.features import FeatureSpace, FeatureSpec, compute
from btf.fit.fitter import FrameFitter
from hal.interfaces import ViewAngles
from hal.scene import render
from radio.packets import encode_models
from tools.analysis.grain_metrics import acf2d

ANCHORS = (2048, 4096, 6144, 8192, 16384, 65536)


def _grid_mask(h: int, w: int, side: int) -> np.ndarray:
    """side x side blocks labelled 0..side^2-1: the most regions a 16-label robot sends."""
    rows = np.minimum(np.arange(h) * side // h, side - 1)
    cols = np.minimum(np.arange(w) * side // w, side - 1)
    return (rows[:, None] * side + cols[None, :]).astype(np.uint8)


def _fitted(img: np.ndarray, labels: np.ndarray):
    f = FrameFitter(16, img.shape[2], bins=256)
    f.add(img, labels)
    return {k: r.model for k, r in f.fit(min_count=64).items()}, f


def _errors(cases, anchors: int) -> tuple[float, float]:
    """Worst error of the measured window (per band) and of the band correlations against every
    pixel pair of the region, over the cases' regions of at least 8000 pixels."""
    acf_err = corr_err = 0.0
    for img, labels, models, truth in cases:
        deps = measure(img, labels, models, max_anchors=anchors, per_band=True)
        for lab, (acf, corr) in truth.items():
            acf_err = max(acf_err, float(np.abs(np.array(deps[lab].acf) - acf).max()))
            corr_err = max(corr_err, float(np.abs(deps[lab].matrix() - corr).max()))
    return acf_err, corr_err


def _cases(ctx: Context):
    """The field plate and photographs, with each region's exact window and band correlation."""
    out = []
    names = ctx.pick(("coffee", "chelsea", "gravel", "camera"), ("coffee",))
    images = [render("field", ViewAngles(60.0, 0.0), ctx.pick((480, 640), (120, 160)), seed=1)]
    pairs = [(images[0].image, images[0].mask.astype(np.uint8))]
    for name in names:
        p = texture_cases.load(name, side=ctx.pick(None, 128))
        pairs.append((p.pixels, p.labels))
    for img, labels in pairs:
        models, _ = _fitted(img, labels)
        truth = {}
        for lab in np.unique(labels):
            inside = labels == lab
            if inside.sum() >= ctx.pick(8000, 500) and (int(lab), 0) in models:
                corr = np.corrcoef(img[inside].T.astype(np.float64)) if img.shape[2] > 1 else np.eye(1)
                truth[int(lab)] = (np.array([acf2d(img[..., b], inside, 6) for b in range(img.shape[2])]), corr)
        out.append((img, labels, models, truth))
    return out


def accuracy(ctx: Context) -> list[str]:
    """Anchors against error and against the pass's time at 1 MP beside the fit's."""
    side = ctx.pick(1000, 200)
    view = render("field", ViewAngles(60.0), size=(side, side), seed=0)
    scene, grid = view.mask.astype(np.uint8), _grid_mask(side, side, 4)
    fits = {name: _fitted(view.image, labels) for name, labels in (("scene", scene), ("grid", grid))}
    cases = _cases(ctx)
    lines = [f"| anchors | worst window error (per band) | worst band-correlation error | pass, {side}x{side} RGB "
             "scene (4 regions) / the fit | 4x4 grid (16 regions) / the fit |", "|---:|---:|---:|---:|---:|"]
    chosen = None
    for anchors in ctx.pick(ANCHORS, (2048, MAX_ANCHORS)):
        acf_err, corr_err = _errors(cases, anchors)
        ratios = []
        for name, labels in (("scene", scene), ("grid", grid)):
            models, fitter = fits[name]

            def fit(labels=labels, fitter=fitter):
                fitter.reset()
                fitter.add(view.image, labels)
                return fitter.fit(min_count=64)

            t = paired_times({"fit": fit, "pass": lambda labels=labels, models=models: measure(
                view.image, labels, models, max_anchors=anchors)}, ctx.pick(15, 2))
            ratios.append(t["pass"] / t["fit"])
        mark = " (**the robot's**)" if anchors == MAX_ANCHORS else ""
        chosen = (anchors, ratios) if anchors == MAX_ANCHORS else chosen
        lines.append(f"| {anchors}{mark} | {acf_err:.3f} | {corr_err:.3f} | {ratios[0]:.2f}x | {ratios[1]:.2f}x |")
    lines += ["", "Errors: the measured autocorrelation on the window (radius 6, per band) and band correlations "
              "against every pixel pair of the region, over the fake field plate and k-means regions of coffee, "
              "chelsea, gravel and camera (regions of at least 8000 pixels). The pass's time is paired with the "
              "fit's (FrameFitter add + fit) on the same frame, best of rounds."]
    if chosen is not None:
        lines += ["", f"**dependence pass / fit at {chosen[0]} anchors: {chosen[1][0]:.2f}x** on the 4-region scene "
                  f"(target <= 1.0x: {verdict(chosen[1][0], 1.0)}), {chosen[1][1]:.2f}x on the 16-region grid"]
    return lines


def robot_cost(ctx: Context) -> list[str]:
    """Bytes and time per capture with and without `[features] dependence`, on the capture path's
    own steps (features, the 16-label fitter, the observed levels, the dependence pass, the body)."""
    lines = ["| frame | regions | MODELS body: levels only | with the grain | added | capture time without the "
             "grain | with | added |", "|---|---:|---:|---:|---:|---:|---:|---:|"]
    spec = FeatureSpec(FeatureSpace.RGB)
    cases = ctx.pick([((480, 640), "scene"), ((480, 640), "grid"), ((1000, 1000), "scene")], [((60, 80), "scene")])
    for size, kind in cases:
        v = render("field", ViewAngles(60.0, 0.0), size, seed=1)
        labels = v.mask if kind == "scene" else _grid_mask(*size, 4)
        fitter = FrameFitter(16, 3, bins=256)

        def capture(grain: bool):
            feats = compute(v.image, spec)
            fitter.reset()
            fitter.add(feats.data, labels)
            results = fitter.fit(min_count=64)
            seen = observed(fitter.counts, fitter.centre0, fitter.bin_width)
            models = {k: r.model for k, r in results.items()}
            deps = (measure(feats.data, labels, models, levels_seen=seen) if grain else
                    {lab: Dependence.observed(*seen[lab]) for lab in {lab for lab, _ in results}})
            return encode_models(results, robot_id=1, seq=1, time=0.0, commanded=(60.0, 0.0),
                                 measured=(60.0, 0.0), feature_space="rgb", bands=feats.band_names,
                                 levels=feats.levels, dependence=deps)

        sizes = {flag: len(capture(flag)) for flag in (False, True)}
        t = paired_times({"off": lambda: capture(False), "on": lambda: capture(True)}, repeat=ctx.pick(15, 2))
        lines.append(
            f"| {size[0]}x{size[1]} RGB field{'' if kind == 'scene' else ', 4x4 grid mask'} | "
            f"{len(np.unique(labels))} | {sizes[False]} B | {sizes[True]} B | +{sizes[True] - sizes[False]} B | "
            f"{t['off'] * 1e3:.1f} ms | {t['on'] * 1e3:.1f} ms | +{(t['on'] - t['off']) * 1e3:.1f} ms "
            f"({t['on'] / t['off']:.2f}x) |")
    return lines + ["", "Capture time: features, the 16-label fitter, the levels from its histograms, the dependence "
                    "pass (with the grain) and the MODELS body; the scene's true mask (or the grid) stands for "
                    f"segmentation. Best of paired rounds. Window: radius 6, {len(window(6))} lags, one row shared "
                    "by the bands, or one per band where their grains differ (the robot's choice)."]


def run(ctx: Context = Context()) -> list[str]:
    t0 = time.perf_counter()
    out = ["### Error and time against the anchors", "", *accuracy(ctx), "",
           "### Cost per capture on the robot: `[features] dependence`", "", *robot_cost(ctx)]
    return out + ["", f"_{time.perf_counter() - t0:.0f} s._"]
