"""The host's radiometry: models brought to one exposure, drift normalised by the reference card.

Levels of the rgb and gray spaces are linear in exposure (`btf.capture_settings`), so a region's
models fitted at exposure e describe it at exposure E scaled by E / e, clipped at the sensor
limits when synthesized: bracketed regions return to the capture's exposure, and a sweep can be
synthesized at any exposure. The reference card's level per band measures the light and the
exposure together, so scaling each capture by (the sweep's median reference level) / (its own)
takes out whatever drifted between captures: a lamp warming up, a cloud, an exposure the camera
chose itself.
"""
from __future__ import annotations

import math
import statistics
import warnings
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np

from btf.capture_settings import LINEAR_SPACES, CaptureSettings, scaled
from btf.dependence import Dependence
from btf.johnson import Johnson

Models = Mapping[tuple[int, int], Johnson]
CLIPPED_REFERENCE = 0.01  # a reference with more of its pixels at a sensor limit understates the light


class RadiometryWarning(UserWarning):
    """A capture could not be normalised as asked (no reference, a clipped one); it is used as measured."""


def settings_json(s: CaptureSettings | None) -> dict[str, Any] | None:
    """A capture's settings as `decode`, `fit --json` and the report show them."""
    if s is None:
        return None
    return {"exposure_us": s.exposure_us, "gain": s.gain, "white_balance_kelvin": s.white_balance_kelvin,
            "white_balance_gains": None if s.white_balance_gains is None else list(s.white_balance_gains),
            "sensor_temperature_c": s.sensor_temperature_c, "unlocked": s.unlocked,
            "reference": None if s.reference is None else list(s.reference), "reference_clipped": s.reference_clipped,
            "brackets": list(s.brackets), "bracketed": {str(k): v for k, v in sorted(s.bracketed.items())},
            "source": s.source}


def describe(s: CaptureSettings | None) -> str:
    """One short line for a table cell."""
    if s is None:
        return ""
    parts = [] if s.exposure_us is None else [f"{s.exposure_us:g} us"]
    if s.gain is not None:
        parts.append(f"gain {s.gain:g}")
    if s.white_balance_kelvin is not None:
        parts.append(f"{s.white_balance_kelvin:g} K")
    elif s.white_balance_gains is not None:
        parts.append(f"wb {s.white_balance_gains[0]:g},{s.white_balance_gains[1]:g}")
    if s.sensor_temperature_c is not None:
        parts.append(f"{s.sensor_temperature_c:.1f} C")
    if s.reference is not None:
        parts.append("ref " + "/".join(f"{v:.1f}" for v in s.reference))
    if s.bracketed:
        parts.append("bracketed " + ", ".join(f"{lab}@{s.exposure_of(lab):g} us" for lab in sorted(s.bracketed)))
    if s.unlocked:
        parts.append("NOT LOCKED")
    return ", ".join(parts)


def check_space(space: str, what: str) -> None:
    if space not in LINEAR_SPACES:
        raise ValueError(f"{what} needs a feature space whose levels scale with exposure "
                         f"({', '.join(LINEAR_SPACES)}), not {space}")


def reference_target(cameras: Iterable[CaptureSettings | None]) -> tuple[float, ...] | None:
    """The median reference level per band over the captures whose reference is usable."""
    refs = [c.reference for c in cameras if usable_reference(c)]
    if not refs:
        return None
    return tuple(statistics.median(r[b] for r in refs) for b in range(len(refs[0])))


def usable_reference(c: CaptureSettings | None) -> bool:
    return (c is not None and c.reference is not None and c.reference_clipped <= CLIPPED_REFERENCE
            and all(v > 0 for v in c.reference))


def median_exposure(cameras: Iterable[CaptureSettings | None]) -> float | None:
    found = [c.exposure_us for c in cameras if c is not None and c.exposure_us is not None]
    return statistics.median(found) if found else None


def _factors(keys, camera: CaptureSettings | None, exposure_us: float | None, target: tuple[float, ...] | None,
             base_exposure_us: float | None, where: str) -> dict[tuple[int, int], float] | None:
    """{(label, band): factor} that brings each region to the capture's own exposure, then to the
    reference level `target`, then to `exposure_us`; None when the capture is used as it stands."""
    if camera is None or camera.exposure_us is None:
        if exposure_us is not None or target is not None:
            warnings.warn(f"{where}: no recorded exposure; used as measured", RadiometryWarning, stacklevel=3)
        return None
    band_factor: dict[int, float] = {}
    own = camera.exposure_us
    if target is not None:
        if usable_reference(camera) and len(camera.reference) == len(target):
            band_factor = {b: t / r for b, (t, r) in enumerate(zip(target, camera.reference))}
            own = base_exposure_us or own
        else:
            why = "no reference level" if camera.reference is None else "its reference is clipped or dark"
            warnings.warn(f"{where}: {why}; not normalised", RadiometryWarning, stacklevel=3)
    final = exposure_us if exposure_us is not None else own
    return {(label, band): camera.exposure_us / camera.exposure_of(label) * band_factor.get(band, 1.0) * final / own
            for label, band in keys}


def adjusted(models: Models, camera: CaptureSettings | None, exposure_us: float | None = None,
             target: tuple[float, ...] | None = None, base_exposure_us: float | None = None,
             where: str = "capture") -> Models:
    """`models` with every region at the capture's own exposure (bracketed regions scaled back),
    then normalised to the reference level `target` (when given), then scaled to `exposure_us`
    (from the capture's exposure, or from `base_exposure_us` after normalisation). A capture that
    cannot be treated as asked warns (RadiometryWarning) and is used as it stands."""
    factors = _factors(models, camera, exposure_us, target, base_exposure_us, where)
    return models if factors is None else {k: scaled(m, factors[k]) for k, m in models.items()}


def _sweep(captures: Mapping[Any, Any], normalise: bool) -> tuple[tuple[float, ...] | None, float | None]:
    cams = [c.camera for c in captures.values()]
    target = reference_target(cams) if normalise else None
    if normalise and target is None:
        raise ValueError("no capture carries a usable reference level: nothing to normalise by "
                         "(the robot records one with [camera] reference_label)")
    return target, (median_exposure(cams) if normalise else None)


def sweep_models(store: Any, captures: Mapping[Any, Any], exposure_us: float | None = None,
                 normalise: bool = False) -> dict[Any, dict[tuple[int, int], Johnson]]:
    """The models of `captures` (stored captures keyed by angle or direction), each region at
    its capture's exposure, or normalised to the captures' median reference level (at their
    median exposure) with `normalise`, then at `exposure_us` when given."""
    target, base = _sweep(captures, normalise)
    return {k: dict(adjusted({key: m.model for key, m in store.models(c.id).items()}, c.camera, exposure_us, target,
                             base, where=f"capture {c.sequence} of robot {c.robot}"))
            for k, c in captures.items()}


def sweep_dependence(store: Any, captures: Mapping[Any, Any], exposure_us: float | None = None,
                     normalise: bool = False) -> dict[Any, dict[int, Dependence]]:
    """The records of `captures` as `sweep_models` brings their models: each band's observed
    levels scaled by its model's factor (a side that reaches the sensor's limit stays open)."""
    target, base = _sweep(captures, normalise)
    out = {}
    for k, c in captures.items():
        deps = store.dependence(c.id)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RadiometryWarning)  # sweep_models said it already
            factors = _factors([(lab, b) for lab, d in deps.items() for b in range(d.n_bands)], c.camera,
                               exposure_us, target, base, "")
        out[k] = deps if factors is None else {lab: _scaled_levels(d, lab, factors, c.levels)
                                                for lab, d in deps.items()}
    return out


def _scaled_levels(dep: Dependence, label: int, factors: Mapping[tuple[int, int], float], levels: int) -> Dependence:
    if not dep.lo:
        return dep
    top = levels - 1
    lo = [min(top, int(math.floor(v * factors[(label, b)]))) for b, v in enumerate(dep.lo)]
    hi = [top if v >= top else min(top, int(math.ceil(v * factors[(label, b)]))) for b, v in enumerate(dep.hi)]
    return dep.with_levels(lo, [max(a, b) for a, b in zip(lo, hi)])


def reference_means(image: np.ndarray, mask: np.ndarray, label: int) -> np.ndarray:
    """Mean level per band of region `label` (ValueError when the mask has none of it)."""
    where = mask == label
    if not where.any():
        raise ValueError(f"the mask has no pixel of reference label {label}")
    pixels = image[where] if image.ndim == 3 else image[where][:, None]
    return pixels.mean(axis=0, dtype=np.float64)


def normalise_image(image: np.ndarray, factors: np.ndarray, levels: int, seed: int = 0,
                    rows: int = 256) -> None:
    """Scale each band of `image` in place by its factor, row tile by row tile. Levels are
    dithered (uniform within their step) before scaling, so the scaled histogram has no
    empty comb teeth; results are rounded and clipped to the sensor's levels."""
    rng = np.random.default_rng(seed)
    bands = image if image.ndim == 3 else image[..., None]
    f = np.asarray(factors, dtype=np.float32)
    for r0 in range(0, bands.shape[0], rows):
        tile = bands[r0:r0 + rows].astype(np.float32)
        tile += rng.random(tile.shape, dtype=np.float32) - np.float32(0.5)
        tile *= f
        np.rint(tile, out=tile)
        bands[r0:r0 + rows] = np.clip(tile, 0, levels - 1)
