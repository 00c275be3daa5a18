"""Synthetic images from a label mask and Johnson models, at measured and unseen angles.

Every pixel is a level its region took: each band's model is drawn truncated to the region's
observed levels (tools.analysis.levelmap) when its record carries them. A region whose record
carries its grain and band correlation is drawn as correlated fields (tools.analysis.fields),
the others pixel by pixel.

Between two measured angles the models are blended in quantile space: one normal
deviate z per pixel and band, mapped through both neighbours' quantile functions
x_of_z and mixed by angle weight. For one-dimensional distributions that is the
optimal-transport (displacement) interpolation; it stays valid when the Johnson
family differs between the two angles, where blending raw parameters is not.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Callable, Mapping, Protocol

import numpy as np

from btf.dependence import Dependence
from btf.johnson import Johnson
from tools.analysis import tiles
from tools.analysis.fields import Grain, blend, draw, grain_of, index_units, remix
from tools.analysis.latent import corrected
from tools.analysis.levelmap import LevelMap, level_map, quantile, uniform_table, z_bits, z_table
from tools.analysis.tiles import (
    Draws,
    Region,
    in_parallel,
    label_counts,
    one_blas_thread,
    region,
    split_rows,
    streams,
    threads,
)

Models = Mapping[tuple[int, int], Johnson]
Dependences = Mapping[int, Dependence]  # per label; labels without one are drawn independently
REACH = 0.05  # a band correlation missed by more than this is named in a warning
CHECKED = 1 << 16  # pixels of a draw whose band correlation is checked against the measured one
TOLERANCE = 0.01  # a draw's band correlation further than this from the measured one is corrected


class MissingModels(ValueError):
    """Mask labels with no model; the message lists them."""


class ExtrapolationWarning(UserWarning):
    """The requested angle lies outside the measured range; the nearest angle was used."""


class ReachWarning(UserWarning):
    """A measured band correlation lies beyond what the region's models can reproduce."""


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
        partial = [lab for lab in missing if lab in have]
        if partial:  # a label with models of some bands only
            lack = [b for b in range(n_bands) if (partial[0], b) not in models]
            raise MissingModels(f"label {partial[0]} has no model of band(s) {lack}{where} "
                                f"(each label needs all {n_bands} bands' models)")
        raise MissingModels(
            f"mask label(s) {missing} have no models{where} (models exist for labels {have})"
        )
    return labels


def _output(mask: np.ndarray, n_bands: int, levels: int) -> np.ndarray:
    if mask.ndim != 2:
        raise ValueError(f"mask must be H x W, got shape {mask.shape}")
    return np.zeros(mask.shape + (n_bands,), dtype=np.uint8 if levels <= 256 else np.uint16)


def _record(deps: Dependences | None, label: int, n_bands: int) -> Dependence | None:
    dep = (deps or {}).get(label)
    return dep if dep is not None and dep.n_bands == n_bands else None


def band_maps(models: Models, label: int, n_bands: int, levels: int, dep: Dependence | None) -> tuple[LevelMap, ...]:
    """Each band's z -> level map, truncated to the region's observed levels when known."""
    return tuple(level_map(models[(label, b)], levels, *(dep.levels(b) if dep is not None and dep.lo else (0,)))
                 for b in range(n_bands))


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
               dependence: Dependences | None = None, independent: bool = False) -> np.ndarray:
    """An H x W x B image: each region's pixels drawn from its models within its observed
    levels, with the region's grain and band correlation (correlated fields) when its record
    has them and not `independent`, else pixel by pixel. Works region by region in row tiles:
    beyond the mask and the image it holds a region's fields (B float32 per pixel of its box)
    or a few tiles, and a few small regions' fields at once where they are drawn on threads."""
    n_bands = _bands(models)
    out = _output(mask, n_bands, levels)
    missed: list[str] = []
    correlated: list[_Correlated] = []
    for label in _check(mask, models, n_bands):
        where = region(mask, label)
        dep = _record(dependence, label, n_bands)
        maps = band_maps(models, label, n_bands, levels, dep)
        if dep is not None and dep.measured and not independent and where.count:
            grain = grain_of(dep, maps)
            missed += _missed(label, dep, grain)
            # a stream per region: a seed gives one image however the regions share the threads
            correlated.append(_Correlated(where, maps, grain, streams(rng, 1)[0], dep.matrix()))
        else:
            for b, m in enumerate(maps):
                fill(out, b, mask, where, _from_stream(Draws(_independent(m, rng, levels), where.count)))
    _fill_all(out, mask, correlated, levels)
    if missed:
        warnings.warn("band correlation beyond what the models can reach: " + "; ".join(missed)
                      + " (the observed levels of the bands cannot couple closer)", ReachWarning, stacklevel=2)
    return out


@dataclass(frozen=True, eq=False)
class _Correlated:
    """A region to be drawn as correlated fields, with its own random stream."""

    where: Region
    maps: tuple[LevelMap, ...]
    grain: Grain
    rng: np.random.Generator
    measured: np.ndarray

    @property
    def box(self) -> int:
        return (self.where.rows.stop - self.where.rows.start) * (self.where.cols.stop - self.where.cols.start)


def _fill_all(out: np.ndarray, mask: np.ndarray, regions: list[_Correlated], levels: int) -> None:
    """Large regions one after another, each spread over the threads; small ones (whose own
    transforms are too short to share) a whole region per thread, largest first."""
    def one(r: _Correlated) -> None:
        _fill_correlated(out, mask, r.where, r.maps, r.grain, r.rng, levels, r.measured)

    small = sorted((r for r in regions if r.box < tiles.PARALLEL_PIXELS), key=lambda r: -r.box)
    for r in regions:
        if r.box >= tiles.PARALLEL_PIXELS:
            one(r)
    with one_blas_thread():
        in_parallel(lambda i: one(small[i]), len(small), sum(r.box for r in small))


def _missed(label: int, dep: Dependence, grain: Grain) -> list[str]:
    want, got = dep.matrix(), grain.reached
    return [f"label {label} bands {i}-{j} {want[i, j]:.2f}, at most {got[i, j]:.2f}"
            for i, j in zip(*np.triu_indices(len(want), 1)) if abs(want[i, j] - got[i, j]) > REACH]


def _independent(m: LevelMap, rng: np.random.Generator, levels: int) -> Callable[[int], np.ndarray]:
    """Independent pixels of a map: uniform 16-bit draws through its table (8-bit sensors), or
    normal draws through its z table (deeper ones)."""
    if levels <= 256:
        table = uniform_table(m)
        return lambda size: table.take(np.frombuffer(rng.bytes(2 * size), dtype=np.uint16))
    bits = z_bits(levels)
    table, (scale, offset) = z_table(m, bits), index_units(bits)
    return lambda size: table.take((rng.standard_normal(size, dtype=np.float32) * np.float32(scale)
                                    + np.float32(offset)).astype(np.intp), mode="clip")


def _drawn_corr(fields: list[np.ndarray], tables: list[np.ndarray], inside: np.ndarray | None) -> np.ndarray:
    """The band correlation of a draw's pixels, on a lattice of about CHECKED of them."""
    h, w = fields[0].shape
    # about CHECKED of the region's own pixels: a lattice over the box would thin out a region
    # that fills a third of it, and check every pixel of a small box that it fills
    count = h * w if inside is None else int(np.count_nonzero(inside))
    step = max(1, round(np.sqrt(count / CHECKED)))
    if inside is not None and np.count_nonzero(inside[::step, ::step]) < 2:
        step = 1  # a region the lattice misses (every other row, say) is read whole
    keep = None if inside is None else inside[::step, ::step]
    cols = None
    for b, (f, table) in enumerate(zip(fields, tables)):
        sub = f[::step, ::step] if keep is None else f[::step, ::step][keep]
        levels = table.take(sub.astype(np.intp).ravel(), mode="clip")
        if cols is None:
            cols = np.empty((len(fields), levels.size), np.float32)
        cols[b] = levels
    # float32 products of centred levels: off by about 1e-5, against a tolerance of TOLERANCE
    cols -= cols.mean(axis=1, keepdims=True)
    cov = (cols @ cols.T).astype(np.float64)
    sd = np.sqrt(np.diag(cov))
    with np.errstate(all="ignore"):
        return np.nan_to_num(cov / np.outer(sd, sd))


def region_fields(grain: Grain, maps: tuple[LevelMap, ...], measured: np.ndarray, shape: tuple[int, int],
                  inside: np.ndarray | None, rng: np.random.Generator, levels: int) -> list[np.ndarray]:
    """A region's fields in the index units of its bands' z tables (fields.draw); a draw whose
    pixels' band correlation strays from the measured one is corrected once (latent.corrected)."""
    bits = z_bits(levels)
    scale, offset = index_units(bits)
    fields = draw(grain, shape, rng, scale, offset, inside=inside)
    if len(maps) > 1:
        drawn = _drawn_corr(fields, [z_table(m, bits) for m in maps], inside)
        live = np.array([m.sd > 0 for m in maps])
        miss = np.abs(drawn - measured)[np.ix_(live, live)]
        if miss.size and miss.max() > TOLERANCE:
            remix(fields, grain.latent, corrected(grain.latent, measured, drawn, list(maps), REACH), offset,
                  least_mixing=len(grain.rings) > 1)
    return fields


def _fill_correlated(out: np.ndarray, mask: np.ndarray, where: Region, maps: tuple[LevelMap, ...],
                     grain: Grain, rng: np.random.Generator, levels: int, measured: np.ndarray) -> None:
    """A region from its fields: one table lookup per pixel and band, the region's tiles found
    once for all bands."""
    h, w = where.rows.stop - where.rows.start, where.cols.stop - where.cols.start
    inside = None if where.count == h * w else mask[where.rows, where.cols] == where.label
    fields = region_fields(grain, maps, measured, (h, w), inside, rng, levels)
    tables = [z_table(m, z_bits(levels)) for m in maps]
    r0 = where.rows.start

    parts = [part for r in where.tiles for part in split_rows(r, threads())]

    def tile(i: int) -> None:  # every band of one part of a row tile: threads never share a row
        r = parts[i]
        sel = None if inside is None else inside[r.start - r0:r.stop - r0]
        full = sel is None or bool(sel.all())
        for b, (field, table) in enumerate(zip(fields, tables)):
            rows = field[r.start - r0:r.stop - r0]
            if full:
                out[r, where.cols, b] = table.take(rows.astype(np.intp), mode="clip")
            elif sel.any():
                out[r, where.cols, b][sel] = table.take(rows[sel].astype(np.intp), mode="clip")
    in_parallel(tile, len(parts), h * w)


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
                dependence: tuple[Dependences | None, Dependences | None] = (None, None),
                independent: bool = False) -> np.ndarray:
    """Quantile-space blend: x = (1 - w) x_lo(z) + w x_hi(z), each quantile function truncated
    to its angle's observed levels, rounded. z is a correlated field where both angles (or the
    only one that has it) carry grain, the grain and latent band correlation blended linearly
    across the angles (a mix of spectra stays one, of correlation matrices too)."""
    if not 0.0 <= weight <= 1.0:
        raise ValueError(f"interpolation weight must lie in [0, 1], got {weight}")
    n_bands = max(_bands(lo), _bands(hi))
    labels = _check(mask, lo, n_bands, " at the lower neighbouring angle")
    _check(mask, hi, n_bands, " at the upper neighbouring angle", labels)
    out = _output(mask, n_bands, levels)
    for label in labels:
        where = region(mask, label)
        deps = [_record(d, label, n_bands) for d in dependence]
        grains = [None if independent or d is None or not d.measured or not where.count
                  else grain_of(d, band_maps(m, label, n_bands, levels, d)) for d, m in zip(deps, (lo, hi))]
        grain = blend(grains[0], grains[1], weight) if all(grains) else (grains[0] or grains[1])
        fields = None
        if grain is not None:
            h, w = where.rows.stop - where.rows.start, where.cols.stop - where.cols.start
            inside = None if where.count == h * w else mask[where.rows, where.cols] == label
            fields = draw(grain, (h, w), rng, inside=inside)
        for b in range(n_bands):
            to_pixels = _blend2(lo[(label, b)], hi[(label, b)], weight, levels,
                                *(d.levels(b) if d is not None and d.lo else None for d in deps))
            fill(out, b, mask, where, _from_stream(Draws(rng.standard_normal, where.count), to_pixels)
                 if fields is None else _from_fields(fields[b], where, to_pixels))
    return out


def _blend2(lo: Johnson, hi: Johnson, weight: float, levels: int, seen_lo: tuple[int, int] | None = None,
            seen_hi: tuple[int, int] | None = None) -> Callable[[np.ndarray], np.ndarray]:
    x_lo = lo.x_of_z if seen_lo is None else (lambda z: quantile(lo, levels, *seen_lo, z))
    x_hi = hi.x_of_z if seen_hi is None else (lambda z: quantile(hi, levels, *seen_hi, z))
    # (1 - w) x_lo + w x_hi in this order: the same floating-point sum as before tiling
    return lambda z: np.clip(np.rint((1.0 - weight) * x_lo(z) + weight * x_hi(z)), 0, levels - 1)


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
    when it has one; `independent` ignores the grain and draws every pixel on its own (still
    within the observed levels)."""
    by_angle = source.models_by_angle() if hasattr(source, "models_by_angle") else source
    if dependence is None and hasattr(source, "dependence_by_angle"):
        dependence = source.dependence_by_angle()
    deps = dependence or {}
    lo, hi, w = neighbours(list(by_angle), float(angle))
    if lo == hi:
        return synthesize(mask, by_angle[lo], rng, levels, deps.get(lo), independent)
    return interpolate(by_angle[lo], by_angle[hi], w, mask, rng, levels, (deps.get(lo), deps.get(hi)), independent)
