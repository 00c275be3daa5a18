"""The light over the plate: its direction, cast shadows, and the shading of a surface.

Shading is the only step that depends on the light, so a surface (grain layout, height
field, normals, albedo) is built once and shaded once per light direction.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from hal.scene.materials import GREY_REFERENCE_EMISSIVITY, GREY_REFERENCE_HEAT_GAIN, MATERIALS, Label
from hal.scene.surface import Surface

AMBIENT = 0.12  # share of sky light that reaches every facet
AIR_KELVIN = 293.15
MIN_LIGHT_ELEVATION_DEG = 5.0  # lower, the shadow march would cross the plate many times


@dataclass(frozen=True, slots=True)
class LightAngles:
    """Direction toward the light in degrees: elevation above the horizon, azimuth clockwise from north."""

    elevation: float
    azimuth: float = 0.0


SUN = LightAngles(45.0, 225.0)  # the default: from the south-west, 45 degrees up


@dataclass(frozen=True, slots=True)
class Shading:
    """Light-dependent state of a surface, per flat cell."""

    radiance: np.ndarray  # (T*T, 5) float32, reflected light per spectral band, 0..1
    direct: np.ndarray  # (T*T,) float64, direct light on each facet, 0 in shadow


def check_light(light: LightAngles | None) -> LightAngles:
    """`light` validated, azimuth wrapped into [0, 360); None is the default sun."""
    if light is None:
        return SUN
    if not isinstance(light, LightAngles):
        raise ValueError(f"light must be LightAngles(elevation, azimuth), got {light!r}")
    if not (math.isfinite(light.elevation) and math.isfinite(light.azimuth)):
        raise ValueError(f"light angles must be finite, got {light}")
    if not MIN_LIGHT_ELEVATION_DEG <= light.elevation <= 90.0:
        raise ValueError(f"light elevation {light.elevation} outside {MIN_LIGHT_ELEVATION_DEG:g}..90 degrees")
    return LightAngles(float(light.elevation), float(light.azimuth) % 360.0)


def light_vector(light: LightAngles = SUN) -> np.ndarray:
    """Unit vector toward the light; x east, y north, z up."""
    az, el = math.radians(light.azimuth), math.radians(light.elevation)
    return np.array([math.cos(el) * math.sin(az), math.cos(el) * math.cos(az), math.sin(el)])


def lit(height: np.ndarray, light: LightAngles = SUN) -> np.ndarray:
    """False where the terrain toward the light rises above the light's ray (cast shadow)."""
    az, el = math.radians(light.azimuth), math.radians(light.elevation)
    rise = math.tan(el)
    steps = int(math.ceil(float(height.max() - height.min()) / rise)) + 1
    rows, cols = height.shape
    # the plate and its wrap-around `steps` cells deep: each step's cells are a view of it, not a copy
    wrapped = np.pad(height, steps, mode="wrap")
    out = np.ones(height.shape, bool)
    raised = np.empty_like(height)
    below = np.empty(height.shape, bool)
    for k in range(1, steps + 1):
        sx, sy = round(k * math.sin(az)), round(k * math.cos(az))
        ahead = wrapped[steps + sy:steps + sy + rows, steps + sx:steps + sx + cols]  # k steps toward the light
        np.add(height, k * rise, out=raised)
        np.less_equal(ahead, raised, out=below)
        out &= below
    return out


@lru_cache(maxsize=8)
def shade(surface: Surface, light: LightAngles = SUN) -> Shading:
    """Lambert plus ambient with cast shadows."""
    shadowless = lit(surface.height64, light).ravel()
    direct = np.clip(surface.normal @ light_vector(light), 0.0, None) * shadowless
    irradiance = AMBIENT + (1.0 - AMBIENT) * direct
    radiance = (surface.albedo * irradiance[:, None]).astype(np.float32)
    return Shading(radiance, direct)


@lru_cache(maxsize=4)
def thermal(surface: Surface, light: LightAngles = SUN) -> np.ndarray:
    """Brightness temperature per flat cell (float32 kelvin) from the light each facet absorbs."""
    direct = shade(surface, light).direct
    table = [MATERIALS[label] for label in Label if label in MATERIALS]
    emissivity = np.array([m.emissivity for m in table] + [GREY_REFERENCE_EMISSIVITY])[surface.label - 1]
    gain = np.array([m.heat_gain for m in table] + [GREY_REFERENCE_HEAT_GAIN])[surface.label - 1]
    absorbed = (1.0 - surface.albedo.mean(axis=1)) * direct
    return ((AIR_KELVIN + gain * absorbed) * emissivity**0.25).astype(np.float32)
