"""The report's BTF section, one per robot and scene: the BTF drawn region by region
(`tools.report.btf_plots`) and the leave-one-out table, interpolation against the nearest
measured angle (`tools.analysis.btf_loo`), with where and why the interpolation loses."""
from __future__ import annotations

import html
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tools.analysis import btf_loo, btf_view
from tools.report.btf_plots import figure_png, region_blocks
from tools.report.look import figure, note, source_name

DPI = 100  # the figures are shown at the size they are drawn: 990 px wide

INTRO = ("The BTF is each region's model as a function of the angles: the mean, standard deviation, "
         "skewness and kurtosis of its level probabilities, and its Johnson family, at the measured angles "
         "(markers), with the curve the interpolation of <code>synth --angle</code> draws between them; "
         "the heat maps show the whole distribution against angle. Leave one out: each angle with measured "
         "angles on both sides is predicted from the others and compared with its own model by the exact "
         "L1 between level probabilities (0: the same, 2: disjoint), beside the nearest measured angle alone.")


@dataclass
class BtfPart:
    """One robot and scene's BTF section: its anchor, who it is, its HTML and the leave-one-out
    summary the report's summary quotes (None: no angle with measured neighbours on both sides)."""

    anchor: str
    who: str
    robot: str
    scene: str
    space: str
    html: str
    loo: btf_loo.LooSummary | None


def btf_sections(store: Any, out: Path, robot: str | None = None, scene: str | None = None) -> list[BtfPart]:
    """Every robot and scene's BTF section; writes their figures into `out`."""
    parts = []
    for k, (r, s, space) in enumerate(btf_view.sources(store, robot, scene)):
        btf = btf_view.load(store, r, s, space)
        parts.append(section(btf, out, f"btf_{k}", f"btf-{k}"))
    return parts


def section(btf: Any, out: Path, stem: str, anchor: str) -> BtfPart:
    who = source_name(btf.robot, btf.scene, btf.space)
    parts = [f"<section class=btf id={anchor}><h3>BTF of {html.escape(who)}</h3>"]
    axes = ", ".join(btf_view.AXIS_TITLES[a] for a in btf.varied) or "nothing"
    again = (f" (the latest capture at each, of {btf.stored} stored)" if btf.stored > len(btf.directions) else "")
    parts.append(f"<p class=note>{len(btf.directions)} measured direction(s){again}; the sweep varied {axes}.</p>")
    if not btf.varied:
        parts.append(note("One measured direction: no BTF to draw yet."))
        return BtfPart(anchor, who, btf.robot, btf.scene, btf.space, "".join(parts) + "</section>", None)
    figures = []
    for label, axis in region_blocks(btf):
        name = f"{stem}_{label}_{axis}.png"
        (out / name).write_bytes(figure_png(btf, [(label, axis)], dpi=DPI))
        figures.append(figure(name, f"region {label} against {btf_view.AXIS_TITLES[axis]}", cls="btf"))
    parts.append("<div>" + "".join(figures) + "</div>")
    rows = btf_loo.leave_one_out(btf)
    parts.append(loo_html(btf, rows))
    return BtfPart(anchor, who, btf.robot, btf.scene, btf.space, "".join(parts) + "</section>",
                   btf_loo.summary(rows) if rows else None)


def loo_html(btf: Any, rows: list) -> str:
    """The summary line, the table (a row per region and band, a column per left-out angle) and
    the losses explained."""
    if not rows:
        return note("Leave one out: no measured angle has measured neighbours on both sides yet.")
    s = btf_loo.summary(rows)
    verdict = "ok" if s.better == s.interior else "warn"
    parts = [f"<p class={verdict}>Leave one out: the interpolation beats the nearest measured angle in "
             f"<b>{s.better} of {s.interior}</b> cases (a region's band at an angle with measured angles on "
             f"both sides); mean exact L1 {s.interpolated_mean:.4f} interpolated against {s.nearest_mean:.4f} "
             "nearest.</p>"]
    points = sorted({r.point for r in rows}, key=lambda i: btf.directions[i].angles())
    by = {(r.label, r.band, r.point): r for r in rows}
    head = "".join(f"<th>{html.escape(btf_loo.angle_text(btf, i))}</th>" for i in points)
    body = []
    for label, band in sorted({(r.label, r.band) for r in rows}):
        cells = []
        for i in points:
            r = by.get((label, band, i))
            cells.append("<td></td>" if r is None else
                         f"<td class={'ok' if r.better else 'bad'}>{r.interpolated:.4f} / {r.nearest:.4f}</td>")
        body.append(f"<tr><td class=l>{label}</td><td class=l>{html.escape(btf.band_name(band))}</td>"
                    + "".join(cells) + "</tr>")
    parts.append(f"<details><summary>Leave one out per region, band and angle ({len(body)} rows)</summary>"
                 "<table class=loo><tr><th class=l>region</th><th class=l>band</th>" + head + "</tr>"
                 + "".join(body) + "</table><p class=note>Each cell: exact L1 of the interpolation from the "
                 "other angles / of the nearest measured angle alone, left-out angle in the header.</p></details>")
    lost = [r for r in rows if not r.better]
    if lost:
        parts.append(f"<details><summary>Where the nearest angle does better, and why ({len(lost)} cases)"
                     "</summary><ul>" + "".join(
            f"<li>region {r.label} band {html.escape(btf.band_name(r.band))} at "
            f"{html.escape(btf_loo.angle_text(btf, r.point))}: {html.escape(btf_loo.why_not(btf, r))}</li>"
            for r in lost) + "</ul></details>")
    return "".join(parts)
