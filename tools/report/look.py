"""One look for the static report (`btf-host report`) and the operator's page (`station --http`):
the stylesheet, the HTML pieces (tables, figures, notes) and a capture's section (its images,
histograms with the Johnson curves, models table and camera settings), rendered by the same
functions for both. The images come from `tools.report.capture_views`; `src` says where each is
found (a file beside the report, a URL of the page).
"""
from __future__ import annotations

import html
import re
from typing import Any, Callable

from tools.analysis.radiometry import describe as describe_camera
from tools.analysis.radiometry import settings_json
from tools.store.rows import DATASET_PREFIX

CSS = """
:root{--ok:#1a7f37;--warn:#b35900;--bad:#c62828;--idle:#57606a;--line:#d0d7de;--bg2:#f6f8fa}
body{font-family:system-ui,sans-serif;font-size:14px;color:#1f2328;margin:0 auto;max-width:1100px;padding:0 8px}
h1{font-size:20px}h2{font-size:16px;margin:14px 0 6px}h3{font-size:14px;margin:10px 0 4px}
table{border-collapse:collapse;font-size:12px}
td,th{border:1px solid var(--line);padding:2px 6px;text-align:right}th{background:var(--bg2)}
td.l,th.l{text-align:left}
img.view{image-rendering:pixelated;width:240px;margin:2px;background:#eee}
img.hist,img.btf{max-width:100%}
code{font-family:ui-monospace,monospace;font-size:12px;background:var(--bg2);padding:0 3px;border-radius:3px}
p.source{margin:0 0 4px;font-size:12px;color:var(--idle);word-break:break-all}
table.loo td{white-space:nowrap}
figure{display:inline-block;margin:2px;vertical-align:top}
figcaption{font-size:11px;text-align:center;color:var(--idle)}
.note{color:var(--idle)}.ok{color:var(--ok)}.bad{color:var(--bad)}.warn{color:var(--warn)}
.capture{border-top:1px solid var(--line);padding-top:4px}
"""


class Html(str):
    """Text that is already HTML: a table cell shows it as it is."""


def cell(v: Any) -> str:
    if isinstance(v, Html):
        return v
    return f"{v:.4f}" if isinstance(v, float) else html.escape(str(v))


def table(head: list[str], rows: list[list[Any]], left: int = 0, cls: str = "") -> str:
    """An HTML table; the first `left` columns are text, aligned left."""
    def td(i: int, v: Any, tag: str) -> str:
        return f"<{tag}{' class=l' if i < left else ''}>{cell(v) if tag == 'td' else html.escape(str(v))}</{tag}>"
    return (f"<table{f' class={cls}' if cls else ''}><tr>" + "".join(td(i, h, "th") for i, h in enumerate(head))
            + "</tr>" + "".join("<tr>" + "".join(td(i, v, "td") for i, v in enumerate(r)) + "</tr>" for r in rows)
            + "</table>")


def figure(src: str, caption: str, cls: str = "view") -> str:
    return (f"<figure><img class={cls} src='{html.escape(src)}' alt='{html.escape(caption)}' "
            f"title='{html.escape(caption)}'><figcaption>{html.escape(caption)}</figcaption></figure>")


def prose(text: str) -> str:
    """Plain text as HTML, with `command` spans (in backticks) set as code."""
    return re.sub(r"`([^`]+)`", r"<code>\1</code>", html.escape(text))


def note(text: str) -> str:
    return f"<p class=note><em>{prose(text)}</em></p>"


MODEL_HEAD = ["label", "band", "family", "gamma", "delta", "xi", "lambda", "pixels", "fitted at (us)"]


def model_rows(capture: Any, fitted: dict) -> list[list[Any]]:
    """A capture's models, one row each (`MODEL_HEAD`): the stored records as fitted, with the
    exposure each was fitted at (a bracketed region's own)."""
    rows = []
    for (label, band), m in fitted.items():
        j = m.model
        at = capture.camera.exposure_of(label) if capture.camera is not None else None
        rows.append([label, capture.band_names[band] if band < len(capture.band_names) else band,
                     j.family.value, j.gamma, j.delta, j.xi, j.lam, m.count, "" if at is None else f"{at:g}"])
    return rows


def camera_table(capture: Any) -> str:
    """The capture's camera settings, one row each (none recorded: a note)."""
    s = settings_json(capture.camera)
    if s is None:
        return note("Camera settings not recorded.")
    def shown(v: Any) -> str:
        if isinstance(v, list):
            return ", ".join(shown(x) for x in v)
        return f"{v:g}" if isinstance(v, float) else str(v)
    rows = [[k.replace("_", " "), shown(v)] for k, v in s.items() if v not in (None, [], {})]
    if isinstance(s.get("bracketed"), dict) and s["bracketed"]:
        rows = [r for r in rows if r[0] != "bracketed"] + [["bracketed", describe_camera(capture.camera)]]
    return table(["setting", "value"], rows, left=2, cls="camera")


def azimuth_shown(azimuth: float, digits: int = 1) -> float:
    """An azimuth as shown, in [0, 360): rounded first, so 359.96 is 0.0, never 360.0."""
    return round(round(azimuth, digits) % 360.0, digits) + 0.0  # + 0.0: no -0.0


def capture_title(capture: Any) -> str:
    az = azimuth_shown(capture.measured[1])
    where = f"{capture.elevation:.1f}°" + (f" / {az:.1f}°" if az else "")
    return f"{capture.scene or 'robot ' + capture.robot} at {where} (seq {capture.sequence})"


def source_name(robot: str, scene: str, space: str = "") -> str:
    """A robot's or dataset's scene as the report names it: 'black (robot 1)', 'plates (dataset /data/plates, rgb)'."""
    source = f"dataset {robot[len(DATASET_PREFIX):]}" if robot.startswith(DATASET_PREFIX) else f"robot {robot}"
    return f"{scene or 'no scene'} ({source}{', ' + space if space else ''})"


def capture_source(capture: Any) -> str:
    """Where a capture came from: a dataset's file and item with its angles, else the robot, its
    sequence and the pose it measured (and was commanded to)."""
    el, az = capture.measured
    light = capture.illumination
    lit = f", light {light[0]:.1f}° / {light[1]:.1f}°" if light[0] is not None and light[1] is not None else ""
    if capture.dataset is not None:
        return (f"file {capture.source_file or 'not recorded'}; dataset {capture.scene or capture.dataset}, "
                f"item {capture.source or capture.sequence}; view elevation {el:.1f}°, azimuth {az:.1f}°{lit}")
    cmd = capture.commanded
    asked = "" if cmd[0] is None else f" (commanded {cmd[0]:.1f}° / {cmd[1] or 0.0:.1f}°)"
    state = f", incarnation {capture.incarnation}" if capture.incarnation else ""
    file = f"; file {capture.source}" if capture.source else ""
    replayed = getattr(capture.camera, "source", None)
    if replayed:  # a replaying camera read the frame from this file
        file += f"; frame from file {replayed}"
    return (f"robot {capture.robot}, sequence {capture.sequence}{state}; pose elevation {el:.2f}°, "
            f"azimuth {az:.2f}°{asked}{lit}{file}")


def capture_section(views: Any, src: Callable[[str], str], models: bool = True) -> str:
    """A capture's section: measured (when known), synthesized (independent, and correlated when
    the capture carries dependence), histograms with the Johnson curves, then its models and
    camera settings (`models`). `src(name)` is where image `name` (`views.images`) is found."""
    cap = views.capture
    captions = {"measured": "measured", "independent": "independent pixels" if "correlated" in views.images
                else "synthesized", "correlated": "grain and band correlation"}
    imgs = [figure(src(name), captions[name]) for name in ("measured", "independent", "correlated")
            if name in views.images]
    if "histograms" in views.images:
        imgs.append(figure(src("histograms"), "histograms and Johnson curves", cls="hist"))
    source = capture_source(cap)
    if views.whole:
        source += "; no label map: the whole image is region 0"
    if getattr(views, "space_choice", None):
        source += f"; feature space chosen automatically, {views.space_choice}"
    if not models and cap.camera is not None:  # no camera table: the settings in the source line
        source += f"; camera {describe_camera(cap.camera)}"
    parts = [f"<div class=capture data-capture='{cap.id}'><h3>{html.escape(capture_title(cap))}</h3>",
             f"<p class=source>{html.escape(source)}</p>"]
    if views.problem:
        parts.append(note(views.problem))
    parts.append("<div>" + "".join(imgs) + "</div>")
    if models:
        parts.append(table(MODEL_HEAD, model_rows(cap, views.fitted), left=3, cls="models")
                     if views.fitted else note("No models stored for this capture."))
        parts.append(camera_table(cap))
    return "".join(parts) + "</div>"
