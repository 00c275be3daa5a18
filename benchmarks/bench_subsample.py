"""Fit run time against error as the pixel stride grows: FrameFitter(subsample=k) keeps every
k-th row and column, so 1/k^2 of the pixels (k = 16 is 1/256).

Errors are against the fit of every pixel of the same frame, worst over all (label, band):
- quantile error: the largest change of the four fitted percentiles, gray levels;
- histogram error: L1 between the model's level probabilities and the full-frame histogram
  (0..2), minus the same for the full-frame fit: what subsampling adds.
"""
from __future__ import annotations

import numpy as np

from benchmarks.common import Context, Section, figure, paired_times, save
from benchmarks.scenes import field, voronoi_labels
from btf.fit.fitter import FrameFitter

STRIDES = (1, 2, 4, 8, 16)
# Default: the largest stride whose worst quantile error stays under half a gray level.
TOLERANCE = 0.5


def _fit(frame: np.ndarray, labels: np.ndarray, n_labels: int, k: int):
    f = FrameFitter(n_labels, 3, subsample=k)
    f.add(frame, labels)
    return f.fit()


def _errors(full: dict, full_hist: np.ndarray, sub: dict) -> tuple[float, float]:
    q = h = 0.0
    for key, r in full.items():
        if key not in sub:
            return float("inf"), 2.0  # a label vanished under the stride
        s = sub[key]
        q = max(q, float(np.max(np.abs(np.subtract(s.percentiles, r.percentiles)))))
        data = full_hist[key] / full_hist[key].sum()
        h_full = float(np.abs(data - r.model.level_probabilities()).sum())
        h_sub = float(np.abs(data - s.model.level_probabilities()).sum())
        h = max(h, h_sub - h_full)
    return q, h


def run(ctx: Context) -> list[Section]:
    sizes = ctx.pick(((480, 640), (1000, 1000)), ((60, 80),))
    label_counts = ctx.pick((1, 4, 16), (1, 4))
    repeat = ctx.pick(5, 1)
    rows = []  # (size, n_labels, k, seconds, q_err, h_err)
    for h, w in sizes:
        frame, _ = field(h, w)
        for n in label_counts:
            labels = voronoi_labels(h, w, n)
            hist_fitter = FrameFitter(n, 3)
            hist_fitter.add(frame, labels)
            full = hist_fitter.fit()
            hists = {key: hist_fitter.counts[key[0], key[1]] for key in full}
            times = paired_times({k: (lambda k=k: _fit(frame, labels, n, k)) for k in STRIDES}, repeat)
            smallest = int(min(hist_fitter.counts[key[0], 0].sum() for key in full))
            for k in STRIDES:
                q, e = _errors(full, hists, _fit(frame, labels, n, k))
                rows.append(((h, w), n, k, times[k], q, e, smallest // (k * k)))
    lines = ["Fake field scene (hal.scene.render, 60 degrees), Voronoi label maps, 3 bands. "
             "Time: FrameFitter add + fit, best of "
             f"{repeat}, strides interleaved. Speed-up is against stride 1 of the same frame.", "",
             "| frame | labels | stride (pixels) | time ms | speed-up | worst quantile error (gray) "
             "| histogram error added | smallest region keeps |", "|---|---:|---|---:|---:|---:|---:|---:|"]
    base = {(r[0], r[1]): r[3] for r in rows if r[2] == 1}
    for size, n, k, t, q, e, kept in rows:
        lines.append(f"| {size[1]}x{size[0]} | {n} | {k} (1/{k * k}) | {t * 1e3:.2f} | "
                     f"{base[(size, n)] / t:.1f}x | {q:.3f} | {e:.4f} | {kept} px |")
    choice = _choose(rows)
    need = _pixels_needed(rows)
    lines += ["", _plot(rows, ctx), "",
              f"**Chosen default: subsample={choice}** — the largest stride whose worst quantile error over "
              f"every frame size and label count stays within {TOLERANCE} gray level (half a quantization "
              "step), i.e. below what the 8-bit sensor itself resolves. Larger strides buy little more time "
              "(the fit's fixed cost per model starts to dominate) and their error grows with the number of "
              "labels, because each region keeps only 1/k^2 of its pixels. The runtime's precision rule "
              "(onboard.capture.skip.subsample_stride) sizes the stride per frame from the smallest region, which "
              "is the same trade made adaptively. Read by region size, the table says: every row whose "
              f"smallest region keeps at least {need} pixels is within {TOLERANCE} gray level, so a stride "
              f"may grow while the smallest kept region keeps {need} pixels (skip.pixels_for_precision(p) "
              f"= 1/(4 p^2) gives that for p = {0.5 / need ** 0.5:.4f})."]
    return [Section("Fit: run time against error as pixels are subsampled", lines)]


def _choose(rows) -> int:
    ok = [k for k in STRIDES if all(r[4] <= TOLERANCE for r in rows if r[2] == k)]
    return max(ok) if ok else 1


def _pixels_needed(rows) -> int:
    """The fewest kept pixels in the smallest region above which every row meets the tolerance."""
    bad = [r[6] for r in rows if r[4] > TOLERANCE]
    return (max(bad) + 1) if bad else min(r[6] for r in rows)


def _pareto(points: list[tuple[float, float, int]]) -> list[tuple[float, float, int]]:
    """Points (time, error, stride) not beaten on both time and error by another."""
    front, best = [], float("inf")
    for t, e, k in sorted(points):
        if e < best:
            front.append((t, e, k))
            best = e
    return front


def _plot(rows, ctx: Context) -> str:
    fig, ax = figure(1, 1, (7.5, 5.0))
    ax = ax[0][0]
    for size in sorted({r[0] for r in rows}):
        for n in sorted({r[1] for r in rows}):
            pts = [(t * 1e3, max(q, 1e-3), k) for s, nn, k, t, q, *_ in rows if s == size and nn == n]
            ts, qs, ks = zip(*pts)
            line, = ax.plot(ts, qs, "o:", alpha=0.6, label=f"{size[1]}x{size[0]}, {n} labels")
            for t, q, k in pts:
                ax.annotate(f"1/{k * k}", (t, q), fontsize=7, xytext=(3, 3), textcoords="offset points")
            front = _pareto(pts)
            ax.plot([p[0] for p in front], [p[1] for p in front], "-", color=line.get_color(), lw=2)
    ax.axhline(TOLERANCE, color="k", ls="--", lw=0.8, label=f"{TOLERANCE} gray level")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("time per frame (ms): add + fit, 3 bands")
    ax.set_ylabel("worst quantile error (gray levels)")
    ax.set_title("Fit: time against error by pixel fraction (solid: Pareto front)")
    ax.legend(fontsize=7)
    return save(fig, ctx, "fit_subsample.png")
