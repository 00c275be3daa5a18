"""Context: how long the fake camera's scene renderer takes, first view against cached views
(the surface is built once per scene, seed and size; each view only projects it)."""
from __future__ import annotations

import time

from benchmarks.common import Context, Section
from hal.interfaces import ViewAngles
from hal.scene import render
from hal.scene.surface import build_surface


def run(ctx: Context) -> list[Section]:
    sizes = ctx.pick(((480, 640), (1000, 1000)), ((48, 64),))
    lines = ["| size | first view (builds the surface) | later view, best of 3 | ratio |", "|---|---:|---:|---:|"]
    for h, w in sizes:
        build_surface.cache_clear()
        t0 = time.perf_counter()
        render("field", ViewAngles(55.0, 10.0), size=(h, w), seed=99)
        first = time.perf_counter() - t0
        later = float("inf")
        for az in (20.0, 30.0, 40.0):
            t0 = time.perf_counter()
            render("field", ViewAngles(55.0, az), size=(h, w), seed=99)
            later = min(later, time.perf_counter() - t0)
        lines.append(f"| {w}x{h} | {first * 1e3:.0f} ms | {later * 1e3:.0f} ms | {first / later:.1f}x |")
    return [Section("Context: fake scene rendering (hal.scene.render, field)", lines)]
