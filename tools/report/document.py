"""An HTML report of a database that leads with its results: a summary (the demo's bars, Tables 1
and 2 and the link's figures when it is a demo's; a row per robot and scene), the contents, the
BTF per robot and scene, the captures and models (tables folded), then every capture's synthetic
beside measured images and histograms with where it came from; a self-contained directory of PNGs.

Its look, and each capture's section, are the operator page's (`tools.report.look`,
`tools.report.capture_views`). Measured images are not in the database (the robot sends models, not
pixels); pass `measured(capture) -> RGB image` (e.g. `tools.report.capture_views.Frames`) to put them
beside the synthetic ones.
"""
from __future__ import annotations

import html
import re
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from tools.analysis.radiometry import describe as describe_camera
from tools.report.btf_section import INTRO, btf_sections
from tools.report.capture_views import Measured, png, views
from tools.report.look import CSS, MODEL_HEAD, capture_section, model_rows, note, source_name, table
from tools.report.summary import summary_html
from tools.store.database import Store

# The report's own layout (the operator's page has its own): wider, a sticky contents bar.
REPORT_CSS = """
body.report{max-width:1360px}
body.report p{max-width:1100px}
nav.toc{position:sticky;top:0;z-index:1;background:#fff;border-bottom:1px solid var(--line);
  padding:5px 0;margin:10px 0;font-size:13px;line-height:1.7}
nav.toc .sub{color:var(--idle)}
section,div.capture{scroll-margin-top:44px}
.row{display:flex;flex-wrap:wrap;gap:8px 28px;align-items:flex-start}
ul.bars{list-style:none;padding:0;margin:6px 0}ul.bars li{margin:4px 0;color:#1f2328}
.badge{display:inline-block;min-width:54px;text-align:center;padding:1px 8px;border-radius:10px;color:#fff;
  font-weight:600;text-transform:uppercase;font-size:12px}
.badge.ok{background:var(--ok)}.badge.bad{background:var(--bad)}
details{margin:6px 0}details>summary{cursor:pointer;color:#0969da}details[open]>summary{margin-bottom:4px}
h3.group{font-size:15px;background:var(--bg2);padding:4px 6px;margin-top:18px}
.capture img.view{width:200px}
table.sources td:last-child,table.sources th:last-child{text-align:left}
"""
FILES = {"measured": "measured", "independent": "synthetic", "correlated": "correlated", "histograms": "hist"}


def _captures_html(caps: list, fitted: dict, automatic: set[int] = frozenset()) -> str:
    """The captures and models tables, each folded under a line saying what it holds; a space
    chosen automatically (`automatic`: those captures' ids) is marked "auto"."""
    els = sorted(c.elevation for c in caps)
    rows = [[c.scene, c.robot, c.sequence, "" if c.commanded[0] is None else f"{c.commanded[0]:.1f}",
             f"{c.measured[0]:.2f}", c.space + (" (auto)" if c.id in automatic else ""), len(fitted[c.id]),
             describe_camera(c.camera)] for c in caps]
    parts = [f"<section id=captures><h2>Captures and models</h2><details><summary>Captures per angle: "
             f"{len(caps)} capture(s), view elevations {els[0]:.1f}° to {els[-1]:.1f}°</summary>"
             + table(["scene", "robot", "seq", "commanded", "measured", "space", "models", "camera"], rows)
             + "</details>"]
    models = [[c.scene, f"{c.elevation:.1f}", *r] for c in caps for r in model_rows(c, fitted[c.id])]
    if not models:
        return "".join(parts) + note("No models stored.") + "</section>"
    families = Counter(r[4] for r in models)
    parts.append(f"<details><summary>Models: {len(models)} (a region's band each; families "
                 + ", ".join(f"{f} {n}" for f, n in families.most_common()) + ")</summary>"
                 + table(["scene", "angle", *MODEL_HEAD], models, left=4) + "</details>")
    return "".join(parts) + "</section>"


def _images_html(store: Store, out: Path, groups: dict, measured: Measured | None, rng: np.random.Generator,
                 bar: Any) -> str:
    """Every capture's synthetic beside measured images and histograms, a section per robot and
    scene (anchors images-k); writes their PNGs into `out`."""
    parts, unmasked, shown = ["<section id=images><h2>Synthetic beside measured</h2>"], 0, 0
    used: set[str] = set()
    for k, ((robot, scene, space), caps) in enumerate(groups.items()):
        parts.append(f"<section id=images-{k}><h3 class=group>{html.escape(source_name(robot, scene, space))}: "
                     f"{len(caps)} capture(s)</h3>")
        for c in caps:
            v = views(store, c, rng, measured)
            name = _file_stem(c, used)
            bar.update()
            unmasked += v.no_mask
            if v.no_mask or not v.fitted:
                continue
            if v.problem:  # a label of the mask without models
                parts.append(note(f"{name}: {v.problem}"))
                continue
            for key, image in v.images.items():
                (out / f"{name}_{FILES[key]}.png").write_bytes(png(image))
            parts.append(capture_section(v, lambda key, name=name: f"{name}_{FILES[key]}.png", models=False))
            shown += 1
        parts.append("</section>")
    total = sum(len(caps) for caps in groups.values())
    if unmasked == total:
        parts.append(note("None: no capture has a label mask (the robot sends one with its captures; "
                          "`fit --mask` and `ingest --mask` store one), so nothing can be synthesized."))
    elif not shown:
        parts.append(note("None: no capture with a label mask has models for it."))
    elif unmasked:
        parts.append(note(f"{unmasked} capture(s) without a label mask are not shown."))
    return "".join(parts) + "</section>"


def _file_stem(c: Any, used: set[str]) -> str:
    """A capture's image files' stem, scene_elevation_sequence: only letters, digits, '.', '_'
    and '-', so a scene or robot name never leads outside the report's folder, and the capture's
    id added where another capture took the stem (two datasets' folders of one name)."""
    source = re.sub(r"[^A-Za-z0-9._-]+", "-", c.scene or "robot" + c.robot).lstrip(".") or "capture"
    stem = f"{source[:60]}_{c.elevation:05.1f}_{c.sequence}"
    if stem in used:
        stem = f"{stem}_id{c.id}"
    used.add(stem)
    return stem


def _toc(btfs: list, groups: dict, demo: Any) -> str:
    def subs(items: list[tuple[str, str]]) -> str:
        return (" <span class=sub>(" + " · ".join(f"<a href=#{a}>{html.escape(t)}</a>" for a, t in items)
                + ")</span>") if items else ""
    links = [f"<a href=#summary>{'Results' if demo is not None else 'Summary'}</a>"]
    if btfs:
        links.append("<a href=#btf>BTF</a>" + subs([(b.anchor, b.scene or b.robot) for b in btfs]))
    links.append("<a href=#captures>Captures and models</a>")
    links.append("<a href=#images>Synthetic beside measured</a>"
                 + subs([(f"images-{k}", scene or robot) for k, (robot, scene, _) in enumerate(groups)]))
    return "<nav class=toc><b>Contents:</b> " + " · ".join(links) + "</nav>"


def write_report(store: Store, out: Path, measured: Measured | None = None, demo: Any = None,
                 seed: int = 0, robot: str | None = None,
                 scene: str | None = None, progress: bool = False) -> Path:
    """Writes out/index.html and its PNGs for the captures of `robot` and `scene` (all when None);
    returns the HTML path. `demo` (a `tools.demo.end_to_end.DemoResult`) puts its results first.
    `progress` shows a tqdm bar over the captures on stderr."""
    from tqdm import tqdm

    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    caps = store.captures(robot=robot, scene=scene)
    fitted = {c.id: store.models(c.id) for c in caps}
    groups: dict[tuple[str, str, str], list] = {}
    for c in caps:  # by robot and scene, each by elevation
        groups.setdefault((c.robot, c.scene, c.space), []).append(c)
    groups = dict(sorted(groups.items()))
    btfs = btf_sections(store, out, robot, scene)
    chosen = " ".join(f"{k} {v}" for k, v in (("robot", robot), ("scene", scene)) if v is not None)
    parts = [f"<!doctype html><meta charset=utf-8><title>btfscout report</title><style>{CSS}{REPORT_CSS}</style>",
             "<body class=report>",
             f"<h1>btfscout report: {html.escape(store.path.name)}"
             + (f" ({html.escape(chosen)})" if chosen else "") + "</h1>",
             summary_html(caps, {cid: len(m) for cid, m in fitted.items()}, btfs, demo),
             _toc(btfs, groups, demo)]
    if btfs:
        parts.append(f"<section id=btf><h2>BTF: the models against angle</h2><p>{INTRO}</p>"
                     + "".join(b.html for b in btfs) + "</section>")
    if caps:
        parts.append(_captures_html(caps, fitted, {c.id for c in caps if store.space_choice(c.id)}))
    with tqdm(total=len(caps), desc="report", unit="capture", disable=not progress) as bar:
        parts.append(_images_html(store, out, groups, measured, rng, bar))
    parts.append("</body>")
    path = out / "index.html"
    path.write_text("\n".join(parts), encoding="utf-8")
    return path
