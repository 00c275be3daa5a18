"""The scene renderer: determinism, view dependence, mixed-plate halves, bands and masks."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hal.interfaces import ViewAngles
from hal.scene import LABEL_NAMES, SCENES, Label, render

SIZE = (96, 128)


def hist(values: np.ndarray) -> np.ndarray:
    h = np.bincount(values.ravel(), minlength=256).astype(float)
    return h / h.sum()


def test_same_seed_same_image_other_seed_other_realisation_same_statistics():
    a = render("black", ViewAngles(60.0, 30.0), SIZE, seed=3)
    b = render("black", ViewAngles(60.0, 30.0), SIZE, seed=3)
    c = render("black", ViewAngles(60.0, 30.0), SIZE, seed=4)
    assert np.array_equal(a.image, b.image) and np.array_equal(a.mask, b.mask)
    assert np.mean(a.image != c.image) > 0.5  # a different grain layout
    assert abs(float(a.image.mean()) - float(c.image.mean())) < 0.05 * float(a.image.mean()) + 0.5
    assert np.abs(hist(a.image) - hist(c.image)).sum() < 0.2


def test_black_plate_statistics_change_with_view_elevation():
    top = render("black", ViewAngles(90.0), (240, 320), seed=1).image.astype(float)
    low = render("black", ViewAngles(30.0), (240, 320), seed=1).image.astype(float)
    # Oblique views see fewer shadowed gaps between grains: brighter and more spread.
    assert low.mean() - top.mean() > 1.5
    assert abs(low.std() - top.std()) > 0.5


def test_white_plate_statistics_change_with_azimuth_relative_to_the_sun():
    toward = render("white", ViewAngles(30.0, 45.0), SIZE, seed=1).image.astype(float)  # sun behind
    against = render("white", ViewAngles(30.0, 225.0), SIZE, seed=1).image.astype(float)  # into the sun
    assert toward.mean() - against.mean() > 5.0  # looking at lit faces vs shadowed faces


@pytest.mark.parametrize("elevation", [90.0, 40.0])
def test_mixed_plate_halves_match_the_single_plates(elevation):
    view = ViewAngles(elevation, 0.0)
    h, w = 120, 160
    mixed = render("mixed", view, (h, w), seed=2)
    black = render("black", view, (h, w), seed=2)
    white = render("white", view, (h, w), seed=2)
    left, right = (slice(None), slice(0, w // 2 - 8)), (slice(None), slice(w // 2 + 8, w))
    assert np.all(mixed.mask[left] == Label.BLACK_SAND) and np.all(mixed.mask[right] == Label.WHITE_SAND)
    assert np.abs(hist(mixed.image[left]) - hist(black.image[left])).sum() < 0.1
    assert np.abs(hist(mixed.image[right]) - hist(white.image[right])).sum() < 0.15
    # and the halves are plainly different materials
    assert np.abs(hist(mixed.image[left]) - hist(mixed.image[right])).sum() > 1.5


def test_rgb_output_shape_dtype_and_masks():
    for scene in SCENES:
        r = render(scene, ViewAngles(70.0, 10.0), SIZE, seed=0)
        assert r.image.shape == (*SIZE, 3) and r.image.dtype == np.uint8
        assert r.mask.shape == SIZE and r.mask.dtype == np.uint8
        assert set(np.unique(r.mask)) <= set(LABEL_NAMES)
    assert set(np.unique(render("black", ViewAngles(90.0), SIZE).mask)) == {Label.BLACK_SAND}
    field = render("field", ViewAngles(90.0), (240, 320), seed=0)
    kinds = set(np.unique(field.mask))
    assert len(kinds) >= 3 and kinds <= {Label.TAN_SAND, Label.GRASS, Label.SOIL, Label.GRAVEL}
    assert LABEL_NAMES[1] == "black_sand" and LABEL_NAMES[2] == "white_sand"


def test_field_grass_is_green_and_bright_in_near_infrared():
    r = render("field", ViewAngles(90.0), (240, 320), seed=0, bands="multispectral")
    grass = r.mask == Label.GRASS
    assert grass.sum() > 100
    img = r.image.astype(float)
    g = img[grass]
    assert g[:, 1].mean() > g[:, 2].mean()  # green over red
    assert g[:, 4].mean() > 2 * g[:, 2].mean()  # the red edge of vegetation


def test_multispectral_bands_shapes_ranges_and_thermal():
    r = render("field", ViewAngles(50.0, 200.0), SIZE, seed=5, bands="multispectral")
    assert r.image.shape == (*SIZE, 6) and r.image.dtype == np.uint16
    assert r.image[..., :5].max() <= 255
    kelvin = r.image[..., 5] / 100.0
    assert kelvin.min() > 270.0 and kelvin.max() < 340.0
    assert kelvin.std() > 0.5  # sunlit and shaded, grass and soil differ in temperature


def test_small_resolutions_stay_faithful_to_the_large():
    small = render("white", ViewAngles(90.0), (48, 64), seed=1).image.astype(float)
    large = render("white", ViewAngles(90.0), (240, 320), seed=1).image.astype(float)
    assert small.shape == (48, 64, 3)
    assert abs(small.mean() - large.mean()) < 6.0


@pytest.mark.parametrize("elevation", [5.0, 12.3, 45.0, 89.99, 90.0])
def test_every_elevation_in_range_renders_finite_in_range_pixels(elevation):
    r = render("field", ViewAngles(elevation, 333.3), (32, 48), seed=9)
    assert r.image.shape == (32, 48, 3)
    assert r.image.std() > 1.0  # a textured surface, not a blank frame


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"scene": "moon"}, "unknown scene"),
    ({"bands": "xray"}, "unknown bands"),
    ({"view": ViewAngles(2.0)}, "elevation 2.0 outside"),
    ({"view": ViewAngles(95.0)}, "outside"),
    ({"view": ViewAngles(float("nan"))}, "finite"),
    ({"size": (4, 4)}, "outside 8..8192"),
    ({"size": "big"}, "size must be"),
])
def test_bad_input_is_named(kwargs, message):
    args = {"scene": "black", "view": ViewAngles(90.0), "size": (16, 16)} | kwargs
    with pytest.raises(ValueError, match=message):
        render(**args)


@settings(max_examples=25, deadline=None)
@given(elevation=st.floats(5.0, 90.0), azimuth=st.floats(-720.0, 720.0),
       h=st.integers(8, 40), w=st.integers(8, 40), scene=st.sampled_from(SCENES))
def test_any_view_and_odd_size_gives_a_full_labelled_frame(elevation, azimuth, h, w, scene):
    r = render(scene, ViewAngles(elevation, azimuth), (h, w), seed=1, bands="multispectral")
    assert r.image.shape == (h, w, 6) and r.mask.shape == (h, w)
    assert np.all(r.mask > 0)
    assert r.image[..., :5].max() <= 255 and r.image[..., 5].min() > 27000
