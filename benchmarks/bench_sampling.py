"""Sampling 1M values per family, float32 and 8-bit pixels, against numpy's standard_normal and
random in the same run; the paper's Java Table 3 for context."""
from __future__ import annotations

import numpy as np

from benchmarks.common import Context, Section, figure, paired_times, save
from btf.johnson import Family, Johnson

FAMILIES = {
    "SN": Johnson.normal(120.0, 20.0),
    "SL, positive skew": Johnson(Family.SL, 0.5, 1.5, 40.0, 30.0),
    "SL, negative skew": Johnson(Family.SL, 0.5, 1.5, 220.0, -30.0),
    "SU": Johnson(Family.SU, 0.5, 1.4, 120.0, 25.0),
    "SB": Johnson(Family.SB, 0.3, 0.9, 20.0, 210.0),
}
# The paper's Table 3: Java, 1M samples (ms).
PAPER_MS = {"Johnson": 937, "Gaussian": 641, "Uniform": 406, "Weibull": 2187}


def run(ctx: Context) -> list[Section]:
    n = ctx.pick(1_000_000, 10_000)
    rng = np.random.default_rng(5)
    fns = {"standard_normal float32": lambda: rng.standard_normal(n, dtype=np.float32),
           "random float32 (uniform)": lambda: rng.random(n, dtype=np.float32),
           "weibull float64 (numpy)": lambda: rng.weibull(1.5, n)}
    for name, m in FAMILIES.items():
        fns[f"{name} float32"] = lambda m=m: m.sample(n, rng, dtype=np.float32)
        fns[f"{name} 8-bit pixels"] = lambda m=m: m.sample_pixels(n, rng)
    t = paired_times(fns, ctx.pick(9, 1))
    ref = t["standard_normal float32"]
    lines = [f"{n:,} samples, best of {ctx.pick(9, 1)} (calls interleaved). Ratio to numpy's "
             "`standard_normal(float32)` measured in the same run.", "",
             "| sampler | ms | / standard_normal | / random |", "|---|---:|---:|---:|"]
    for k, v in t.items():
        lines.append(f"| {k} | {v * 1e3:.2f} | {v / ref:.2f}x | {v / t['random float32 (uniform)']:.2f}x |")
    worst_px = max(v for k, v in t.items() if k.endswith("pixels"))
    worst_f = max(v for k, v in t.items() if k.endswith("float32") and not k.startswith(("standard", "random")))
    lines += ["", f"**Slowest family, 8-bit pixels / standard_normal = {worst_px / ref:.2f}x; "
              f"float32 / standard_normal = {worst_f / ref:.2f}x.**", "",
              "Context, the paper's Table 3 (Java, 1M samples): " + ", ".join(
                  f"{k} {v} ms" for k, v in PAPER_MS.items())
              + f" — Johnson / Gaussian = {PAPER_MS['Johnson'] / PAPER_MS['Gaussian']:.2f}x there. "
              "Pixels use a 2^16-entry lookup table drawn by uniform uint16 indices, so every family "
              "costs the same.", "", _plot(t, ctx)]
    return [Section("Sampling: 1M values per family", lines)]


def _plot(t: dict[str, float], ctx: Context) -> str:
    fig, ax = figure(1, 1, (7.5, 4.5))
    ax = ax[0][0]
    names = list(t)
    ax.barh(names, [t[k] * 1e3 for k in names], color=["gray" if " " in k and k.split()[0] in
                                                       ("standard_normal", "random", "weibull") else "C0"
                                                       for k in names])
    ax.set_xlabel("ms per call")
    ax.set_title("Sampling 1M values (gray: numpy references)")
    ax.invert_yaxis()
    return save(fig, ctx, "sampling.png")
