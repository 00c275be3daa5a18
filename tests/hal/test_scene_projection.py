"""The scene's projection (which cell each pixel sees) and its read noise, against plain
float64 numpy that marches every ray with exact floors and no shortcuts."""
from __future__ import annotations

import math

import numpy as np
import pytest

from hal.interfaces import ViewAngles
from hal.scene.projection import MARGIN, PaddedPlate, seen_cells
from hal.scene.sensor import unit_normal
from hal.scene.surface import build_surface


def ray_march(height: np.ndarray, view: ViewAngles, h: int, w: int) -> np.ndarray:
    """Flat index of the cell each pixel sees: every ray sampled cell by cell in float64, each
    pixel row seeing the first sample whose running image-plane height reaches it."""
    size = height.shape[0]
    el, az = math.radians(view.elevation), math.radians(view.azimuth)
    se, ce = (1.0, 0.0) if view.elevation >= 90.0 else (math.sin(el), math.cos(el))
    xs = np.arange(w) - w / 2.0 + 0.5
    ys = np.arange((-h / 2.0 - float(height.max()) * ce) / se - 2.0, (h / 2.0) / se + 2.0, 1.0)
    fx, fy, rx, ry = math.sin(az), math.cos(az), math.cos(az), -math.sin(az)
    ix = np.floor(xs[None, :] * rx + ys[:, None] * fx + size / 2.0).astype(np.int64) % size
    iy = np.floor(xs[None, :] * ry + ys[:, None] * fy + size / 2.0).astype(np.int64) % size
    cells = iy * size + ix
    reach = np.maximum.accumulate(ys[:, None] * se + height.ravel()[cells] * ce, axis=0)
    rows = np.arange(h) + 0.5 - h / 2.0  # bottom to top
    k = np.stack([np.searchsorted(reach[:, c], rows) for c in range(w)], axis=1)
    return cells[np.minimum(k, len(ys) - 1)[::-1], np.arange(w)]


@pytest.fixture(scope="module")
def plate():
    return build_surface("field", 5, 192, 1.2).height


def seen(height: np.ndarray, view: ViewAngles, h: int, w: int) -> np.ndarray:
    """Flat index into the plate of the cell each pixel sees."""
    plate = PaddedPlate.of(height)
    return plate.cell[seen_cells(plate, view, h, w)]


@pytest.mark.parametrize("h, w", [(90, 120), (61, 47)])  # even and odd sides
def test_a_nadir_view_sees_every_cell_under_it_once(plate, h, w):
    view = ViewAngles(90.0, 0.0)
    assert np.array_equal(seen(plate, view, h, w), ray_march(plate, view, h, w))
    for azimuth in (90.0, 180.0, 270.0):  # a pixel is a cell: no row or column twice, none left out
        assert np.unique(seen(plate, ViewAngles(90.0, azimuth), h, w)).size == h * w


@pytest.mark.parametrize("view", [ViewAngles(60.0, 10.0), ViewAngles(30.0, 200.0), ViewAngles(12.0, 333.0),
                                  ViewAngles(5.0, 45.0)])
def test_oblique_views_see_what_the_exact_ray_march_sees(plate, view):
    h, w = 70, 3 * MARGIN + 5  # blocks of columns, the last one short
    got = seen(plate, view, h, w)
    exact = ray_march(plate, view, h, w)
    assert np.mean(got == exact) > 0.999  # float32 may move a point on a cell's edge


def test_the_padded_plate_repeats_the_plate_around_it():
    height = np.arange(36, dtype=np.float32).reshape(6, 6)
    padded = PaddedPlate.of(height)
    wide = 6 + 2 * MARGIN
    cell = padded.cell.reshape(wide, wide)
    assert np.array_equal(padded.height.reshape(wide, wide), height.ravel()[cell])
    assert cell[MARGIN, MARGIN] == 0 and cell[MARGIN - 1, MARGIN - 1] == 35
    assert cell[0, MARGIN + 2] == (-MARGIN % 6) * 6 + 2  # the row MARGIN above the plate's first, wrapped
    assert padded.top == 35.0


def test_read_noise_is_a_standard_normal_drawn_from_the_generator():
    draw = unit_normal(np.random.default_rng(3), (1000, 1000))
    again = unit_normal(np.random.default_rng(3), (1000, 1000))
    assert draw.dtype == np.float32 and np.array_equal(draw, again)
    assert abs(float(draw.mean())) < 0.005 and abs(float(draw.std()) - 1.0) < 0.005
    assert np.mean(np.abs(draw) > 2.0) == pytest.approx(0.0455, abs=0.002)
    assert 4.0 < float(np.abs(draw).max()) < 4.5
    assert not np.array_equal(draw, unit_normal(np.random.default_rng(4), (1000, 1000)))
