"""The MODELS.json document `btf-host fit --json` prints and `synth --model` reads.

Each model row carries its region's observed levels in its band ("lo", "hi"); the document's
"dependence" holds, per region, the band correlations and the autocorrelation on the
half-plane window of its radius (btf.dependence.window: "acf", one row shared by the bands or
one per band), or null when the grain was not measured. Documents of the older layout
({"lags": [1, 2, 4, 8], "regions": [{"label", "corr", "dx", "dy"}]}, no levels) are still read.
"""
from __future__ import annotations

from typing import Mapping

import numpy as np

from btf.dependence import LAGS, Dependence
from btf.johnson import Family, Johnson

Dependences = Mapping[int, Dependence]


def models_document(space: str, band_names: tuple[str, ...], levels: int, angle: float | None,
                    results: Mapping[tuple[int, int], object], pca: dict | None = None,
                    image: str | None = None, dependence: Dependences | None = None) -> dict:
    """The MODELS.json document: a row per model (with its observed levels when the record
    has them) and the measured grain (null when none was measured)."""
    deps = dependence or {}
    rows = []
    for (label, band), r in sorted(results.items()):
        m = r.model
        row = {
            "label": int(label), "band": int(band), "band_name": band_names[band],
            "family": str(m.family.value), "gamma": m.gamma, "delta": m.delta, "xi": m.xi, "lam": m.lam,
            "percentiles": [float(p) for p in r.percentiles], "z": float(r.z), "count": int(r.count),
            "beta1": float(r.beta1), "beta2": float(r.beta2),
        }
        seen = deps[label].levels(band) if label in deps and deps[label].lo else None
        if seen is not None:
            row["lo"], row["hi"] = seen
        rows.append(row)
    measured = {lab: d for lab, d in deps.items() if d.measured}
    return {"image": image, "space": space, "bands": list(band_names), "levels": int(levels),
            "angle": angle, "pca": pca, "models": rows,
            "dependence": dependence_record(measured) if measured else None}


def dependence_record(dependence: Dependences) -> dict:
    """{"regions": [{"label", "radius", "corr", "acf"}]}: the document's dependence section (null
    at a lag not measured)."""
    return {"regions": [{"label": int(lab), "radius": d.radius, "corr": list(d.corr), "acf": d.acf_rows()}
                        for lab, d in sorted(dependence.items()) if d.measured]}


def _grain(row: dict) -> tuple[int, Dependence]:
    label = int(row["label"])
    if "acf" in row:
        return label, Dependence.from_rows(row["corr"], row["acf"], int(row["radius"]))
    return label, Dependence.from_lags(*(tuple(float(v) for v in row[k]) for k in ("corr", "dx", "dy")))


def dependence_from_document(doc: dict, n_bands: int) -> dict[int, Dependence]:
    """The per-label records of a models document ({} when it has neither grain nor levels);
    ValueError says what is wrong."""
    rec = doc.get("dependence")
    out: dict[int, Dependence] = {}
    if rec is not None:
        if not isinstance(rec, dict) or not isinstance(rec.get("regions"), list):
            raise ValueError("dependence: expected an object with a 'regions' list")
        if "lags" in rec and rec["lags"] != list(LAGS):
            raise ValueError(f"dependence: lags {rec.get('lags')!r}; synthesis reads lags {list(LAGS)}")
        for k, row in enumerate(rec["regions"]):
            try:
                label, dep = _grain(row)
            except (KeyError, TypeError, ValueError) as exc:
                raise ValueError(f"dependence region {k}: {exc}") from None
            if dep.n_bands != n_bands:
                raise ValueError(f"dependence of label {label}: {dep.n_bands} band(s), the models have {n_bands}")
            out[label] = dep
    for label, (lo, hi) in _levels(doc, n_bands).items():
        try:
            out[label] = out[label].with_levels(lo, hi) if label in out else Dependence.observed(lo, hi)
        except ValueError as exc:
            raise ValueError(f"model levels of label {label}: {exc}") from None
    return out


def _levels(doc: dict, n_bands: int) -> dict[int, tuple[list[int], list[int]]]:
    """{label: (lo per band, hi per band)} of the labels whose every model row has them."""
    found: dict[int, dict[int, tuple[int, int]]] = {}
    for k, row in enumerate(doc.get("models") or []):
        if "lo" not in row and "hi" not in row:
            continue
        lo, hi = row.get("lo"), row.get("hi")
        if type(lo) is not int or type(hi) is not int:
            raise ValueError(f"model {k}: lo {lo!r} and hi {hi!r} must both be integer levels")
        found.setdefault(int(row["label"]), {})[int(row["band"])] = (lo, hi)
    return {lab: ([bands[b][0] for b in range(n_bands)], [bands[b][1] for b in range(n_bands)])
            for lab, bands in found.items() if set(bands) == set(range(n_bands))}


def models_from_document(doc: object) -> tuple[float | None, dict[tuple[int, int], Johnson], dict]:
    """(angle, models, the document) from one parsed MODELS.json document; ValueError says what is wrong."""
    if not isinstance(doc, dict) or not isinstance(doc.get("models"), list):
        raise ValueError("not a models document (expected an object with a 'models' list)")
    out: dict[tuple[int, int], Johnson] = {}
    for k, row in enumerate(doc["models"]):
        try:
            label, band = row["label"], row["band"]
            if type(label) is not int or type(band) is not int or label < 0 or band < 0:
                raise ValueError(f"label {label!r} and band {band!r} must be whole numbers from 0")
            if (label, band) in out:  # a second one would silently take the first's place
                raise ValueError(f"a second model of label {label} band {band}; keep one")
            out[(label, band)] = Johnson(Family(row["family"]), float(row["gamma"]), float(row["delta"]),
                                         float(row["xi"]), float(row["lam"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"model {k}: {exc}") from None
    angle = doc.get("angle")
    if angle is not None and (type(angle) not in (int, float) or not np.isfinite(angle)):
        raise ValueError(f"angle {angle!r} is not a finite number of degrees")
    if angle is not None and not 0.0 <= angle <= 90.0:
        raise ValueError(f"angle {angle:g}: an elevation lies in 0..90 degrees")
    return (None if angle is None else float(angle)), out, doc
