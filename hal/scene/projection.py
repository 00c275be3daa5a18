"""Which ground cell each pixel of an orthographic view sees: rays marched over the height field.

An image column is a vertical plane through the plate along the view azimuth. Along it,
ground samples one cell apart run from below the frame's near edge to its far edge; a
sample's image-plane height is its distance along the ground times sin(elevation) plus its
terrain height times cos(elevation), and a pixel row sees the first sample whose running
maximum of that height reaches the row (nearer grains hide what lies behind them).

Every step is a whole-array numpy operation without a modulo or a float64 pass over the
samples: the plate is read through a copy padded with its own wrap-around (`PaddedPlate`,
once per plate), a block of columns at a time; the running maximum and the running count
are loops over contiguous rows; and the sample a row sees is the count of samples below it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hal.interfaces import ViewAngles
from hal.scene.sensor import gather

MARGIN = 64  # columns per block, and the wrap-around the padded plate repeats on each side


@dataclass(frozen=True, slots=True)
class PaddedPlate:
    """A T x T periodic plate grown by MARGIN cells of its own wrap-around on every side, so a
    block of MARGIN columns reads it with plain indices, whatever the view."""

    height: np.ndarray  # ((T + 2 MARGIN)^2,) float32, flat
    cell: np.ndarray  # ((T + 2 MARGIN)^2,) int32: the plate's flat index of each padded cell
    size: int  # T
    top: float  # the highest point: how far below the frame a grain can reach into it

    @classmethod
    def of(cls, height: np.ndarray) -> PaddedPlate:
        size = height.shape[0]
        cells = np.arange(size * size, dtype=np.int32).reshape(size, size)
        return cls(np.pad(height.astype(np.float32), MARGIN, mode="wrap").ravel(),
                   np.pad(cells, MARGIN, mode="wrap").ravel(), size, float(height.max()))


def _sample_index(plate: PaddedPlate, origin: tuple[float, float], step: tuple[float, float, float, float],
                  shape: tuple[int, int]) -> np.ndarray:
    """(ny, w) flat index into the padded plate of the cell holding origin + c (rx, ry) + j (fx, fy),
    sample j of column c: per block, each row's first point is wrapped into the plate and the
    block's few columns stay within the margin."""
    ny, w = shape
    rx, ry, fx, fy = step
    size, wide = plate.size, plate.size + 2 * MARGIN
    j = np.arange(ny)
    out = np.empty((ny, w), np.int32)
    for c0 in range(0, w, MARGIN):
        dc = np.arange(min(w, c0 + MARGIN) - c0)
        x0 = ((origin[0] + c0 * rx + j * fx) % size + MARGIN).astype(np.float32)
        y0 = ((origin[1] + c0 * ry + j * fy) % size + MARGIN).astype(np.float32)
        # float32, and positive: truncation is the floor, the cell the point lies in
        block = np.add.outer(y0, (dc * ry).astype(np.float32)).astype(np.int32)
        block *= wide
        block += np.add.outer(x0, (dc * rx).astype(np.float32)).astype(np.int32)
        out[:, c0:c0 + dc.size] = block
    return out


def _running_max(rows: np.ndarray) -> None:
    """Each row becomes the elementwise maximum of itself and every row before it (in place;
    row by row is several times faster than numpy's accumulate along the first axis)."""
    for j in range(1, rows.shape[0]):
        np.maximum(rows[j - 1], rows[j], out=rows[j])


def _running_sum(rows: np.ndarray) -> None:
    for j in range(1, rows.shape[0]):
        np.add(rows[j - 1], rows[j], out=rows[j])


def seen_cells(plate: PaddedPlate, view: ViewAngles, h: int, w: int) -> np.ndarray:
    """Flat index (h, w) int32 into the padded plate of the cell each pixel of the view sees
    (`plate.cell` names it in the plate); one pixel of a nadir view is one cell."""
    size = plate.size
    el, az = math.radians(view.elevation), math.radians(view.azimuth % 360.0)
    se, ce = math.sin(el), math.cos(el)
    if view.elevation >= 90.0:
        se, ce = 1.0, 0.0
    # ground from below the frame's near edge (tall near grains reach into it) to the far edge
    ys = np.arange((-h / 2.0 - plate.top * ce) / se - 2.0, (h / 2.0) / se + 2.0, 1.0)
    ny = ys.size
    fx, fy, rx, ry = math.sin(az), math.cos(az), math.cos(az), -math.sin(az)
    x0 = 0.5 - w / 2.0  # lateral position of the first column
    origin = (x0 * rx + ys[0] * fx + size / 2.0, x0 * ry + ys[0] * fy + size / 2.0)
    samples = _sample_index(plate, origin, (rx, ry, fx, fy), (ny, w))  # near to far
    # image-plane height of each sample; a sample is seen once it tops all nearer ones
    reach = gather(plate.height, samples)
    reach *= np.float32(ce)
    reach += (ys * se).astype(np.float32)[:, None]
    _running_max(reach)
    # Row i from the bottom (at height i + 1/2 - h/2) sees sample k, the number of samples
    # below it. A sample at `reach` is below the rows from floor(reach + h/2 + 1/2) up: count
    # the samples by that first row, then sum the counts up the rows.
    reach += np.float32(h / 2.0 + 0.5)
    np.floor(reach, out=reach)
    np.clip(reach, 0, h, out=reach)
    first = reach.astype(np.int64)
    first *= w
    first += np.arange(w)
    below = np.bincount(first.ravel(), minlength=(h + 1) * w)[:h * w].reshape(h, w)
    _running_sum(below)
    np.minimum(below, ny - 1, out=below)
    seen = below[::-1] * w  # image rows top to bottom
    seen += np.arange(w)
    return gather(samples.ravel(), seen)
