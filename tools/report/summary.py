"""The report's first section, what the data shows: the demo's bars with the figures that decide
them, the paper's Tables 1 and 2 and what the link measured (when the report is a demo's), then a
row per robot and scene with its captures, models and how well the BTF interpolates (leave one out).
"""
from __future__ import annotations

import html
from typing import Any

from tools.report.look import Html, source_name, table

BAR_TITLES = {"mixed_reproduction": "Mixed plate reproduction", "unseen_angle": "Unseen angle",
              "johnson_best": "Johnson fits best"}
LINK_FIGURES = (("delivered", "packets delivered"), ("lost", "frames lost"), ("corrupted", "frames corrupted"),
                ("retransmissions", "retransmissions"), ("duplicates", "duplicates dropped"),
                ("rejected", "frames rejected"), ("skipped", "poses skipped"))


def bars_html(demo: Any) -> str:
    """The bars, met or missed, each with the figure that decides it and what it asks."""
    figures = demo.figures()
    items = []
    for name, met in demo.bars().items():
        figure, needed = figures.get(name, ("no figure: the experiment has no rows", ""))
        items.append(f"<li class={'ok' if met else 'bad'}><span class='badge {'ok' if met else 'bad'}'>"
                     f"{'met' if met else 'missed'}</span> <b>{html.escape(BAR_TITLES.get(name, name))}</b>: "
                     f"{html.escape(figure)}<span class=note> (bar: {html.escape(needed)})</span></li>")
    return "<ul class=bars>" + "".join(items) + "</ul>"


def table1_html(rows: list[dict]) -> str:
    """Table 1 as the paper prints it: a row per mask method, the bands of both spaces across."""
    spaces = list(dict.fromkeys(r["space"] for r in rows))
    columns = [(sp, b) for sp in spaces for b in next(r for r in rows if r["space"] == sp)["correlation"]]
    by = {(r["method"], r["space"]): r for r in rows}
    body = []
    for method in dict.fromkeys(r["method"] for r in rows):
        first = next(by[(method, sp)] for sp in spaces if (method, sp) in by)
        body.append([method, first["regions"], *[f"{by[(method, sp)]['correlation'][b]:.3f}"
                                                  if (method, sp) in by else "" for sp, b in columns]])
    return table(["mask", "regions", *[f"{sp} {b}" for sp, b in columns]], body, left=1)


def table2_html(pdfs: dict[str, dict[str, float]]) -> str:
    """Table 2: each scene's total histogram error per model, the lowest in bold."""
    peers = list(next(iter(pdfs.values())).keys()) if pdfs else []
    body = []
    for scene, t in pdfs.items():
        low = min(t.values())
        body.append([scene, *[Html(f"<b>{t[p]:.3f}</b>") if t[p] == low else f"{t[p]:.3f}" for p in peers]])
    return table(["scene", *peers], body, left=1)


def link_html(demo: Any) -> str:
    """What crossed the link, both ends summed, over which simulated radio, and the run time."""
    link = demo.link

    def figure(key: str) -> str:
        if key == "retransmissions":
            return (f"{link.get(key, 0)} ({link.get('retransmissions_robot', 0)} robot, "
                    f"{link.get('retransmissions_host', 0)} host)")
        return str(link.get(key, 0))
    c = demo.channel
    radio = ("" if c is None else f" over a simulated radio losing {c.loss:.0%} of its frames"
             f"{' in bursts' if c.bursty else ''}, bit error rate {c.ber:g}, {c.latency * 1000:g} ms latency,"
             f" {c.bandwidth * 8 / 1000:g} kbit/s")
    return (f"<p>The robots' models crossed the link{html.escape(radio)}; both ends counted. "
            f"Run time {demo.seconds:.1f} s (sweeps and experiments; this report was written after).</p>"
            + table(["captures stored", *[title for _, title in LINK_FIGURES]],
                    [[", ".join(f"{s} {n}" for s, n in demo.captures.items()), *[figure(k) for k, _ in LINK_FIGURES]]],
                    left=1))


def experiments_html(demo: Any) -> str:
    """The rows behind the first two bars, folded: per angle and band, per plate."""
    bands = list(demo.mixed[0]["synthetic"]) if demo.mixed else []

    def ratio(r: dict, b: str) -> float:
        return r["synthetic"][b] / r["ceiling"][b] if r["ceiling"][b] else 0.0
    mixed = [[f"{r['angle']:.1f}", *[f"{r[k][b]:.3f}" for k in ("synthetic", "ceiling") for b in bands],
              f"{min(ratio(r, b) for b in bands):.3f}"] for r in demo.mixed]
    unseen = [[s, *[f"{u[k]:.3f}" for k in ("fitted", "interpolated", "nearest")], f"{u['lo']:g}/{u['hi']:g}"]
              for s, u in demo.unseen.items()]
    return (f"<details><summary>Mixed plate reproduction per angle ({len(mixed)} angles): the synthetic mixed "
            "plate (black and white models, mixed mask) against its capture, beside the ceiling of two captures "
            "with different grain seeds; the paper reports 0.97</summary>"
            + table(["angle", *[f"{k} {b}" for k in ("synthetic", "ceiling") for b in bands], "worst ratio"], mixed)
            + "</details>"
            f"<details><summary>Unseen angle per plate ({len(unseen)} plates): total histogram error at 45° of its "
            "own fit, of the interpolation from its neighbours and of the nearest measured angle</summary>"
            + table(["plate", "fitted at 45°", "interpolated", "nearest measured", "neighbours"], unseen, left=1)
            + "</details>")


def demo_html(demo: Any) -> str:
    """The demo's results: bars, Tables 1 and 2 side by side, the link, the experiments folded."""
    return (bars_html(demo) + "<div class=row>"
            "<div><h3>Table 1: correlation per band of the synthetic field scene, per mask</h3>"
            + table1_html(demo.table1) + "</div>"
            "<div><h3>Table 2: total histogram error per model</h3>" + table2_html(demo.pdfs)
            + "<p class=note>Lowest in bold.</p></div></div>"
            "<h3>The link</h3>" + link_html(demo) + experiments_html(demo))


def sources_html(caps: list, models: dict[int, int], btfs: list) -> str:
    """A row per robot, scene and space: its captures, angles, models (`models`: a count per capture
    id) and leave-one-out verdict."""
    loo = {(b.robot, b.scene, b.space): b for b in btfs}
    groups: dict[tuple[str, str, str], list] = {}
    for c in caps:
        groups.setdefault((c.robot, c.scene, c.space), []).append(c)
    rows = []
    for (robot, scene, space), group in sorted(groups.items()):
        els = sorted(c.elevation for c in group)
        part = loo.get((robot, scene, space))
        name = html.escape(source_name(robot, scene))
        s = part.loo if part is not None else None
        verdict = ("no angle with measured neighbours on both sides" if s is None else
                   f"interpolation better in {s.better} of {s.interior}; mean L1 {s.interpolated_mean:.4f} "
                   f"against {s.nearest_mean:.4f} nearest")
        tone = "note" if s is None else "ok" if s.better == s.interior else "warn"
        rows.append([Html(f"<a href=#{part.anchor}>{name}</a>" if part else name), space, len(group),
                     f"{els[0]:.1f}° to {els[-1]:.1f}°", sum(models[c.id] for c in group),
                     Html(f"<span class={tone}>{html.escape(verdict)}</span>")])
    return table(["scene", "space", "captures", "view elevations", "models", "BTF leave one out"], rows, left=2,
                 cls="sources")


def summary_html(caps: list, models: dict[int, int], btfs: list, demo: Any = None) -> str:
    """The summary section (anchor `summary`): the demo's results when `demo`, then the database's."""
    head = f"<section id=summary class=summary><h2>{'Summary' if demo is None else 'Results'}</h2>"
    data = (f"<h3>The database: {len(caps)} capture(s) of {len({(c.robot, c.scene) for c in caps})} "
            "robot(s) and scene(s)</h3>" + sources_html(caps, models, btfs))
    return head + (demo_html(demo) if demo is not None else "") + data + "</section>"
