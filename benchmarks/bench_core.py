"""Johnson core: fitting every model of a frame, against np.percentile over one band.
(Sampling: bench_sampling; the fit against MLE and other peers: bench_peers.)"""
from __future__ import annotations

import numpy as np

from benchmarks.common import Context, Section, paired_times, verdict
from onboard.fit import FrameFitter


def _frame(rng: np.random.Generator, side: int = 1000) -> tuple[np.ndarray, np.ndarray]:
    labels = (np.arange(side)[:, None] * 8 // side + np.arange(side)[None, :] * 2 // side) % 8
    base = np.array([40, 70, 100, 130, 160, 190, 210, 90])[labels][..., None]
    frame = np.clip(base + rng.gamma(2.0, 8.0, (side, side, 3)), 0, 255).astype(np.uint8)
    return frame, labels.astype(np.uint8)


def fit_speed(rng: np.random.Generator, ctx: Context) -> list[str]:
    frame, labels = _frame(rng, ctx.pick(1000, 100))
    fitter = FrameFitter(8, 3)

    def fit_all():
        fitter.reset()
        fitter.add(frame, labels)
        return fitter.fit()

    band = frame[..., 0].ravel()
    t = paired_times({"fit": fit_all, "pct": lambda: np.percentile(band, [5.8, 30, 70, 94.2])},
                     ctx.pick(9, 1))
    t_fit, t_pct = t["fit"], t["pct"]
    r = t_fit / t_pct
    return [
        "| task | time |", "|---|---|",
        f"| FrameFitter add + fit, {labels.shape[1]}x{labels.shape[0]} RGB, 8 labels (24 models) | {t_fit * 1e3:.2f} ms |",
        f"| np.percentile, one {band.size:,}-value uint8 band | {t_pct * 1e3:.2f} ms |",
        "",
        f"**fit / np.percentile = {r:.2f}x** (target <= 1.0x: {verdict(r, 1.0)})",
    ]


def run(ctx: Context) -> list[Section]:
    rng = np.random.default_rng(20240601)
    return [Section("Core: fitting every model of a frame", fit_speed(rng, ctx))]
