"""The operator page's BTF panel data (`GET /api/btf`), computed in a worker process of the page:
for one robot, scene and feature space and one (region, band), the measured points against the
sweep's main angle, the interpolated curve between them and the leave-one-out figures
(`tools.analysis.btf_view`, `tools.analysis.btf_loo`: what the report and `btf-host btf` show).
"""
from __future__ import annotations

from typing import Any

from tools.analysis import btf_loo, btf_view
from tools.store.database import Store

_stores: dict[str, Store] = {}


def _store(db: str) -> Store:
    if db not in _stores:
        _stores[db] = Store.open(db, create=False)
    return _stores[db]


def _series(btf: btf_view.Btf, label: int, band: int, axis: str) -> list[dict]:
    out = []
    for key, pts in btf.series(label, band, axis).items():
        points = []
        for i in pts:
            m = btf_view.moments(btf.probabilities(i, label, band))
            points.append({"angle": btf_view.axis_value(btf.directions[i], axis), "seq": btf.captures[i].sequence,
                           "angles": btf_loo.angle_text(btf, i), "family": btf.models[i][(label, band)].family.value,
                           "pixels": btf.counts[i].get((label, band)), **m.as_dict()})
        curve = [{"angle": c.angle, **c.moments.as_dict()} for c in btf_view.curve(btf, label, band, axis, pts, key)]
        out.append({"name": btf.series_name(axis, key), "points": points, "curve": curve})
    return out


def panel(db: str, params: dict) -> dict:
    """The panel's JSON document; {"empty": why} when there is nothing to draw yet."""
    store = _store(db)
    found = btf_view.sources(store)
    if not found:
        return {"empty": "no captures yet", "sources": []}
    sources = [{"robot": r, "scene": s, "space": sp} for r, s, sp in found]
    want = (params.get("robot"), params.get("scene"), params.get("space"))
    if want == (None, None, None):  # the newest capture's
        newest = max(store.captures(), key=lambda c: c.id)
        chosen = (newest.robot, newest.scene, newest.space)
    else:
        chosen = next((f for f in found if all(w in (None, v) for w, v in zip(want, f))), None)
    if chosen is None:
        return {"empty": f"no captures of robot {want[0]} scene {want[1]!r}", "sources": sources}
    btf = btf_view.load(store, *chosen)
    regions = btf.regions()
    label, band = params.get("label"), params.get("band")
    if (label, band) not in regions:
        label, band = regions[0]
    axis = btf.main_axis
    loo = btf_loo.leave_one_out(btf, label, band)
    return {"sources": sources, "robot": btf.robot, "scene": btf.scene, "space": btf.space, "levels": btf.levels,
            "bands": list(btf.band_names), "regions": [[lab, b] for lab, b in regions], "label": label,
            "band": band, "band_name": btf.band_name(band), "axis": axis, "axis_title": btf_view.AXIS_TITLES[axis],
            "varied": list(btf.varied), "points": len(btf.at(label, band)),
            "series": _series(btf, label, band, axis),
            "loo": {"summary": btf_loo.summary(loo).as_dict(), "rows": btf_loo.loo_json(btf, loo)}}
