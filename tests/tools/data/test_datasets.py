"""Dataset layouts: angles from CUReT tables, UTIA file names and folder sidecars."""
from __future__ import annotations

import math

import numpy as np
import pytest

from tools.data.datasets import Angles, DatasetError, Layout, parse_utia_name, read_curet_table, scan, write_rendered

VIEWS = [Angles(30.0, 0.0, 40.0, 0.0), Angles(60.0, 90.0, 70.0, 180.0), Angles(90.0, 0.0, 55.0, 45.0)]


@pytest.mark.parametrize("layout", list(Layout))
def test_rendered_dataset_scans_back_to_its_angles(tmp_path, layout):
    write_rendered(tmp_path, layout, VIEWS, size=(24, 32))
    images = scan(tmp_path, layout)
    assert [im.name for im in images] == sorted(im.name for im in images)
    got = {(round(im.angles.elevation, 6), round(im.angles.azimuth, 6), round(im.angles.light_elevation, 6),
            round(im.angles.light_azimuth, 6)) for im in images}
    assert got == {(a.elevation, a.azimuth, a.light_elevation, a.light_azimuth) for a in VIEWS}


def test_utia_names_are_polar_degrees():
    a = parse_utia_name("tl075_pl120_tv030_pv345.png")
    assert (a.elevation, a.azimuth, a.light_elevation, a.light_azimuth) == (60.0, 345.0, 15.0, 120.0)
    assert parse_utia_name("tl7.5_pl0_tv0_pv0.bmp").light_elevation == 82.5


@pytest.mark.parametrize("name", ["img_001.png", "tl075_pl120_tv030.png", "tl075_pl120_tv095_pv000.png",
                                  "tlx_pl0_tv0_pv0.png"])
def test_utia_names_that_do_not_parse_are_refused(name):
    with pytest.raises(DatasetError, match="image"):
        parse_utia_name(name)


def test_curet_table_is_radians_and_numbers_come_from_file_names(tmp_path):
    (tmp_path / "angles.txt").write_text(
        f"# CUReT\n7 {math.pi / 3} {math.pi} {math.pi / 6} 0.5\n12, 0, 0, 0, 0\n")
    table = read_curet_table(tmp_path / "angles.txt")
    assert table[7] == Angles(30.0, 180.0, 60.0, round(math.degrees(0.5), 6))
    assert table[12].elevation == 90.0
    write_rendered(tmp_path / "d", "utia", [Angles(45.0, 0.0)], size=(16, 16), masks=False)
    (tmp_path / "d" / next((tmp_path / "d").glob("*.png")).name).rename(tmp_path / "01-007.png")
    images = scan(tmp_path, "curet")
    assert [(im.name, im.angles.elevation) for im in images] == [("01-007.png", 30.0)]


@pytest.mark.parametrize("text, problem", [
    ("", "no rows"), ("1 0 0 0\n", "fields"), ("1 a b c d\n", "not numbers"),
    ("1 45 0 0 0\n", "radians"), ("1 0 0 0 0\n1 0 0 0 0\n", "twice"), ("1 2.0 0 0 0\n", "elevation"),
])
def test_bad_curet_tables_name_the_problem(tmp_path, text, problem):
    (tmp_path / "angles.txt").write_text(text)
    with pytest.raises(DatasetError, match=problem):
        read_curet_table(tmp_path / "angles.txt")


def test_curet_image_missing_from_the_table_is_named(tmp_path):
    write_rendered(tmp_path, "curet", VIEWS[:2], size=(16, 16), masks=False)
    (tmp_path / "angles.txt").write_text("1 0 0 0 0\n")
    with pytest.raises(DatasetError, match="01-002.png.*not in the angle table"):
        scan(tmp_path, "curet")


def test_curet_without_table_is_refused(tmp_path):
    write_rendered(tmp_path, "utia", VIEWS[:1], size=(16, 16), masks=False)
    with pytest.raises(DatasetError, match="angles.txt: no such file"):
        scan(tmp_path, "curet")


def test_folder_without_sidecar_has_no_angles(tmp_path):
    write_rendered(tmp_path, "folder", VIEWS, size=(16, 16), masks=False)
    (tmp_path / "angles.csv").unlink()
    assert [im.angles for im in scan(tmp_path, "folder")] == [None, None, None]


def test_folder_sidecar_without_light_columns_and_missing_rows(tmp_path):
    write_rendered(tmp_path, "folder", VIEWS, size=(16, 16), masks=False)
    (tmp_path / "angles.csv").write_text("file,elevation,azimuth\nview_000.png,30,370\nview_001.png,60,0\n")
    with pytest.raises(DatasetError, match="no row for view_002.png"):
        scan(tmp_path, "folder")
    (tmp_path / "view_002.png").unlink()
    images = scan(tmp_path, "folder")
    assert images[0].angles == Angles(30.0, 10.0) and not images[0].angles.has_light


@pytest.mark.parametrize("text, problem", [
    ("name,el\nview_000.png,3\n", "needs columns"), ("file,elevation,azimuth\nview_000.png,x,0\n", "not numbers"),
    ("file,elevation,azimuth\nview_000.png,120,0\n", "elevation 120"),
    ("file,elevation,azimuth\n", "no rows below its header"),
    ("file,elevation,azimuth\nview_000.png,30,0\nview_000.png,40,0\n", "line 3: view_000.png listed twice"),
    ("file,elevation,azimuth,light_elevation,light_azimuth\nview_000.png,30,0,45,\n",
     "needs both light_elevation and light_azimuth"),
    ("name,el\nview_000.png,3\n", r"\(found: el, name\)"),
])
def test_bad_sidecars_name_the_problem(tmp_path, text, problem):
    write_rendered(tmp_path, "folder", VIEWS[:1], size=(16, 16), masks=False)
    (tmp_path / "angles.csv").write_text(text)
    with pytest.raises(DatasetError, match=problem):
        scan(tmp_path, "folder")


def test_a_sidecar_as_spreadsheets_write_it_is_read(tmp_path):
    """A byte-order mark before the header (Excel's CSV UTF-8) and spaces after the commas."""
    write_rendered(tmp_path, "folder", VIEWS[:1], size=(16, 16), masks=False)
    (tmp_path / "angles.csv").write_bytes(b"\xef\xbb\xbffile, elevation, azimuth\r\nview_000.png, 30, 10\r\n")
    assert scan(tmp_path, "folder")[0].angles == Angles(30.0, 10.0)


def test_missing_directory_empty_directory_and_unknown_layout(tmp_path):
    with pytest.raises(DatasetError, match="no such directory"):
        scan(tmp_path / "nope", "utia")
    with pytest.raises(DatasetError, match="no image files"):
        scan(tmp_path, "utia")
    with pytest.raises(DatasetError, match="layout 'bonn'"):
        scan(tmp_path, "bonn")


def test_rendered_views_are_lit_from_their_illumination_direction(tmp_path):
    from hal.interfaces import ViewAngles
    from hal.scene import LightAngles, render
    from tools.data.images import read_image

    views = [Angles(60.0, 0.0, 80.0, 0.0), Angles(60.0, 0.0, 20.0, 0.0), Angles(60.0, 0.0, 20.0, 180.0),
             Angles(60.0, 0.0)]
    paths = write_rendered(tmp_path, "folder", views, scene="white", size=(32, 32), seed=5, masks=False)
    images = [read_image(p) for p in paths]
    for a, image in zip(views, images):
        light = LightAngles(a.light_elevation, a.light_azimuth) if a.has_light else None
        assert np.array_equal(image, render("white", ViewAngles(a.elevation, a.azimuth), (32, 32), 5,
                                            light=light).image)
    high, low, low_behind, sun = (im.astype(float) for im in images)
    assert low.mean() < 0.6 * high.mean()
    assert np.abs(low - low_behind).mean() > 0.2 * low.mean()  # shadows fall on the other side of each grain
    assert np.array_equal(sun, render("white", ViewAngles(60.0, 0.0), (32, 32), 5).image)


@pytest.mark.parametrize("angles, problem", [(Angles(60.0, 0.0, 2.0, 0.0), "light elevation 2"),
                                             (Angles(1.0, 0.0), "elevation 1.0 outside")])
def test_views_the_renderer_cannot_draw_are_named(tmp_path, angles, problem):
    with pytest.raises(DatasetError, match=f"rendered view 1 .*{problem}"):
        write_rendered(tmp_path, "folder", [Angles(60.0, 0.0), angles], size=(16, 16), masks=False)
