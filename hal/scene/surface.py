"""The sample's surface on a periodic ground grid: grain layout, height, normals, albedo.

Everything here is independent of the view and of the light, so one surface per
(scene, seed, size) is built once and cached; `hal.scene.light` shades it per light
direction and each view only projects it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from hal.scene.materials import GREY_REFERENCE_REFLECTANCE, GREY_REFERENCE_SIDE, MATERIALS, Label, Material, Shape

BLADE_POINTS = 8  # spheres along one grass blade


@dataclass(frozen=True, slots=True)
class Spheres:
    """Grains as (possibly flattened) spheres on the torus, with per-grain spectral albedo."""

    cx: np.ndarray
    cy: np.ndarray
    cz: np.ndarray
    r: np.ndarray
    flatten: np.ndarray
    albedo: np.ndarray  # (n, 5)

    def subset(self, keep: np.ndarray) -> Spheres:
        return Spheres(*(a[keep] for a in (self.cx, self.cy, self.cz, self.r, self.flatten, self.albedo)))


@dataclass(frozen=True, slots=True, eq=False)  # hashed by identity: a key of the shading cache
class Surface:
    """View- and light-independent state of the plate on a T x T periodic grid."""

    height: np.ndarray  # (T, T) float32, pixels
    height64: np.ndarray  # (T, T) float64, the same heights for the shadow march
    normal: np.ndarray  # (T*T, 3) unit surface normals
    albedo: np.ndarray  # (T*T, 5) per spectral band
    label: np.ndarray  # (T*T,) uint8

    @property
    def size(self) -> int:
        return self.height.shape[0]


@lru_cache(maxsize=4)
def _gaussian_filter(size: int, scale: float) -> np.ndarray:
    """Transfer function of the blob filter on the rfft2 grid (shared by a scene's several fields)."""
    f2 = np.fft.fftfreq(size)[:, None] ** 2 + np.fft.rfftfreq(size)[None, :] ** 2
    return np.exp(-2.0 * (math.pi * scale) ** 2 * f2)


def smooth_noise(rng: np.random.Generator, size: int, scale: float) -> np.ndarray:
    """Periodic Gaussian-filtered white noise, rescaled to 0..1; scale is the blob size in pixels."""
    white = rng.standard_normal((size, size), dtype=np.float32)
    # numpy's float64 transforms run several times faster than its float32 ones
    spectrum = np.fft.rfft2(white.astype(np.float64)) * _gaussian_filter(size, scale)
    field = np.fft.irfft2(spectrum, s=(size, size)).astype(np.float32)
    lo, hi = float(field.min()), float(field.max())
    return (field - lo) / max(hi - lo, 1e-12)


def _grain_albedo(m: Material, n: int, rng: np.random.Generator) -> np.ndarray:
    base = np.asarray(m.albedo)
    brightness = np.exp(m.albedo_sigma * rng.standard_normal(n))
    tint = np.exp(m.tint_sigma * rng.standard_normal((n, base.size)))
    albedo = base[None, :] * brightness[:, None] * tint
    if m.bright_fraction > 0:
        bright = rng.random(n) < m.bright_fraction
        albedo[bright] = m.bright_albedo * tint[bright]
    return np.clip(albedo, 0.01, 0.95)


def _grains(m: Material, size: int, scale: float, rng: np.random.Generator) -> Spheres:
    rm = m.radius * scale
    n = int(m.coverage * size * size / (math.pi * rm * rm * math.exp(2 * m.radius_sigma**2)))
    r = np.clip(rm * np.exp(m.radius_sigma * rng.standard_normal(n)), 0.35 * rm, 3.0 * rm)
    cx, cy = rng.uniform(0, size, n), rng.uniform(0, size, n)
    cz = rng.uniform(0.0, 0.6, n) * rm  # grains settle at different depths
    albedo = _grain_albedo(m, n, rng)
    if m.shape is Shape.CLODS:
        moisture = smooth_noise(rng, size, 12.0 * rm)
        wet = moisture[cy.astype(int) % size, cx.astype(int) % size]
        albedo *= (1.0 - 0.5 * wet)[:, None]  # water darkens soil
    return Spheres(cx, cy, cz, r, np.full(n, m.flatten), albedo)


def _blades(m: Material, size: int, scale: float, rng: np.random.Generator) -> Spheres:
    width = m.radius * scale
    k = BLADE_POINTS
    n = int(m.coverage * size * size / (2.0 * width * 14.0 * scale))
    lengths = 14.0 * scale * np.exp(0.25 * rng.standard_normal(n))
    lean = np.deg2rad(30.0) + np.deg2rad(25.0) * rng.standard_normal(n)  # mostly wind-bent one way
    rise = rng.uniform(0.3, 0.9, n)
    x0, y0 = rng.uniform(0, size, n), rng.uniform(0, size, n)
    t = np.linspace(0.0, 1.0, k)[None, :]
    cx = x0[:, None] + t * lengths[:, None] * np.cos(lean)[:, None]
    cy = y0[:, None] + t * lengths[:, None] * np.sin(lean)[:, None]
    cz = t * lengths[:, None] * rise[:, None]
    r = width * (1.0 - 0.5 * t) * np.exp(m.radius_sigma * rng.standard_normal(n))[:, None]
    albedo = np.repeat(_grain_albedo(m, n, rng), k, axis=0)
    return Spheres(cx.ravel(), cy.ravel(), cz.ravel(), r.ravel(), np.full(n * k, m.flatten), albedo)


def _splat(s: Spheres, size: int) -> np.ndarray:
    """Index of the sphere whose top is highest over each cell (flat, -1 where none)."""
    best = np.zeros(size * size, np.int64)
    reach = np.ceil(s.r).astype(np.int64)
    for rad in np.unique(reach):
        sel = np.flatnonzero(reach == rad)
        off = np.arange(-rad, rad + 1)
        ox, oy = (a.ravel() for a in np.meshgrid(off, off))
        # a cell's centre is within half a cell of its offset: corners beyond the radius never count
        near = (np.maximum(np.abs(ox) - 0.5, 0.0) ** 2 + np.maximum(np.abs(oy) - 0.5, 0.0) ** 2) < rad * rad
        ox, oy = ox[near], oy[near]
        bx, by = np.floor(s.cx[sel]), np.floor(s.cy[sel])
        # offsets from the grain centre in float32: sub-pixel accuracy is all a stamp needs
        fx = (bx + 0.5 - s.cx[sel]).astype(np.float32)[:, None] + ox.astype(np.float32)
        fy = (by + 0.5 - s.cy[sel]).astype(np.float32)[:, None] + oy.astype(np.float32)
        room = (s.r[sel] ** 2).astype(np.float32)[:, None] - fx * fx - fy * fy
        inside = room > 0
        cz, flat = s.cz[sel, None].astype(np.float32), s.flatten[sel, None].astype(np.float32)
        z = (cz + flat * np.sqrt(np.maximum(room, 0)))[inside]  # z >= 0: grains never sink below 0
        key = ((z * 256.0).astype(np.int64) << 32) | np.broadcast_to(sel[:, None] + 1, inside.shape)[inside]
        px = (bx.astype(np.int64)[:, None] + ox)[inside] % size
        py = (by.astype(np.int64)[:, None] + oy)[inside] % size
        np.maximum.at(best, py * size + px, key)
    return (best & 0xFFFFFFFF) - 1


def _geometry(s: Spheres, owner: np.ndarray, cells: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """Exact height and unit normal at the centres of `cells` (flat indices), from their owning sphere."""
    height = np.zeros(cells.size)
    normal = np.zeros((cells.size, 3))
    normal[:, 2] = 1.0
    o = owner[cells]
    covered = np.flatnonzero(o >= 0)
    o = o[covered]
    row, col = np.divmod(cells[covered], size)
    r, flat = s.r[o], s.flatten[o]
    half = size / 2.0
    dx = (col + 0.5 - s.cx[o] + half) % size - half
    dy = (row + 0.5 - s.cy[o] + half) % size - half
    q = np.sqrt(np.maximum(r**2 - dx * dx - dy * dy, 0.0))
    height[covered] = s.cz[o] + flat * q
    qs = np.maximum(q, 0.05 * r)  # rim of a sphere: steep but finite slope
    nx, ny = flat * dx / qs, flat * dy / qs
    length = np.sqrt(nx * nx + ny * ny + 1.0)
    normal[covered] = np.stack([nx / length, ny / length, 1.0 / length], axis=1)
    return height, normal


def scene_labels(scene: str, size: int, scale: float, rng: np.random.Generator) -> np.ndarray:
    """Which material covers each cell of the torus, (T, T) uint8."""
    if scene == "black":
        return np.full((size, size), Label.BLACK_SAND, np.uint8)
    if scene == "white":
        return np.full((size, size), Label.WHITE_SAND, np.uint8)
    if scene == "mixed":
        labels = np.full((size, size), Label.WHITE_SAND, np.uint8)
        labels[:, : size // 2] = Label.BLACK_SAND  # west half; the view's left at azimuth 0
        return labels
    if scene == "field":
        kinds = (Label.TAN_SAND, Label.GRASS, Label.SOIL, Label.GRAVEL)
        fields = np.stack([smooth_noise(rng, size, 0.08 * size) for _ in kinds])
        # a little fine noise roughens the patch borders
        fields += 0.08 * np.stack([smooth_noise(rng, size, 3.0 * scale) for _ in kinds])
        return np.asarray(kinds, np.uint8)[np.argmax(fields, axis=0)]
    raise ValueError(f"unknown scene {scene!r}")


def _near(labels: np.ndarray, s: Spheres, label: int, reach: float) -> np.ndarray:
    """Spheres whose footprint may touch cells of `label` (centre or a point `reach` away)."""
    size = labels.shape[0]
    keep = np.zeros(s.cx.size, bool)
    for ox, oy in ((0, 0), (reach, 0), (-reach, 0), (0, reach), (0, -reach)):
        ix = np.floor(s.cx + ox).astype(np.int64) % size
        iy = np.floor(s.cy + oy).astype(np.int64) % size
        keep |= labels[iy, ix] == label
    return keep


@lru_cache(maxsize=4)
def build_surface(scene: str, seed: int, size: int, scale: float, reference: bool = False) -> Surface:
    """The plate for `scene` on a size x size torus; each material draws from its own stream.

    A material's grains come from a generator seeded by (seed, label) only, so the black
    half of the mixed plate is the same realisation as the black plate. With `reference`,
    the grey card lies on the same plate (`with_reference`).
    """
    if reference:
        return with_reference(build_surface(scene, seed, size, scale))
    labels = scene_labels(scene, size, scale, np.random.default_rng([seed, 0]))
    flat_labels = labels.ravel()
    height = np.zeros(size * size)
    normal = np.zeros((size * size, 3))
    albedo = np.zeros((size * size, 5))
    kinds = np.unique(labels)
    for label in kinds:
        m = MATERIALS[Label(int(label))]
        rng = np.random.default_rng([seed, int(label)])
        spheres = _blades(m, size, scale, rng) if m.shape is Shape.BLADES else _grains(m, size, scale, rng)
        if kinds.size > 1:
            spheres = spheres.subset(_near(labels, spheres, int(label), float(spheres.r.max()) + 1.0))
            cells = np.flatnonzero(flat_labels == label)
        else:
            cells = np.arange(size * size)
        owner = _splat(spheres, size)
        o = owner[cells]
        grain_albedo = np.where((o >= 0)[:, None], spheres.albedo[np.maximum(o, 0)], np.asarray(m.substrate))
        if kinds.size > 1:
            height[cells], normal[cells] = _geometry(spheres, owner, cells, size)
            albedo[cells] = grain_albedo
        else:  # one material covers the plate: no scatter into the full arrays
            height, normal = _geometry(spheres, owner, cells, size)
            albedo = grain_albedo
    height = height.reshape(size, size)
    return Surface(height.astype(np.float32), height, normal, albedo, flat_labels.copy())


def with_reference(plate: Surface) -> Surface:
    """`plate` with the grey reference card at its centre: a level square resting on the
    highest grains (nothing hides it, it casts a shadow), facing straight up."""
    size = plate.size
    side = max(2, round(GREY_REFERENCE_SIDE * size))
    lo = (size - side) // 2
    card = np.zeros((size, size), bool)
    card[lo:lo + side, lo:lo + side] = True
    cells = np.flatnonzero(card)
    height = plate.height64.copy()
    height[card] = float(height.max()) + 0.5
    normal, albedo, label = plate.normal.copy(), plate.albedo.copy(), plate.label.copy()
    normal[cells] = (0.0, 0.0, 1.0)
    albedo[cells] = GREY_REFERENCE_REFLECTANCE
    label[cells] = Label.GREY_REFERENCE
    return Surface(height.astype(np.float32), height, normal, albedo, label)
