"""A physically motivated renderer of sand, grass, soil and gravel plates.

Grains are hemispheres on a height field with lognormal radii and per-grain albedo,
lit from a light direction (Lambert plus ambient) with cast shadows marched over the
height field; the default light is the sun from the south-west, 45 degrees up (`SUN`).
A view is an orthographic camera at (elevation, azimuth): the ground is compressed by
sin(elevation) along the view azimuth and nearer grains hide what lies behind them,
so the pixel statistics change with the view.

Outputs of `render`:
- bands="rgb": image H x W x 3 uint8, RGB order.
- bands="multispectral": image H x W x 6 uint16; channels 0..4 are the spectral bands
  blue, green, red, red edge, near infrared in 0..255 (8-bit range); channel 5 is
  thermal brightness temperature in centikelvin (29315 = 20 degrees C).
- mask: H x W uint8 material label per pixel, ids in `LABEL_NAMES`
  (1 black sand, 2 white sand, 3 tan sand, 4 grass, 5 soil, 6 gravel).

Scenes: "black", "white", "mixed" (west half black, east half white: the view's left
and right at azimuth 0), "field" (irregular patches of tan sand, grass, soil, gravel).
Geometry: x east, y north, azimuth clockwise from north; at azimuth 0 the image's top
is north and its columns run west to east. One pixel of a nadir view is one grid cell.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hal.interfaces import ViewAngles
from hal.scene.light import SUN, LightAngles, check_light, shade, thermal
from hal.scene.materials import BAND_NAMES, LABEL_NAMES, REFERENCE_SIZE, Label
from hal.scene.surface import Surface, build_surface

__all__ = ["BAND_NAMES", "BANDS", "LABEL_NAMES", "Label", "LightAngles", "RenderedView", "SCENES", "SUN",
           "render"]

SCENES: tuple[str, ...] = ("black", "white", "mixed", "field")
BANDS: tuple[str, ...] = ("rgb", "multispectral")
MIN_ELEVATION_DEG = 5.0
MIN_GRAIN_PIXELS = 1.0  # below this grains are rendered finer and averaged down
MAX_SUPERSAMPLE = 4
READ_NOISE_DN = 0.8
THERMAL_NOISE_CK = 5.0  # 0.05 K, a good microbolometer


@dataclass(frozen=True, slots=True)
class RenderedView:
    image: np.ndarray
    mask: np.ndarray
    scene: str
    view: ViewAngles
    bands: str
    light: LightAngles = SUN


def _check(scene: str, view: ViewAngles, size: tuple[int, int], bands: str) -> tuple[int, int]:
    if scene not in SCENES:
        raise ValueError(f"unknown scene {scene!r}; choose from {', '.join(SCENES)}")
    if bands not in BANDS:
        raise ValueError(f"unknown bands {bands!r}; choose from {', '.join(BANDS)}")
    if not (math.isfinite(view.elevation) and math.isfinite(view.azimuth)):
        raise ValueError(f"view angles must be finite, got {view}")
    if not MIN_ELEVATION_DEG <= view.elevation <= 90.0:
        raise ValueError(f"elevation {view.elevation} outside {MIN_ELEVATION_DEG}..90 degrees")
    try:
        h, w = (int(v) for v in size)
    except (TypeError, ValueError):
        raise ValueError(f"size must be (height, width), got {size!r}") from None
    if not (8 <= h <= 8192 and 8 <= w <= 8192):
        raise ValueError(f"size {h}x{w} outside 8..8192 pixels per side")
    return h, w


def _visible(surface: Surface, view: ViewAngles, h: int, w: int) -> np.ndarray:
    """Flat surface index seen by each pixel (h, w): first terrain hit along each ray."""
    size = surface.size
    el, az = math.radians(view.elevation), math.radians(view.azimuth % 360.0)
    se, ce = math.sin(el), math.cos(el)
    if view.elevation >= 90.0:
        se, ce = 1.0, 0.0
    zmax = float(surface.height.max())
    xs = np.arange(w) - w / 2.0 + 0.5  # lateral, along the image rows
    # ground from below the frame's near edge (tall near grains reach into it) to the far edge
    ys = np.arange((-h / 2.0 - zmax * ce) / se - 2.0, (h / 2.0) / se + 2.0, 1.0)
    fx, fy, rx, ry = math.sin(az), math.cos(az), math.cos(az), -math.sin(az)
    half = size / 2.0
    ix = np.floor(xs[None, :] * rx + ys[:, None] * fx + half).astype(np.int64) % size
    iy = np.floor(xs[None, :] * ry + ys[:, None] * fy + half).astype(np.int64) % size
    cells = iy * size + ix  # (ny, w), near to far
    # image-plane height of each ground sample; a sample is seen once it tops all nearer ones
    s = ys[:, None] * se + surface.height.ravel()[cells] * ce
    reach = np.maximum.accumulate(s, axis=0).T  # (w, ny), non-decreasing per column
    ny = reach.shape[1]
    lo = float(reach.min())
    span = float(reach.max()) - lo + 1.0
    offset = (np.arange(w) * span)[:, None]
    targets = h / 2.0 - np.arange(h)[::-1] - 0.5  # image rows bottom to top
    k = np.searchsorted((reach - lo + offset).ravel(), (targets[None, :] - lo + offset).ravel())
    k = np.clip(k.reshape(w, h) - (np.arange(w) * ny)[:, None], 0, ny - 1)
    return cells[k.T[::-1], np.arange(w)[None, :]]


def render(scene: str, view: ViewAngles, size: tuple[int, int] = (480, 640), seed: int = 0,
           bands: str = "rgb", light: LightAngles | None = None) -> RenderedView:
    """Render `scene` seen from `view` at `size` = (height, width), lit from `light` (None: `SUN`).

    Deterministic per seed; the grain layout is shared by every view and light of a seed.
    """
    h, w = _check(scene, view, size, bands)
    light = check_light(light)
    long_side = max(h, w)
    scale = long_side / REFERENCE_SIZE
    ss = min(MAX_SUPERSAMPLE, max(1, math.ceil(MIN_GRAIN_PIXELS / (1.1 * scale))))
    surface = build_surface(scene, int(seed), long_side * ss, scale * ss)
    shading = shade(surface, light)
    cells = _visible(surface, view, h * ss, w * ss)
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, round(view.elevation * 1000),
                                 round(view.azimuth % 360.0 * 1000), 1])
    center = cells[ss // 2::ss, ss // 2::ss]
    mask = surface.label[center]
    if bands == "rgb":
        radiance = shading.rgb[cells]
    else:
        radiance = shading.radiance[cells]
    if ss > 1:
        radiance = radiance.reshape(h, ss, w, ss, -1).mean(axis=(1, 3))
    dn = radiance * 255.0 + rng.normal(0.0, READ_NOISE_DN, radiance.shape)
    dn = np.clip(np.rint(dn), 0, 255)
    if bands == "rgb":
        return RenderedView(dn.astype(np.uint8), mask, scene, view, bands, light)
    kelvin = thermal(surface, light)[cells]
    if ss > 1:
        kelvin = kelvin.reshape(h, ss, w, ss).mean(axis=(1, 3))
    ck = np.clip(np.rint(kelvin * 100.0 + rng.normal(0.0, THERMAL_NOISE_CK, kelvin.shape)), 0, 65535)
    image = np.concatenate([dn, ck[..., None]], axis=2).astype(np.uint16)
    return RenderedView(image, mask, scene, view, bands, light)
