"""Shared helpers for the benchmark modules: the run context, timing, sections, plots, the machine."""
from __future__ import annotations

import os
import platform
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

HERE = Path(__file__).resolve().parent


@dataclass(frozen=True)
class Context:
    """How a benchmark runs: `quick` shrinks sizes and repeats to a smoke test; plots go to `out`."""
    quick: bool = False
    out: Path = HERE

    def pick(self, full, quick):
        return quick if self.quick else full


@dataclass(frozen=True)
class Section:
    """A titled block of markdown lines in RESULTS.md."""
    title: str
    lines: list[str] = field(default_factory=list)

    def markdown(self) -> list[str]:
        return [f"## {self.title}", "", *self.lines, ""]


def best_time(fn: Callable[[], object], repeat: int = 7, warmup: int = 1) -> float:
    """Best wall time of `repeat` calls, seconds (the least disturbed by other load)."""
    for _ in range(warmup):
        fn()
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def paired_times(fns: dict[str, Callable[[], object]], repeat: int = 7) -> dict[str, float]:
    """Best time of each function, the calls interleaved round by round so that a burst of
    load from other processes hits every contender alike (a ratio from one run stays fair)."""
    for fn in fns.values():
        fn()
    best = {k: float("inf") for k in fns}
    for _ in range(repeat):
        for k, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            best[k] = min(best[k], time.perf_counter() - t0)
    return best


def paired_rounds(fns: dict[str, Callable[[], object]], repeat: int = 7) -> dict[str, np.ndarray]:
    """Every round's time of each function, the calls interleaved (and their order reversed
    every other round, so that neither always runs on the other's warm caches)."""
    for fn in fns.values():
        fn()
    keys = list(fns)
    times = {k: np.empty(repeat) for k in keys}
    for r in range(repeat):
        for k in (keys if r % 2 == 0 else keys[::-1]):
            t0 = time.perf_counter()
            fns[k]()
            times[k][r] = time.perf_counter() - t0
    return times


@dataclass(frozen=True)
class Saving:
    """The share of time a rule saves, from rounds paired with its baseline: the median of the
    per-round savings and their interquartile range."""
    median: float
    q25: float
    q75: float
    rounds: int

    @classmethod
    def of(cls, rule: np.ndarray, base: np.ndarray) -> Saving:
        s = 1.0 - np.asarray(rule, float) / np.asarray(base, float)
        q25, med, q75 = np.percentile(s, [25, 50, 75])
        return cls(float(med), float(q25), float(q75), int(s.size))

    @property
    def measurable(self) -> bool:
        """Whether the spread of the paired rounds leaves out zero."""
        return not self.q25 <= 0.0 <= self.q75

    def text(self) -> str:
        spread = f"quartiles {self.q25:+.0%}..{self.q75:+.0%}, {self.rounds} rounds"
        if self.measurable:
            return f"{self.median:.0%} ({spread})"
        return f"no measurable difference (median {self.median:+.0%}, {spread})"


def figure(ncols: int = 1, nrows: int = 1, size: tuple[float, float] = (6.4, 4.2), **kw):
    """A matplotlib figure on the Agg backend (no display needed)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt.subplots(nrows, ncols, figsize=(size[0] * ncols, size[1] * nrows), squeeze=False, **kw)


def save(fig, ctx: Context, name: str, tight: bool = True) -> str:
    """Write the figure as `name` under ctx.out; the markdown image line for RESULTS.md."""
    import warnings

    import matplotlib.pyplot as plt
    ctx.out.mkdir(parents=True, exist_ok=True)
    if tight:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fig.tight_layout()
    fig.savefig(ctx.out / name, dpi=90)
    plt.close(fig)
    return f"![{name}]({name})"


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine_lines() -> list[str]:
    try:
        load = "%.2f %.2f %.2f" % os.getloadavg()
    except OSError:
        load = "unknown"
    return [
        f"- platform: {platform.platform()}",
        f"- CPU: {cpu_model()}",
        f"- cores: {os.cpu_count()} (load average at start: {load}; the machine is shared)",
        f"- python: {sys.version.split()[0]}",
        f"- numpy: {np.__version__}",
    ]


def verdict(ratio: float, limit: float, lower_is_better: bool = True) -> str:
    ok = ratio <= limit if lower_is_better else ratio >= limit
    return "met" if ok else "NOT met"
