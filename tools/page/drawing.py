"""The operator page's drawings, made in its worker processes (`tools.page.data` hands them over):
a capture's card picture, its section and histograms (the report's own, `tools.report`), and
the BTF panel. Synthesis, OpenCV and matplotlib load here, in the workers, never in the station.
"""
from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from tools.analysis.radiometry import adjusted
from tools.page.btf_panel import panel
from tools.report.capture_views import Frames, histogram_png, label_map, png, shown, views
from tools.report.look import capture_section
from tools.store.database import Store

__all__ = ["panel", "render", "warm"]

SHOWN_FIRST = "correlated", "independent", "measured"  # a card's picture: the likest to the surface
_stores: dict[str, Any] = {}  # the worker's connection to each database


def render(db: str, capture_id: int, fake: Any, what: str, rev: int) -> dict:
    """`what` "thumb" ({"png"}: the card's picture), "section" ({"html", "images": {name: png}}:
    its pictures, the histograms' place kept) or "histograms" ({"png"}: the plot, a drawing of its
    own as it takes longest) of one capture; {"missing": text} when there is nothing."""
    store = _stores.get(db)
    if store is None:
        store = _stores[db] = Store.open(db, create=False)
    cap = store.capture_by_id(capture_id)
    if cap is None:
        return {"missing": f"no capture {capture_id} in the database"}
    rng = np.random.default_rng(capture_id)  # the same drawing every time
    if what == "thumb":  # the synthesis, or the measured frame when there is none
        v = views(store, cap, rng, None, histograms=False)
        if not v.images:
            v = views(store, cap, rng, Frames(fake), histograms=False)
        name = next((k for k in SHOWN_FIRST if k in v.images), None)
        return {"png": png(v.images[name])} if name else {"missing": v.problem or "nothing to draw"}
    if what == "histograms":
        return _histograms(store, cap, fake)
    v = views(store, cap, rng, Frames(fake), histograms=False)
    images = {k: png(img) for k, img in v.images.items()}
    if v.fitted and not (v.no_mask or v.problem):  # what views() draws histograms for
        v.images["histograms"] = b""  # its place in the section; drawn when the page asks for it
    html = capture_section(v, lambda k: f"capture/{capture_id}/{k}.png?r={rev}")
    return {"html": html, "images": images}


def _histograms(store: Store, cap: Any, fake: Any) -> dict:
    """The histograms with the Johnson curves (as `views` draws them), without synthesizing again."""
    fitted = store.models(cap.id)
    models = dict(adjusted({k: m.model for k, m in fitted.items()}, cap.camera))
    frame = Frames(fake)(cap)  # measured bars wherever the report draws them (rgb, and gray)
    real = frame if frame is not None and shown(cap, frame) else None
    mask, _ = label_map(store, cap, models, frame)
    if mask is None or not models:
        return {"missing": f"capture {cap.id} has no histograms"}
    return {"png": histogram_png(real, mask, models, cap.band_names, cap.levels)}


def warm() -> None:
    """One plot drawn before the first request needs one (matplotlib's first figure costs a second)."""
    with warnings.catch_warnings():  # an empty plot's "no artists for the legend"
        warnings.simplefilter("ignore")
        histogram_png(None, np.zeros((2, 2), np.uint8), {}, ("Y",))
