"""Synthesis of a 1000x1000 RGB image from an 8-label mask, directly and interpolated between
two view angles (tools.analysis.synth); the paper's goal: under a couple of seconds."""
from __future__ import annotations

import numpy as np

from benchmarks.common import Context, Section, best_time
from benchmarks.scenes import field, voronoi_labels
from btf.fit.fitter import FrameFitter
from tools.analysis.synth import interpolate, synthesize


def _models(frame: np.ndarray, labels: np.ndarray, n: int):
    f = FrameFitter(n, 3)
    f.add(frame, labels)
    return {k: r.model for k, r in f.fit().items()}


def run(ctx: Context) -> list[Section]:
    h, w = ctx.pick((1000, 1000), (64, 64))
    n = 8
    mask = voronoi_labels(h, w, n, seed=1)
    frame, _ = field(h, w)
    lo = _models(frame, mask, n)
    hi = _models(np.clip(frame.astype(np.int16) + 25, 0, 255).astype(np.uint8), mask, n)
    rng = np.random.default_rng(0)
    repeat = ctx.pick(5, 1)
    t_syn = best_time(lambda: synthesize(mask, lo, rng), repeat)
    t_int = best_time(lambda: interpolate(lo, hi, 0.4, mask, rng), repeat)
    t_copy = best_time(lambda: frame.copy(), repeat)
    lines = [f"{w}x{h} RGB from an {n}-label mask ({len(lo)} models), best of {repeat}.", "",
             "| task | time | / the paper's 2 s goal |", "|---|---:|---:|",
             f"| synthesize (lookup-table pixels) | {t_syn * 1e3:.1f} ms | {t_syn / 2.0:.3f} |",
             f"| interpolate between two angles (quantile blend) | {t_int * 1e3:.1f} ms | {t_int / 2.0:.3f} |",
             "", f"Context: copying the {frame.nbytes / 1e6:.0f} MB frame takes {t_copy * 1e3:.2f} ms; "
             f"synthesis = {t_syn / t_copy:.0f}x a copy, interpolation = {t_int / t_syn:.1f}x synthesis "
             "(float64 deviates through two quantile functions instead of one table lookup)."]
    return [Section("Synthesis: 1000x1000 RGB from an 8-label mask", lines)]
