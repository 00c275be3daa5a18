"""On-board features and segmentation for a 1 MP RGB frame, timed against np.percentile.

Every time is the best of several runs, reported as a ratio to one np.percentile over
a 1M-value band in the same run (the yardstick: a whole capture, fit and
encode included, should cost at most 4 of those). ISODATA rows also give the share of
pixels labelled differently from the scene's true regions, so the subsample size can
be chosen by time against error.
"""
from __future__ import annotations

import time
from itertools import permutations

import numpy as np

from benchmarks.common import Context, Section
from btf.fit.features import FeatureSpace, FeatureSpec, PcaBasis, compute
from btf.fit.isodata import IsodataParams, isodata
from radio.packets.mask import downsample_labels

SIDE = 1000
REPEATS = 5
_REPEATS = [REPEATS]  # this run's repeat count
CLUTTER = np.array([[194, 178, 128], [86, 125, 70], [112, 84, 62], [150, 150, 140]], float)


def _scene(seed: int = 0, side: int = SIDE) -> tuple[np.ndarray, np.ndarray]:
    """Four clutter types in irregular patches, with grain noise and shading."""
    rng = np.random.default_rng(seed)
    coarse = rng.integers(0, 4, (10, 10))
    truth = np.kron(coarse, np.ones((side // 10, side // 10), np.int64))
    shade = np.linspace(0.85, 1.1, side)[None, :, None]
    img = CLUTTER[truth] * shade + rng.normal(0, 9, (side, side, 3))
    return np.clip(img, 0, 255).astype(np.uint8), truth


def _best(fn, repeats: int | None = None) -> float:
    repeats = repeats or _REPEATS[0]
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


def _label_error(labels: np.ndarray, truth: np.ndarray) -> float:
    """Share of pixels mislabelled under the best renaming of found labels to true ones."""
    k = int(max(labels.max(), truth.max())) + 1
    conf = np.bincount(labels.ravel().astype(np.int64) * k + truth.ravel(), minlength=k * k).reshape(k, k)
    if k <= 8:
        best = max(sum(conf[i, p[i]] for i in range(k)) for p in permutations(range(k)))
    else:
        best = conf.max(axis=1).sum()
    return 1.0 - best / truth.size


def run(ctx: Context | None = None) -> list[str]:
    ctx = ctx or Context()
    side, _REPEATS[0] = ctx.pick((SIDE, REPEATS), (100, 1))
    frame, truth = _scene(side=side)
    band = frame[..., 1].ravel()
    ref = _best(lambda: np.percentile(band, (5, 25, 50, 75, 95)))
    lines = [
        f"Yardstick: one `np.percentile` over a 1M-value band = {ref * 1e3:.1f} ms. "
        "The whole capture (this plus fit and encode) should stay within 4x.",
        "",
        "| step | ms | x percentile | error |",
        "|---|---:|---:|---:|",
    ]

    def row(name: str, t: float, err: str = "") -> None:
        lines.append(f"| {name} | {t * 1e3:.1f} | {t / ref:.2f} | {err} |")

    for space, bands in ((FeatureSpace.RGB, None), (FeatureSpace.GRAY, None),
                         (FeatureSpace.HSV, None), (FeatureSpace.HSV, ("V",)), (FeatureSpace.HSV, ("S", "V"))):
        spec = FeatureSpec(space, bands)
        label = f"features {space.value}" + (f" ({','.join(bands)} only)" if bands else "")
        row(label, _best(lambda: compute(frame, spec)))
    row("pca basis fit (20k sample, once per scene)", _best(lambda: PcaBasis.fit(frame)))
    basis = PcaBasis.fit(frame)
    row("features pca (apply)", _best(lambda: compute(frame, FeatureSpec(FeatureSpace.PCA), pca=basis)))

    rgb = compute(frame, FeatureSpec(FeatureSpace.RGB))
    for sub in ctx.pick((2000, 5000, 20000), (2000,)):
        params = IsodataParams(k=4, subsample=sub, split_std=20, merge_distance=25)
        t = _best(lambda: isodata(rgb.data, params))
        err = _label_error(isodata(rgb.data, params).labels, truth)
        row(f"isodata k=4, subsample {sub}", t, f"{err:.2%} mislabelled")
    params = IsodataParams(k=4, split_std=20, merge_distance=25)
    res = isodata(rgb.data, params)
    row("downsample labels to 64x64", _best(lambda: downsample_labels(res.labels, 64)))
    total = _best(lambda: downsample_labels(isodata(compute(frame, FeatureSpec(FeatureSpace.RGB)).data,
                                                    params).labels, 64))
    row("**rgb features + isodata (20k) + MASK map**", total)
    hsv_total = _best(lambda: isodata(compute(frame, FeatureSpec(FeatureSpace.HSV)).data, params))
    row("hsv features + isodata (20k)", hsv_total)
    lines.append("")
    return [Section("On-board features and segmentation (1 MP RGB frame)", lines)]


if __name__ == "__main__":
    print("\n".join(run()[0].markdown()))
