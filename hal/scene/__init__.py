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
  (1 black sand, 2 white sand, 3 tan sand, 4 grass, 5 soil, 6 gravel, 7 grey reference).

Any scene can hold a grey reference card (`reference=True`): a flat, spectrally grey
patch of known reflectance (`GREY_REFERENCE_REFLECTANCE`) lying level on the grains at the
plate's centre, so it is in every view; its level follows the light and the exposure, not
the view, which is what drift normalisation needs.

Scenes: "black", "white", "mixed" (west half black, east half white: the view's left
and right at azimuth 0), "field" (irregular patches of tan sand, grass, soil, gravel).
Geometry: x east, y north, azimuth clockwise from north; at azimuth 0 the image's top
is north and its columns run west to east. One pixel of a nadir view is one grid cell.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from hal.interfaces import ViewAngles
from hal.scene.light import SUN, LightAngles, check_light, shade, thermal
from hal.scene.materials import BAND_NAMES, GREY_REFERENCE_REFLECTANCE, LABEL_NAMES, REFERENCE_SIZE, Label
from hal.scene.projection import PaddedPlate, seen_cells
from hal.scene.sensor import clipped_mean, digitise, gather
from hal.scene.surface import Surface, build_surface

__all__ = ["BAND_NAMES", "BANDS", "GREY_REFERENCE_REFLECTANCE", "LABEL_NAMES", "Label", "LightAngles",
           "RenderedView", "SCENES", "SUN", "SceneRadiance", "render", "scene_radiance"]

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


@lru_cache(maxsize=4)
def _padded(surface: Surface) -> PaddedPlate:
    """The surface's heights as the projection reads them, once per surface."""
    return PaddedPlate.of(surface.height)


@lru_cache(maxsize=2)
def _colour_table(surface: Surface, light: LightAngles) -> np.ndarray:
    """Per padded cell its red, green and blue radiance and its label: the 16-byte row an rgb
    pixel needs, read in one gather (once per surface and light)."""
    plate = _padded(surface)
    table = np.empty((plate.cell.size, 4), np.float32)
    table[:, :3] = gather(np.ascontiguousarray(shade(surface, light).radiance[:, (2, 1, 0)]), plate.cell)
    table[:, 3] = gather(surface.label, plate.cell)
    return table


def _block_mean(image: np.ndarray, ss: int) -> np.ndarray:
    """The mean of each ss x ss block of an (H ss, W ss, ...) image: ss^2 whole-image sums,
    several times faster than numpy's mean over the block axes."""
    total = np.zeros((image.shape[0] // ss, image.shape[1] // ss, *image.shape[2:]), np.float32)
    for dy in range(ss):
        for dx in range(ss):
            total += image[dy::ss, dx::ss]
    total *= np.float32(1.0 / (ss * ss))
    return total


@dataclass(frozen=True, slots=True)
class SceneRadiance:
    """The light reaching each pixel of a view before the camera turns it into numbers.

    `radiance` is H x W x B float32 (1.0 fills an 8-bit pixel at the reference exposure);
    `kelvin` the thermal band (multispectral only). `expose` makes the image, so a camera
    can meter (`metered_mean`) before it chooses an exposure, as auto exposure does.
    """

    radiance: np.ndarray
    kelvin: np.ndarray | None
    mask: np.ndarray
    scene: str
    view: ViewAngles
    bands: str
    light: LightAngles
    noise_seed: tuple[int, ...]

    def band_factors(self, exposure: float, gain: float, white_balance: tuple[float, float]) -> np.ndarray:
        """Radiance-to-DN multiplier per band: exposure and gain on all, the white balance on red and blue."""
        factors = np.full(self.radiance.shape[-1], 255.0 * exposure * gain)
        red, blue = (0, 2) if self.bands == "rgb" else (2, 0)
        factors[red] *= white_balance[0]
        factors[blue] *= white_balance[1]
        return factors

    def metered_mean(self, exposure: float = 1.0, gain: float = 1.0,
                     white_balance: tuple[float, float] = (1.0, 1.0)) -> np.ndarray:
        """Mean level per band of the noise-free image at these settings (clipped like the sensor)."""
        return clipped_mean(self.radiance, self.band_factors(exposure, gain, white_balance), 255.0)

    def expose(self, exposure: float = 1.0, gain: float = 1.0,
               white_balance: tuple[float, float] = (1.0, 1.0)) -> RenderedView:
        """The image at `exposure` (relative to the reference, 10 ms) and analogue `gain`; read
        noise is amplified by the gain. At (1, 1, (1, 1)) this is exactly `render`'s image."""
        _check_exposure(exposure, gain, white_balance)
        rng = np.random.default_rng(list(self.noise_seed))
        factors = self.band_factors(exposure, gain, white_balance)
        if self.bands == "rgb":
            image = digitise(self.radiance, factors, READ_NOISE_DN * gain, 255, rng, np.uint8)
            return RenderedView(image, self.mask, self.scene, self.view, self.bands, self.light)
        spectral = digitise(self.radiance, factors, READ_NOISE_DN * gain, 255, rng, np.uint16)
        thermal_ck = digitise(self.kelvin[..., None], (100.0,), THERMAL_NOISE_CK, 65535, rng, np.uint16)
        image = np.concatenate([spectral, thermal_ck], axis=2)
        return RenderedView(image, self.mask, self.scene, self.view, self.bands, self.light)


def _check_exposure(exposure: float, gain: float, white_balance: tuple[float, float]) -> None:
    values = (exposure, gain, *white_balance)
    if len(values) != 4 or not all(math.isfinite(v) and v > 0 for v in values):
        raise ValueError(f"exposure, gain and white balance must be positive and finite, "
                         f"got {exposure}, {gain}, {white_balance}")


def scene_radiance(scene: str, view: ViewAngles, size: tuple[int, int] = (480, 640), seed: int = 0,
                   bands: str = "rgb", light: LightAngles | None = None, reference: bool = False) -> SceneRadiance:
    """What `render` sees before exposure: the view's radiance, mask and noise stream."""
    h, w = _check(scene, view, size, bands)
    light = check_light(light)
    long_side = max(h, w)
    scale = long_side / REFERENCE_SIZE
    ss = min(MAX_SUPERSAMPLE, max(1, math.ceil(MIN_GRAIN_PIXELS / (1.1 * scale))))
    surface = build_surface(scene, int(seed), long_side * ss, scale * ss, bool(reference))
    plate = _padded(surface)
    seen = seen_cells(plate, view, h * ss, w * ss)
    noise_seed = (int(seed) & 0xFFFFFFFF, round(view.elevation * 1000), round(view.azimuth % 360.0 * 1000), 1)
    centres = (slice(ss // 2, None, ss), slice(ss // 2, None, ss))  # the sample a supersampled pixel is labelled by
    kelvin = None
    if bands == "rgb":
        rows = gather(_colour_table(surface, light), seen)
        mask = rows[centres][..., 3].astype(np.uint8)
        radiance = (_block_mean(rows, ss) if ss > 1 else rows)[..., :3]
    else:
        cells = gather(plate.cell, seen)
        mask = gather(surface.label, cells[centres])
        radiance = gather(shade(surface, light).radiance, cells)
        kelvin = gather(thermal(surface, light), cells)
        if ss > 1:
            radiance, kelvin = _block_mean(radiance, ss), _block_mean(kelvin, ss)
    return SceneRadiance(radiance, kelvin, mask, scene, view, bands, light, noise_seed)


def render(scene: str, view: ViewAngles, size: tuple[int, int] = (480, 640), seed: int = 0,
           bands: str = "rgb", light: LightAngles | None = None, exposure: float = 1.0, gain: float = 1.0,
           white_balance: tuple[float, float] = (1.0, 1.0), reference: bool = False) -> RenderedView:
    """Render `scene` seen from `view` at `size` = (height, width), lit from `light` (None: `SUN`).

    `exposure` is relative to the reference exposure (10 ms: a pixel of radiance 1.0 fills
    255), `gain` the analogue gain, `white_balance` the (red, blue) gains; more exposure is a
    brighter image that saturates sooner. `reference` lays the grey reference card at the
    plate's centre (label `Label.GREY_REFERENCE`). Deterministic per seed; the grain layout
    is shared by every view, light and exposure of a seed.
    """
    _check_exposure(exposure, gain, white_balance)
    return scene_radiance(scene, view, size, seed, bands, light, reference).expose(exposure, gain, white_balance)
