"""Shared helpers for the benchmark modules: timing, sections, the machine header."""
from __future__ import annotations

import os
import platform
import sys
import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np


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
    return [
        f"- platform: {platform.platform()}",
        f"- CPU: {cpu_model()}",
        f"- cores: {os.cpu_count()}",
        f"- python: {sys.version.split()[0]}",
        f"- numpy: {np.__version__}",
    ]


def verdict(ratio: float, limit: float, lower_is_better: bool = True) -> str:
    ok = ratio <= limit if lower_is_better else ratio >= limit
    return "met" if ok else "NOT met"
