"""An HTML report of a database: captures per angle, the models, synthetic beside measured
images, histogram overlays and the metric tables; a self-contained directory of PNGs.

Its look, and each capture's section, are the operator page's (`tools.report.look`,
`tools.report.capture_views`). Measured images are not in the database (the robot sends models, not
pixels); pass `measured(capture) -> RGB image` (e.g. `tools.report.capture_views.Frames`) to put them
beside the synthetic ones.
"""
from __future__ import annotations

import html
from pathlib import Path
from typing import Any

import numpy as np

from tools.analysis.radiometry import describe as describe_camera
from tools.report.btf_section import btf_sections
from tools.report.capture_views import Measured, png, views
from tools.report.look import CSS, MODEL_HEAD, capture_section, model_rows, note, table
from tools.store.database import Store


def _demo_sections(demo: Any) -> list[str]:
    out = ["<h2>Mixed plate reproduction</h2><p>Correlation between the synthetic mixed plate "
           "(black and white models, mixed mask) and its capture, beside the ceiling: two captures "
           "of the same plate with different grain seeds. The paper reports 0.97.</p>"]
    rows = []
    for r in demo.mixed:
        for b in r["synthetic"]:
            ratio = r["synthetic"][b] / r["ceiling"][b] if r["ceiling"][b] else 0.0
            rows.append([f"{r['angle']:.1f}", b, r["synthetic"][b], r["ceiling"][b], ratio, 0.97])
    out.append(table(["angle", "band", "synthetic", "ceiling", "ratio", "paper"], rows))
    out.append("<h2>Unseen angle (45°)</h2>")
    out.append(table(["plate", "fitted at 45°", "interpolated", "nearest measured", "neighbours"],
                      [[s, u["fitted"], u["interpolated"], u["nearest"], f"{u['lo']:g}/{u['hi']:g}"]
                       for s, u in demo.unseen.items()]))
    out.append("<h2>Table 2: total histogram error per model</h2>")
    peers = list(next(iter(demo.pdfs.values())).keys()) if demo.pdfs else []
    out.append(table(["scene", *peers], [[s, *[t[p] for p in peers]] for s, t in demo.pdfs.items()]))
    out.append("<h2>Table 1: correlation per band on the field scene</h2>")
    out.append(table(["mask", "space", "regions", "band 1", "band 2", "band 3"],
                      [[r["method"], r["space"], r["regions"], *r["correlation"].values()] for r in demo.table1]))
    bars = demo.bars()
    out.append("<h2>Bars</h2><ul>" + "".join(
        f"<li class={'ok' if v else 'bad'}>{html.escape(k)}: {'met' if v else 'MISSED'}</li>"
        for k, v in bars.items()) + "</ul>")
    out.append(f"<p>Link, both ends: {html.escape(', '.join(f'{k} {v}' for k, v in demo.link.items()))}. "
               f"Run time {demo.seconds:.1f} s (sweeps and experiments; this report was written after).</p>")
    return out


def write_report(store: Store, out: Path, measured: Measured | None = None, demo: Any = None,
                 seed: int = 0, robot: str | None = None,
                 scene: str | None = None, progress: bool = False) -> Path:
    """Writes out/index.html and its PNGs for the captures of `robot` and `scene` (all when None);
    returns the HTML path. `progress` shows a tqdm bar over the captures on stderr."""
    from tqdm import tqdm

    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    caps = store.captures(robot=robot, scene=scene)
    chosen = " ".join(f"{k} {v}" for k, v in (("robot", robot), ("scene", scene)) if v is not None)
    parts = [f"<!doctype html><meta charset=utf-8><title>btfscout report</title><style>{CSS}</style>",
             f"<h1>btfscout report: {html.escape(store.path.name)}"
             + (f" ({html.escape(chosen)})" if chosen else "") + "</h1>",
             *btf_sections(store, out, robot, scene),
             "<h2>Captures per angle</h2>",
             table(["scene", "robot", "seq", "commanded", "measured", "space", "models", "camera"],
                    [[c.scene, c.robot, c.sequence, "" if c.commanded[0] is None else f"{c.commanded[0]:.1f}",
                      f"{c.measured[0]:.2f}", c.space, len(store.models(c.id)), describe_camera(c.camera)]
                     for c in caps])]
    rows = [[c.scene, f"{c.elevation:.1f}", *r] for c in caps for r in model_rows(c, store.models(c.id))]
    parts += ["<h2>Models</h2>", table(["scene", "angle", *MODEL_HEAD], rows, left=4)
              if rows else note("No models stored.")]
    parts.append("<h2>Synthetic beside measured</h2>")
    shown, unmasked = len(parts), 0
    files = {"measured": "measured", "independent": "synthetic", "correlated": "correlated", "histograms": "hist"}
    for c in tqdm(caps, desc="report", unit="capture", disable=not progress):
        v = views(store, c, rng, measured)
        name = f"{c.scene or 'robot' + c.robot}_{c.elevation:05.1f}_{c.sequence}"
        unmasked += v.no_mask
        if v.no_mask or not v.fitted:
            continue
        if v.problem:  # a label of the mask without models
            parts.append(note(f"{name}: {v.problem}"))
            continue
        for key, image in v.images.items():
            (out / f"{name}_{files[key]}.png").write_bytes(png(image))
        parts.append(capture_section(v, lambda key, name=name: f"{name}_{files[key]}.png", models=False))
    if unmasked == len(caps):
        parts.append(note("None: no capture has a label mask (the robot sends one with its captures; "
                           "`fit --mask` and `ingest --mask` store one), so nothing can be synthesized."))
    elif len(parts) == shown:
        parts.append(note("None: no capture with a label mask has models for it."))
    elif unmasked:
        parts.append(note(f"{unmasked} capture(s) without a label mask are not shown."))
    if demo is not None:
        parts += _demo_sections(demo)
    path = out / "index.html"
    path.write_text("\n".join(parts), encoding="utf-8")
    return path
