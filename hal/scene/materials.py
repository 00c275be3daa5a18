"""Clutter materials: label ids, spectral albedo and grain geometry.

Spectral bands follow a five-band field multispectral camera:
blue 475 nm, green 560 nm, red 668 nm, red edge 717 nm, near infrared 842 nm.
Sizes are in pixels at the reference resolution (640 px on the long side).
"""
from __future__ import annotations

from dataclasses import dataclass
from enum import Enum, IntEnum


class Label(IntEnum):
    """Ground-truth clutter type per pixel in a rendered mask (0 is never used)."""

    BLACK_SAND = 1
    WHITE_SAND = 2
    TAN_SAND = 3
    GRASS = 4
    SOIL = 5
    GRAVEL = 6
    GREY_REFERENCE = 7  # the grey reference card, not a clutter material


class Shape(Enum):
    GRAINS = "grains"  # hemispheres with lognormal radii
    CLODS = "clods"  # flattened hemispheres, albedo darkened by moisture
    BLADES = "blades"  # chains of thin spheres rising from root to tip


BAND_NAMES: tuple[str, ...] = ("blue", "green", "red", "red_edge", "nir")
REFERENCE_SIZE = 640
# The grey reference card: a flat, spectrally neutral diffuse target (an 18% grey card: it stays unclipped where auto exposure brightens black sand six times).
GREY_REFERENCE_REFLECTANCE = 0.18
GREY_REFERENCE_SIDE = 0.12  # side of the square card, share of the plate's side
GREY_REFERENCE_EMISSIVITY = 0.95
GREY_REFERENCE_HEAT_GAIN = 20.0


@dataclass(frozen=True, slots=True)
class Material:
    label: Label
    shape: Shape
    albedo: tuple[float, float, float, float, float]  # median per spectral band
    albedo_sigma: float  # per-grain lognormal spread of brightness
    tint_sigma: float  # per-grain, per-band lognormal spread (colour variation)
    radius: float  # median radius, reference pixels
    radius_sigma: float
    flatten: float  # height / radius of a grain
    coverage: float  # summed grain footprint area / plate area
    substrate: tuple[float, float, float, float, float]  # albedo showing in the gaps
    bright_fraction: float = 0.0  # share of bright accessory grains (e.g. quartz in basalt)
    bright_albedo: float = 0.0
    emissivity: float = 0.95
    heat_gain: float = 25.0  # kelvin of warming at full absorbed sunlight


MATERIALS: dict[Label, Material] = {
    Label.BLACK_SAND: Material(
        Label.BLACK_SAND, Shape.GRAINS, (0.070, 0.074, 0.079, 0.083, 0.088), 0.25, 0.04,
        2.2, 0.35, 1.0, 2.4, (0.05, 0.05, 0.055, 0.06, 0.06),
        bright_fraction=0.05, bright_albedo=0.45, emissivity=0.96, heat_gain=30.0),
    Label.WHITE_SAND: Material(
        Label.WHITE_SAND, Shape.GRAINS, (0.60, 0.66, 0.70, 0.72, 0.74), 0.10, 0.03,
        2.2, 0.35, 1.0, 2.4, (0.45, 0.50, 0.53, 0.55, 0.56), emissivity=0.92, heat_gain=30.0),
    Label.TAN_SAND: Material(
        Label.TAN_SAND, Shape.GRAINS, (0.24, 0.32, 0.42, 0.46, 0.50), 0.15, 0.05,
        2.0, 0.35, 1.0, 2.4, (0.18, 0.24, 0.31, 0.34, 0.37), emissivity=0.93, heat_gain=30.0),
    Label.GRASS: Material(
        Label.GRASS, Shape.BLADES, (0.050, 0.160, 0.070, 0.32, 0.52), 0.20, 0.12,
        1.1, 0.15, 1.0, 2.2, (0.08, 0.11, 0.15, 0.18, 0.22), emissivity=0.98, heat_gain=8.0),
    Label.SOIL: Material(
        Label.SOIL, Shape.CLODS, (0.09, 0.12, 0.16, 0.19, 0.23), 0.15, 0.04,
        4.5, 0.45, 0.6, 1.8, (0.06, 0.08, 0.11, 0.13, 0.16), emissivity=0.95, heat_gain=22.0),
    Label.GRAVEL: Material(
        Label.GRAVEL, Shape.GRAINS, (0.20, 0.21, 0.22, 0.23, 0.24), 0.30, 0.06,
        7.0, 0.30, 0.7, 1.1, (0.24, 0.32, 0.42, 0.46, 0.50), emissivity=0.94, heat_gain=26.0),
}

LABEL_NAMES: dict[int, str] = {int(label): label.name.lower() for label in Label}
