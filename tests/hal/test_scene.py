"""The scene renderer: determinism, view and light dependence, mixed-plate halves, bands and masks."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hal.interfaces import ViewAngles
from hal.scene import LABEL_NAMES, SCENES, SUN, Label, LightAngles, render
from hal.scene.light import lit
from hal.scene.surface import build_surface

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
    ({"light": LightAngles(2.0, 0.0)}, "light elevation 2.0 outside"),
    ({"light": LightAngles(45.0, float("inf"))}, "light angles must be finite"),
    ({"light": (45.0, 0.0)}, "LightAngles"),
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


@pytest.mark.parametrize("bands", ["rgb", "multispectral"])
@pytest.mark.parametrize("size", [(24, 32), (90, 120)])  # supersampled and not
def test_default_light_is_the_sun_whichever_way_it_is_named(bands, size):
    view = ViewAngles(50.0, 300.0)
    default = render("field", view, size, seed=4, bands=bands)
    for light in (None, SUN, LightAngles(45.0, 225.0 - 720.0)):
        other = render("field", view, size, seed=4, bands=bands, light=light)
        assert np.array_equal(default.image, other.image) and np.array_equal(default.mask, other.mask)
        assert other.light == SUN


def bump(radius: float = 6.0, size: int = 64) -> np.ndarray:
    """A hemisphere of `radius` in the middle of a flat size x size plate."""
    y, x = np.mgrid[:size, :size] + 0.5
    return np.sqrt(np.maximum(radius**2 - (x - size / 2) ** 2 - (y - size / 2) ** 2, 0.0))


def test_a_bump_casts_its_shadow_away_from_the_light_longer_as_the_light_drops():
    height, r, c = bump(), 6.0, 32
    lengths = []
    for elevation in (60.0, 30.0, 15.0):
        east = ~lit(height, LightAngles(elevation, 90.0))  # light from the east: shadow to the west
        cols = np.flatnonzero(east.any(axis=0))
        assert cols.max() < c + 1
        length = c - cols.min()
        # a sphere's shadow reaches r / sin(elevation) from its foot
        assert length == pytest.approx(r / np.sin(np.radians(elevation)), abs=1.0)
        north = ~lit(height, LightAngles(elevation, 0.0))  # light from the north: shadow to the south
        rows = np.flatnonzero(north.any(axis=1))
        assert rows.max() < c + 1 and c - rows.min() == length
        lengths.append(length)
    assert lengths[0] < lengths[1] < lengths[2]
    assert lit(height, LightAngles(90.0, 0.0)).all()


def test_shadowed_share_of_a_plate_grows_as_the_light_drops():
    surface = build_surface("white", 1, 256, 0.4)
    shadowed = [float(np.mean(~lit(surface.height64, LightAngles(el, 225.0)))) for el in (80.0, 45.0, 20.0, 8.0)]
    assert all(a < b for a, b in zip(shadowed, shadowed[1:])) and shadowed[-1] > 2 * shadowed[1]


def test_histogram_follows_the_light_elevation_and_a_low_light_darkens_and_cools():
    view = ViewAngles(60.0, 0.0)
    high = render("white", view, SIZE, seed=1, light=LightAngles(75.0, 180.0))
    low = render("white", view, SIZE, seed=1, light=LightAngles(20.0, 180.0))
    assert np.abs(hist(high.image) - hist(low.image)).sum() > 1.0
    assert low.image.mean() < 0.6 * high.image.mean()
    assert low.image.std() > 0.5 * low.image.mean() * high.image.std() / high.image.mean()  # shadows add contrast
    assert np.array_equal(high.mask, low.mask)  # the light moves, the grains do not
    hot = render("black", view, SIZE, seed=1, bands="multispectral", light=LightAngles(75.0, 180.0)).image
    cold = render("black", view, SIZE, seed=1, bands="multispectral", light=LightAngles(20.0, 180.0)).image
    assert hot[..., 5].mean() - cold[..., 5].mean() > 100  # more than a kelvin warmer under a high sun


def test_only_the_azimuth_between_view_and_light_matters_on_isotropic_sand():
    def mean(view_az: float, light_az: float) -> float:
        return float(render("white", ViewAngles(30.0, view_az), SIZE, seed=1,
                            light=LightAngles(40.0, light_az)).image.mean())

    behind = mean(45.0, 225.0)
    assert mean(135.0, 315.0) == pytest.approx(behind, rel=0.03)  # both turned by 90 degrees
    assert behind - mean(135.0, 225.0) > 5.0  # the light moved to the side


def test_a_new_light_reuses_the_grain_layout():
    render("mixed", ViewAngles(70.0), (40, 48), seed=11)
    before = build_surface.cache_info()
    render("mixed", ViewAngles(70.0), (40, 48), seed=11, light=LightAngles(25.0, 10.0))
    after = build_surface.cache_info()
    assert after.misses == before.misses and after.hits == before.hits + 1
