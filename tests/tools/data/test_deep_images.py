"""16-bit (and float) images through fit, mask, synth, compare, pdfs and ingest.

The thermal case is the scene model's thermal band (hal.scene, centikelvin) as a thermal
camera records it: its optics blur (a Gaussian of 1 pixel) and its noise (NETD 50 mK, i.e.
5 centikelvin), written as a 16-bit PNG.
"""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from btf.fit.fitter import FrameFitter
from hal.interfaces import ViewAngles
from hal.scene import render
from tests.support.databases import older_database
from tools.data.images import read_image, write_image, write_mask
from tools.report.capture_views import histogram_png, level_span, measured_per_level, model_curve
from tools.store.database import Store


def thermal_camera(scene: str = "mixed", size=(480, 640), seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    view = render(scene, ViewAngles(60.0, 0.0), size, seed=seed, bands="multispectral")
    kelvin = cv2.GaussianBlur(view.image[..., 5].astype(np.float32), (0, 0), 1.0)
    kelvin += np.random.default_rng(seed).normal(0.0, 5.0, kelvin.shape).astype(np.float32)
    return np.clip(np.rint(kelvin), 0, 65535).astype(np.uint16), view.mask


@pytest.fixture(scope="module")
def thermal(tmp_path_factory):
    d = tmp_path_factory.mktemp("thermal")
    image, mask = thermal_camera()
    assert cv2.imwrite(str(d / "thermal.png"), image)
    write_mask(d / "mask.png", mask)
    return d


def test_thermal_render_fit_synth_compare_histogram_l1_within_005(host, thermal, tmp_path):
    code, out, err = host("fit", thermal / "thermal.png", "--mask", thermal / "mask.png", "--space", "gray", "--json")
    assert code == 0, err
    doc = json.loads(out)
    assert doc["levels"] == 65536 and doc["bands"] == ["Y"] and doc["dependence"] is not None
    assert all(m["xi"] > 20000 for m in doc["models"])  # fitted in centikelvin, not squeezed to 8 bits
    (tmp_path / "m.json").write_text(out)
    code, _, err = host("synth", "--model", tmp_path / "m.json", "--mask", thermal / "mask.png",
                        "--angle", 60, "--out", tmp_path / "s.png")
    assert code == 0, err
    synth = cv2.imread(str(tmp_path / "s.png"), cv2.IMREAD_UNCHANGED)
    real = cv2.imread(str(thermal / "thermal.png"), cv2.IMREAD_UNCHANGED)
    assert synth.dtype == np.uint16 and synth.shape == real.shape
    assert abs(float(synth.mean()) - float(real.mean())) < 20  # centikelvin: 0.2 K
    code, out, err = host("compare", thermal / "thermal.png", tmp_path / "s.png", "--mask", thermal / "mask.png",
                          "--space", "gray", "--json")
    assert code == 0, err
    regions = json.loads(out)["regions"]
    assert [r["label"] for r in regions] == [1, 2]
    assert max(r["hist_diff"] for r in regions) <= 0.05


def test_deep_histograms_are_binned_over_the_occupied_levels(host, thermal, tmp_path):
    # Two draws of one thermal plate (other seeds) are one distribution: per level their
    # histograms would differ by counting noise alone; over the binned levels they agree.
    other, _ = thermal_camera(seed=2)
    cv2.imwrite(str(tmp_path / "other.png"), other)
    code, out, _ = host("compare", thermal / "thermal.png", tmp_path / "other.png", "--space", "gray", "--json")
    assert code == 0
    (row,) = json.loads(out)["regions"]
    assert row["hist_diff"] < 0.1 and row["w1"] < 30


def test_pdfs_and_mask_take_16_bit_images(host, thermal, tmp_path):
    code, out, err = host("pdfs", thermal / "thermal.png", "--mask", thermal / "mask.png", "--space", "gray", "--json")
    assert code == 0, err
    rows = json.loads(out)["rows"]
    assert len(rows) == 2
    assert all(r["errors"]["johnson"] < min(r["errors"]["gaussian"], 0.1) for r in rows)
    code, _, err = host("mask", thermal / "thermal.png", "--method", "kmeans", "--k", 2, "--out", tmp_path / "k.png")
    assert code == 0, err
    got = cv2.imread(str(tmp_path / "k.png"), cv2.IMREAD_UNCHANGED)
    truth = cv2.imread(str(thermal / "mask.png"), cv2.IMREAD_UNCHANGED)
    # The white plate is cooler (darker): class 0, darkest first.
    assert np.mean((got == 0) == (truth == 2)) > 0.9


def test_16_bit_db_path_keeps_the_depth(host, thermal, tmp_path):
    db = tmp_path / "t.db"
    code, _, err = host("fit", thermal / "thermal.png", "--mask", thermal / "mask.png", "--space", "gray",
                        "--angle", 60, "--db", db)
    assert code == 0, err
    with Store.open(db) as store:
        assert [c.levels for c in store.captures()] == [65536]
    code, _, err = host("synth", "--db", db, "--mask", thermal / "mask.png", "--angle", 60, "--out", tmp_path / "s.tif")
    assert code == 0, err
    synth = cv2.imread(str(tmp_path / "s.tif"), cv2.IMREAD_UNCHANGED)
    assert synth.dtype == np.uint16 and synth.min() > 20000


def test_ingest_stores_16_bit_levels(host, tmp_path):
    folder = tmp_path / "thermal"
    folder.mkdir()
    for seed in (1, 2):
        image, _ = thermal_camera("white", (60, 80), seed)
        cv2.imwrite(str(folder / f"t{seed}.png"), image)
    db = tmp_path / "i.db"
    code, _, err = host("ingest", folder, "--layout", "folder", "--db", db, "--space", "gray", "--workers", 0, "--quiet")
    assert code == 0, err
    with Store.open(db) as store:
        caps = store.captures()
        assert [c.levels for c in caps] == [65536, 65536]
        assert all(store.dependence(c.id) for c in caps)
        assert min(m.model.xi for c in caps for m in store.models(c.id).values()) > 20000


@pytest.mark.parametrize("suffix", [".png", ".tif"])
@pytest.mark.parametrize("channels", [1, 3])
def test_16_bit_files_read_and_write_exactly(tmp_path, suffix, channels):
    rng = np.random.default_rng(channels)
    pixels = rng.integers(0, 65536, (20, 30, channels), dtype=np.uint16)
    path = tmp_path / f"x{suffix}"
    write_image(path, pixels[..., 0] if channels == 1 else pixels)
    got = read_image(path)
    assert got.dtype == np.uint16 and got.shape == (20, 30, channels)  # one band stays one band
    assert np.array_equal(got, pixels)


def test_float_images_in_0_1_become_16_bit_levels(host, tmp_path):
    values = np.random.default_rng(0).uniform(0.2, 0.8, (40, 50)).astype(np.float32)
    assert cv2.imwrite(str(tmp_path / "f.tif"), values)
    got = read_image(tmp_path / "f.tif")
    assert got.dtype == np.uint16 and np.array_equal(got[..., 0], np.rint(values * 65535).astype(np.uint16))
    code, out, _ = host("fit", tmp_path / "f.tif", "--space", "gray", "--json")
    assert code == 0 and json.loads(out)["levels"] == 65536


@pytest.mark.parametrize("pixels, message", [
    (np.full((8, 8), 1.5, np.float32), "span 1.5..1.5; expected 0..1"),
    (np.array([[np.nan, 0.5]], np.float32), "NaN or infinite"),
    (np.full((8, 8), -3, np.int16), "int16 pixels"),
])
def test_unusable_pixel_types_are_one_line_and_exit_2(host, tmp_path, pixels, message):
    assert cv2.imwrite(str(tmp_path / "bad.tif"), pixels)
    for argv in (["fit", tmp_path / "bad.tif"], ["mask", tmp_path / "bad.tif", "--method", "kmeans",
                                                 "--out", tmp_path / "m.png"]):
        code, _, err = host(*argv)
        assert code == 2 and len(err.strip().splitlines()) == 1 and message in err


def test_depth_mistakes_are_one_line_and_exit_2(host, thermal, tmp_path):
    write_image(tmp_path / "eight.png", np.zeros((480, 640, 3), np.uint8))
    write_image(tmp_path / "deep.png", np.full((48, 64, 3), 999, np.uint16))
    cases = [
        (["compare", thermal / "thermal.png", tmp_path / "eight.png"], "compare images of one depth"),
        # a thermal frame is one band: no colour space of it, at any depth
        (["fit", thermal / "thermal.png", "--space", "hsv"], "the image is one band"),
        (["pdfs", thermal / "thermal.png", "--mask", thermal / "mask.png", "--space", "pca"], "use gray"),
        (["fit", tmp_path / "deep.png", "--space", "hsv"], "16-bit images are fitted in rgb or gray"),
    ]
    code, out, _ = host("fit", thermal / "thermal.png", "--mask", thermal / "mask.png", "--space", "gray", "--json")
    (tmp_path / "m.json").write_text(out)
    cases.append((["synth", "--model", tmp_path / "m.json", "--mask", thermal / "mask.png", "--angle", 60,
                   "--out", tmp_path / "s.jpg"], "16-bit pixels need a .png or .tif file"))
    for argv, message in cases:
        code, _, err = host(*argv)
        assert code == 2 and len(err.strip().splitlines()) == 1 and message in err, (argv, err)


def test_a_schema_5_database_is_upgraded_with_8_bit_levels(tmp_path):
    db = older_database(tmp_path / "old.db", 5,  # the tables schema 5 did not have yet
                        "ALTER TABLE captures DROP COLUMN levels; DROP TABLE capture_camera; DROP TABLE rejected_packets;",
                        "bot", 1, 0.0, None, (60.0, 0.0), "gray", ("Y",), {})
    with Store.open(db) as store:
        assert [c.levels for c in store.captures()] == [256]
        assert store.add_capture("bot", 2, 0.0, None, (50.0, 0.0), "gray", ("Y",), {}, levels=65536)
        assert store.levels() == 65536


def test_report_shows_16_bit_captures_at_their_depth(host, tmp_path):
    folder = tmp_path / "imgs"
    folder.mkdir()
    image, mask = thermal_camera("mixed", (60, 80), 1)
    cv2.imwrite(str(folder / "t.png"), image)
    write_mask(tmp_path / "mask.png", mask)
    db = tmp_path / "r.db"
    assert host("ingest", folder, "--layout", "folder", "--db", db, "--mask", tmp_path / "mask.png",
                "--space", "gray", "--workers", 0, "--quiet")[0] == 0
    code, _, err = host("report", "--db", db, "--out", tmp_path / "rep", "--quiet")
    assert code == 0, err
    for kind in ("synthetic", "correlated"):
        (shown,) = (tmp_path / "rep").glob(f"*_{kind}.png")
        pixels = cv2.imread(str(shown), cv2.IMREAD_UNCHANGED)
        # the hot black sand (left) and the cool white sand (right), stretched for viewing
        assert pixels[:, :40].mean() > pixels[:, 40:].mean() + 60, kind


def test_a_deep_bands_measured_histogram_stands_beside_its_johnson_curve():
    image, mask = thermal_camera("mixed", (120, 160), 2)
    labels = [int(v) for v in np.unique(mask)]
    fitter = FrameFitter(max(labels) + 1, 1, bins=65536)
    fitter.add(image[..., None], mask)
    models = {k: r.model for k, r in fitter.fit().items()}
    span = level_span(models, 0, 65536)
    for lab in labels:
        values = image[mask == lab]
        per_level, edges = measured_per_level(values, 65536, span)
        widths = np.diff(edges)
        # at most 256 bins of whole levels, as deep histograms are compared (level_bins.Grid)
        assert len(edges) <= 257 and np.all(widths == np.rint(widths)) and widths.min() >= 1
        shown = per_level @ widths
        assert shown == pytest.approx(np.mean((values > edges[0]) & (values < edges[-1])))
        # on the scale of the curve: probability per level, where the bulk of the region lies
        x, curve = model_curve(models[(lab, 0)], 65536)
        centres = (edges[:-1] + edges[1:]) / 2
        bulk = per_level > 0.25 * per_level.max()
        assert np.median(per_level[bulk] / np.interp(centres[bulk], x, curve)) == pytest.approx(1.0, abs=0.15)
    with_image = histogram_png(image[..., None], mask, models, ("Y",), 65536)
    assert with_image != histogram_png(None, mask, models, ("Y",), 65536)  # the measured bars are drawn
