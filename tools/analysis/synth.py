"""Synthetic images from a label mask and Johnson models, at measured and unseen angles.

Between two measured angles the models are blended in quantile space: one normal
deviate z per pixel and band, mapped through both neighbours' quantile functions
x_of_z and mixed by angle weight. For one-dimensional distributions that is the
optimal-transport (displacement) interpolation; it stays valid when the Johnson
family differs between the two angles, where blending raw parameters is not.
"""
from __future__ import annotations

import warnings
from typing import Callable, Mapping, Protocol

import numpy as np

from btf.dependence import LAGS, Dependence
from btf.johnson import Family, Johnson
from tools.analysis.fields import blend, latent, region_fields
from tools.analysis.tiles import Draws, Region, label_counts, region

Models = Mapping[tuple[int, int], Johnson]
Dependences = Mapping[int, Dependence]  # per label; labels without one are drawn independently


class MissingModels(ValueError):
    """Mask labels with no model; the message lists them."""


class ExtrapolationWarning(UserWarning):
    """The requested angle lies outside the measured range; the nearest angle was used."""


class _ModelSource(Protocol):
    def models_by_angle(self) -> dict[float, dict[tuple[int, int], Johnson]]: ...


def _bands(models: Models) -> int:
    if not models:
        raise MissingModels("no models to synthesize from")
    return max(b for _, b in models) + 1


def _check(mask: np.ndarray, models: Models, n_bands: int, where: str = "",
           labels: list[int] | None = None) -> list[int]:
    if mask.ndim != 2:
        raise ValueError(f"mask must be H x W, got shape {mask.shape}")
    labels = list(label_counts(mask)) if labels is None else labels
    missing = sorted({lab for lab in labels for b in range(n_bands) if (lab, b) not in models})
    if missing:
        have = sorted({lab for lab, _ in models})
        raise MissingModels(
            f"mask label(s) {missing} have no models{where} (models exist for labels {have})"
        )
    return labels


def _output(mask: np.ndarray, n_bands: int, levels: int) -> np.ndarray:
    if mask.ndim != 2:
        raise ValueError(f"mask must be H x W, got shape {mask.shape}")
    return np.zeros(mask.shape + (n_bands,), dtype=np.uint8 if levels <= 256 else np.uint16)


def _correlated(dep: Dependence | None, n_bands: int) -> bool:
    return dep is not None and dep.n_bands == n_bands


def _pixels(model: Johnson, z: np.ndarray, levels: int) -> np.ndarray:
    """Levels of x(z), rounded and clipped: the transform in float32 (a pixel is within 0.005
    of a level of where float64 puts it, so at most that rare boundary pixel rounds the other
    way), a third of x_of_z's time on the fields' float32 z."""
    z = np.asarray(z, dtype=np.float32)
    f32 = np.float32
    g, d, xi, lam = f32(model.gamma), f32(model.delta), f32(model.xi), f32(model.lam)
    with np.errstate(over="ignore", invalid="ignore"):
        if model.family is Family.CONST:
            x = np.full(z.shape, xi, dtype=np.float32)
        elif model.family is Family.SN:
            x = xi + lam * z
        else:
            t = (z - g) / d
            if model.family is Family.SU:
                e = np.exp(t)
                x = xi + (f32(0.5) * lam) * (e - f32(1.0) / e)
            elif model.family is Family.SB:
                x = xi + lam / (f32(1.0) + np.exp(-t))
            else:  # SL, lam's sign its side
                x = xi + lam * np.exp(t if model.lam > 0 else -t)
    x = np.nan_to_num(x, nan=0.0, posinf=levels - 1, neginf=0.0)
    return np.clip(np.rint(x), 0, levels - 1)


PixelsOf = Callable[[slice, np.ndarray, int], np.ndarray]  # (rows, region pixels in them, count)


def fill(out: np.ndarray, band: int, mask: np.ndarray, where: Region, pixels: PixelsOf) -> None:
    """out[..., band] at the region's pixels, row tile by row tile in row-major order."""
    for r in where.tiles:
        sel = mask[r, where.cols] == where.label
        k = int(np.count_nonzero(sel))
        if k == sel.size:  # the tile lies inside the region: no gather or scatter
            out[r, where.cols, band] = pixels(r, sel, k).reshape(sel.shape)
        elif k:
            out[r, where.cols, band][sel] = pixels(r, sel, k)


def _from_fields(fields: np.ndarray, where: Region, to_pixels: Callable[[np.ndarray], np.ndarray]) -> PixelsOf:
    """Pixels from a band's correlated field over the region's box."""
    r0 = where.rows.start

    def pixels(r: slice, sel: np.ndarray, k: int) -> np.ndarray:
        box = fields[r.start - r0:r.stop - r0]
        return to_pixels(box if k == sel.size else box[sel])
    return pixels


def _from_stream(draws: Draws, to_pixels: Callable[[np.ndarray], np.ndarray] | None = None) -> PixelsOf:
    """Pixels from an independent random stream (drawn as pixels, or as z for `to_pixels`)."""
    if to_pixels is None:
        return lambda r, sel, k: draws.take(k)
    return lambda r, sel, k: to_pixels(draws.take(k))


def synthesize(mask: np.ndarray, models: Models, rng: np.random.Generator, levels: int = 256,
               dependence: Dependences | None = None) -> np.ndarray:
    """An H x W x B image: each region's pixels drawn from its models, with the region's grain
    and band copula (a correlated field, `tools.analysis.fields`) when `dependence` has it, else independently.
    Works region by region in row tiles: beyond the mask and the image it holds a region's
    correlated fields (B float32 per pixel of its box) or a few tiles."""
    n_bands = _bands(models)
    out = _output(mask, n_bands, levels)
    for label in _check(mask, models, n_bands):
        where = region(mask, label)
        dep = (dependence or {}).get(label)
        if _correlated(dep, n_bands):
            dep = latent(dep, tuple(models[(label, b)] for b in range(n_bands)), levels)
            fields = region_fields(where, dep, rng)
            for b in range(n_bands):
                fill(out, b, mask, where, _from_fields(
                    fields[b], where, lambda z, m=models[(label, b)]: _pixels(m, z, levels)))
            del fields
            continue
        for b in range(n_bands):
            model = models[(label, b)]
            draws = Draws(lambda size, m=model: m.sample_pixels(size, rng, levels), where.count)
            fill(out, b, mask, where, _from_stream(draws))
    return out


def blend_pixels(weighted: list[tuple[float, Johnson]], levels: int) -> Callable[[np.ndarray], np.ndarray]:
    """z -> sum_k w_k x_k(z), rounded and clipped to the levels (quantile-space blending)."""
    def to_pixels(z: np.ndarray) -> np.ndarray:
        x = np.zeros(len(z))
        for w, m in weighted:
            x += w * m.x_of_z(z)
        return np.clip(np.rint(x), 0, levels - 1)
    return to_pixels


def interpolate(lo: Models, hi: Models, weight: float, mask: np.ndarray,
                rng: np.random.Generator, levels: int = 256,
                dependence: tuple[Dependences | None, Dependences | None] = (None, None)) -> np.ndarray:
    """Quantile-space blend: x = (1 - w) x_lo(z) + w x_hi(z), rounded and clipped to the levels.
    z is a correlated field where both angles (or the only one that has it) carry dependence,
    blended linearly across the angles (a mix of correlation matrices stays one)."""
    if not 0.0 <= weight <= 1.0:
        raise ValueError(f"interpolation weight must lie in [0, 1], got {weight}")
    n_bands = max(_bands(lo), _bands(hi))
    labels = _check(mask, lo, n_bands, " at the lower neighbouring angle")
    _check(mask, hi, n_bands, " at the upper neighbouring angle", labels)
    out = _output(mask, n_bands, levels)
    for label in labels:
        where = region(mask, label)
        d_lo, d_hi = ((d or {}).get(label) for d in dependence)
        d_lo, d_hi = (latent(d, tuple(m[(label, b)] for b in range(n_bands)), levels)
                      if _correlated(d, n_bands) else None for d, m in ((d_lo, lo), (d_hi, hi)))
        dep = blend(d_lo, d_hi, weight) if d_lo and d_hi else (d_lo or d_hi)
        fields = None if dep is None else region_fields(where, dep, rng)
        for b in range(n_bands):
            to_pixels = _blend2(lo[(label, b)], hi[(label, b)], weight, levels)
            fill(out, b, mask, where, _from_stream(Draws(rng.standard_normal, where.count), to_pixels)
                 if fields is None else _from_fields(fields[b], where, to_pixels))
    return out


def _blend2(lo: Johnson, hi: Johnson, weight: float, levels: int) -> Callable[[np.ndarray], np.ndarray]:
    # (1 - w) x_lo + w x_hi in this order: the same floating-point sum as before tiling
    return lambda z: np.clip(np.rint((1.0 - weight) * lo.x_of_z(z) + weight * hi.x_of_z(z)), 0, levels - 1)


def neighbours(angles: list[float], angle: float) -> tuple[float, float, float]:
    """(lower angle, upper angle, weight of the upper); clamped to the ends with a warning."""
    if not angles:
        raise MissingModels("no measured angles to synthesize from")
    if not np.isfinite(angle):
        raise ValueError(f"angle {angle} is not a finite number of degrees")
    a = sorted(angles)
    if angle <= a[0] or angle >= a[-1]:
        near = a[0] if angle <= a[0] else a[-1]
        if angle != near:
            warnings.warn(
                f"angle {angle:g} lies outside the measured range {a[0]:g}..{a[-1]:g}; "
                f"using the nearest measured angle {near:g}",
                ExtrapolationWarning, stacklevel=3,
            )
        return near, near, 0.0
    k = int(np.searchsorted(a, angle))
    if a[k] == angle:
        return angle, angle, 0.0
    lo, hi = a[k - 1], a[k]
    return lo, hi, (angle - lo) / (hi - lo)


def synthesize_at(source: _ModelSource | Mapping[float, Models], mask: np.ndarray, angle: float,
                  rng: np.random.Generator, levels: int = 256,
                  dependence: Mapping[float, Dependences] | None = None,
                  independent: bool = False) -> np.ndarray:
    """An image at `angle` from models by angle (a mapping, or a Store's models_by_angle()).
    Dependence by angle comes from `dependence`, else from the source's dependence_by_angle()
    when it has one; `independent` ignores it and draws every pixel on its own."""
    by_angle = source.models_by_angle() if hasattr(source, "models_by_angle") else source
    if dependence is None and hasattr(source, "dependence_by_angle"):
        dependence = source.dependence_by_angle()
    deps = {} if independent or dependence is None else dependence
    lo, hi, w = neighbours(list(by_angle), float(angle))
    if lo == hi:
        return synthesize(mask, by_angle[lo], rng, levels, deps.get(lo))
    return interpolate(by_angle[lo], by_angle[hi], w, mask, rng, levels, (deps.get(lo), deps.get(hi)))


# --- the MODELS.json document that `btf-host fit --json` prints ----------------------------
def models_document(space: str, band_names: tuple[str, ...], levels: int, angle: float | None,
                    results: Mapping[tuple[int, int], object], pca: dict | None = None,
                    image: str | None = None, dependence: Dependences | None = None) -> dict:
    """The MODELS.json document; `dependence` None (not measured) is written as null."""
    rows = []
    for (label, band), r in sorted(results.items()):
        m = r.model
        rows.append({
            "label": int(label), "band": int(band), "band_name": band_names[band],
            "family": str(m.family.value), "gamma": m.gamma, "delta": m.delta, "xi": m.xi, "lam": m.lam,
            "percentiles": [float(p) for p in r.percentiles], "z": float(r.z), "count": int(r.count),
            "beta1": float(r.beta1), "beta2": float(r.beta2),
        })
    return {"image": image, "space": space, "bands": list(band_names), "levels": int(levels),
            "angle": angle, "pca": pca, "models": rows,
            "dependence": None if dependence is None else dependence_record(dependence)}


def dependence_record(dependence: Dependences) -> dict:
    """{"lags", "regions": [{"label", "corr", "dx", "dy"}]}: the document's dependence section."""
    return {"lags": list(LAGS), "regions": [
        {"label": int(lab), "corr": list(d.corr), "dx": list(d.dx), "dy": list(d.dy)}
        for lab, d in sorted(dependence.items())]}


def dependence_from_document(doc: dict, n_bands: int) -> dict[int, Dependence]:
    """The per-label dependence of a models document ({} when it has none); ValueError says what is wrong."""
    rec = doc.get("dependence")
    if rec is None:
        return {}
    if not isinstance(rec, dict) or not isinstance(rec.get("regions"), list):
        raise ValueError("dependence: expected an object with a 'regions' list")
    if rec.get("lags") != list(LAGS):
        raise ValueError(f"dependence: lags {rec.get('lags')!r}; synthesis reads lags {list(LAGS)}")
    out: dict[int, Dependence] = {}
    for k, row in enumerate(rec["regions"]):
        try:
            dep = Dependence(*(tuple(float(v) for v in row[name]) for name in ("corr", "dx", "dy")))
            label = int(row["label"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"dependence region {k}: {exc}") from None
        if dep.n_bands != n_bands:
            raise ValueError(f"dependence of label {label}: {dep.n_bands} band(s), the models have {n_bands}")
        out[label] = dep
    return out


def models_from_document(doc: object) -> tuple[float | None, dict[tuple[int, int], Johnson], dict]:
    """(angle, models, the document) from one parsed MODELS.json document; ValueError says what is wrong."""
    if not isinstance(doc, dict) or not isinstance(doc.get("models"), list):
        raise ValueError("not a models document (expected an object with a 'models' list)")
    out: dict[tuple[int, int], Johnson] = {}
    for k, row in enumerate(doc["models"]):
        try:
            out[(int(row["label"]), int(row["band"]))] = Johnson(
                Family(row["family"]), float(row["gamma"]), float(row["delta"]),
                float(row["xi"]), float(row["lam"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"model {k}: {exc}") from None
    angle = doc.get("angle")
    if angle is not None and (type(angle) not in (int, float) or not np.isfinite(angle)):
        raise ValueError(f"angle {angle!r} is not a finite number of degrees")
    return (None if angle is None else float(angle)), out, doc
