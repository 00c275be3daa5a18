"""Images of other than one or three bands: a multi-spectral camera's TIFF through mask, fit,
synth, compare and pdfs as its own bands, and alpha channels that are not bands.

The multi-spectral case is the scene model's camera (hal.scene, bands="multispectral"): five
spectral bands and a thermal one, 16-bit, written as one TIFF of six samples.
"""
from __future__ import annotations

import io
import json
import random
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import tifffile
from PIL import Image

from hal.interfaces import ViewAngles
from hal.scene import render
from radio import packets as pk
from tests.support.robots import IDLE, robot_toml
from tools.data.images import ImageError, read_image, view_rgb, write_image, write_mask
from tools.station.receiver import Receiver
from tools.store.database import Store


@pytest.fixture(scope="module")
def spectral(tmp_path_factory):
    d = tmp_path_factory.mktemp("spectral")
    view = render("mixed", ViewAngles(60.0, 0.0), (96, 128), seed=2, bands="multispectral")
    tifffile.imwrite(d / "view.tif", view.image, photometric="minisblack", planarconfig="contig")
    write_mask(d / "mask.png", view.mask)
    return d, view.image, view.mask


def test_a_six_band_tiff_is_fitted_synthesized_and_compared_as_its_six_bands(host, spectral, tmp_path):
    d, image, mask = spectral
    assert image.shape[2] == 6 and image.dtype == np.uint16
    code, out, err = host("fit", d / "view.tif", "--mask", d / "mask.png", "--json")
    assert code == 0, err
    doc = json.loads(out)
    assert doc["space"] == "raw" and doc["bands"] == [f"B{k}" for k in range(6)] and doc["levels"] == 65536
    (tmp_path / "m.json").write_text(out)
    code, _, err = host("synth", "--model", tmp_path / "m.json", "--mask", d / "mask.png", "--out", tmp_path / "s.tif")
    assert code == 0, err
    synth = read_image(tmp_path / "s.tif")
    assert synth.shape == image.shape and synth.dtype == np.uint16
    for lab in np.unique(mask):
        inside = mask == lab
        for b in range(6):  # every band of every region within the levels it took
            real, made = image[..., b][inside], synth[..., b][inside]
            assert real.min() <= made.min() and made.max() <= real.max(), (lab, b)
            assert abs(float(made.mean()) - float(real.mean())) <= 0.05 * float(np.ptp(real)) + 1, (lab, b)
    code, out, err = host("compare", d / "view.tif", tmp_path / "s.tif", "--mask", d / "mask.png", "--json")
    assert code == 0, err
    compared = json.loads(out)
    assert compared["space"] == "raw" and sorted(compared["correlation"]) == [f"B{k}" for k in range(6)]
    code, out, err = host("pdfs", d / "view.tif", "--mask", d / "mask.png")
    assert code == 0, err
    assert {line.split()[1] for line in out.splitlines()[1:] if line.split()} >= {f"B{k}" for k in range(6)}


def test_a_multi_spectral_tiff_is_segmented_on_all_its_bands_each_over_its_own_range(host, spectral, tmp_path):
    d, image, truth = spectral
    for method in ("kmeans", "isodata", "felzenszwalb"):
        code, _, err = host("mask", d / "view.tif", "--method", method, "--k", "2", "--out", tmp_path / f"{method}.png")
        assert code == 0 and err == "", (method, err)
        labels = cv2.imread(str(tmp_path / f"{method}.png"), cv2.IMREAD_UNCHANGED)
        assert labels.shape == image.shape[:2]
        if method == "isodata":  # splits up to 2 k; over one range for all bands the thermal one took it all (1 class)
            assert 2 <= len(np.unique(labels)) <= 4
        else:  # the scene's two materials, up to the order of the labels
            agree = np.mean((labels == 0) == (truth == truth.min()))
            assert max(agree, 1 - agree) >= 0.95, method


def test_bands_png_cannot_hold_and_spaces_they_lack_are_one_line_and_exit_2(host, spectral, tmp_path):
    d, _, _ = spectral
    code, out, _ = host("fit", d / "view.tif", "--mask", d / "mask.png", "--json")
    (tmp_path / "m.json").write_text(out)
    code, _, err = host("synth", "--model", tmp_path / "m.json", "--mask", d / "mask.png", "--out", tmp_path / "s.png")
    assert code == 2 and err.strip().endswith("6 bands need a .tif file (PNG holds one or three)")
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "s.png").exists()
    code, _, err = host("fit", d / "view.tif", "--space", "rgb")
    assert code == 2 and "the image has 6 bands" in err and "raw" in err and len(err.strip().splitlines()) == 1


def test_a_planar_tiff_and_a_stack_of_pages_are_bands_and_alpha_is_not(tmp_path):
    rng = np.random.default_rng(0)
    bands = rng.integers(0, 256, (20, 30, 4), dtype=np.uint8)
    tifffile.imwrite(tmp_path / "planar.tif", np.moveaxis(bands, -1, 0), photometric="minisblack",
                     planarconfig="separate")
    tifffile.imwrite(tmp_path / "pages.tif", np.moveaxis(bands, -1, 0), photometric="minisblack")
    tifffile.imwrite(tmp_path / "rgba.tif", bands, photometric="rgb", extrasamples=["unassalpha"])
    assert np.array_equal(read_image(tmp_path / "planar.tif"), bands)
    assert np.array_equal(read_image(tmp_path / "pages.tif"), bands)
    assert np.array_equal(read_image(tmp_path / "rgba.tif"), bands[..., :3])
    Image.fromarray(bands[..., :2], "LA").save(tmp_path / "gray_alpha.png")
    Image.fromarray(bands, "RGBA").save(tmp_path / "rgba.png")
    assert np.array_equal(read_image(tmp_path / "gray_alpha.png"), bands[..., :1])
    assert np.array_equal(read_image(tmp_path / "rgba.png"), bands[..., :3])
    scan = bands[..., 0] > 127  # a bilevel TIFF: one band of black and white at 8 bits
    tifffile.imwrite(tmp_path / "bilevel.tif", scan)
    assert np.array_equal(read_image(tmp_path / "bilevel.tif"), np.where(scan, 255, 0).astype(np.uint8)[..., None])


@pytest.mark.parametrize("count", [2, 4, 7])
def test_bands_written_read_back_exactly(tmp_path, count):
    bands = np.random.default_rng(count).integers(0, 65536, (9, 11, count), dtype=np.uint16)
    write_image(tmp_path / "b.tif", bands)
    assert np.array_equal(read_image(tmp_path / "b.tif"), bands)


def test_a_gray_and_alpha_png_is_fitted_as_one_band(host, tmp_path):
    gray = np.random.default_rng(3).integers(40, 200, (40, 50), dtype=np.uint8)
    Image.fromarray(np.dstack([gray, np.full_like(gray, 255)]), "LA").save(tmp_path / "ga.png")
    code, out, err = host("fit", tmp_path / "ga.png", "--json")
    assert code == 0, err
    assert json.loads(out)["bands"] == ["Y"]


def test_a_tiff_of_several_images_is_refused_in_one_line(host, tmp_path):
    tifffile.imwrite(tmp_path / "series.tif", np.zeros((2, 3, 8, 8), np.uint8), photometric="minisblack")
    code, _, err = host("fit", tmp_path / "series.tif")
    assert code == 2 and "expected one image of bands" in err and len(err.strip().splitlines()) == 1


def test_the_report_draws_a_multi_spectral_capture_as_false_colour(host, spectral, tmp_path):
    d, image, mask = spectral
    code, _, err = host("fit", d / "view.tif", "--mask", d / "mask.png", "--angle", 60, "--db", tmp_path / "ms.db")
    assert code == 0, err
    code, _, err = host("report", "--db", tmp_path / "ms.db", "--out", tmp_path / "rep", "--quiet")
    assert code == 0, err
    for name in ("synthetic", "correlated"):
        drawn = read_image(tmp_path / "rep" / f"robothost_060.0_0_{name}.png")
        assert drawn.shape == image.shape[:2] + (3,) and drawn.dtype == np.uint8
        # the first three bands, each over its own levels: the two materials stay apart in each
        for b in range(3):
            means = [float(drawn[..., b][mask == lab].mean()) for lab in np.unique(mask)]
            real = [float(image[..., b][mask == lab].mean()) for lab in np.unique(mask)]
            assert (means[0] < means[1]) == (real[0] < real[1]) and abs(means[0] - means[1]) > 10, (name, b)


def test_spaces_judges_a_multi_spectral_tiff_in_its_own_bands_and_draws_it(host, spectral, tmp_path):
    d, image, _ = spectral
    code, out, err = host("spaces", d / "view.tif", "--masks", "kmeans2", "--json", "--picture", tmp_path / "p.png")
    assert code == 0, err
    doc = json.loads(out)
    assert [r["space"] for r in doc["rows"]] == ["raw"] and doc["choice"]["space"] == "raw"
    drawn = read_image(tmp_path / "p.png")
    assert drawn.shape[2] == 3 and drawn.shape[0] >= image.shape[0]


def _small_tiff() -> bytes:
    buf = io.BytesIO()
    tifffile.imwrite(buf, np.arange(6 * 7 * 5, dtype=np.uint16).reshape(6, 7, 5), photometric="minisblack",
                     planarconfig="contig")
    return buf.getvalue()


SMALL_TIFF = _small_tiff()


DAMAGED_RUN = """
import sys
from tools.cli import main
for path in sys.argv[1:]:
    code = main(["fit", path, "--independent-only"])
    print(f"@@ {code}", file=sys.stderr, flush=True)
"""


def test_damaged_tiffs_are_fitted_or_refused_in_one_line_in_a_process_of_their_own(tmp_path):
    # a process of its own: pytest's log capture would hide lines a reader logs to stderr
    rng = random.Random(3)
    paths = []
    for k in range(60):
        data = bytearray(SMALL_TIFF)
        for _ in range(rng.randint(1, 6)):
            data[rng.randrange(len(data))] = rng.randrange(256)
        paths.append(tmp_path / f"damaged{k}.tif")
        paths[-1].write_bytes(bytes(data[:rng.randint(8, len(data))]))
    run = subprocess.run([sys.executable, "-c", DAMAGED_RUN, *map(str, paths)], capture_output=True, text=True,
                         timeout=300, cwd=Path(__file__).resolve().parents[3])
    assert run.returncode == 0, run.stderr[-2000:]
    rest, refused = run.stderr, 0
    for path in paths:  # each file's stderr is what comes before its marker
        said, _, rest = rest.partition("@@ ")
        code, _, rest = rest.partition("\n")
        lines = [line for line in said.splitlines() if line.strip()]
        assert (code == "0" and lines == []) or (code == "2" and len(lines) == 1 and str(path) in lines[0]), \
            (code, lines)
        refused += code == "2"
    assert refused >= len(paths) // 2  # most of the damage is found, and said in one line


def test_a_tiff_whose_header_claims_more_pixels_than_an_image_may_have_is_refused_before_reading(tmp_path):
    with tifffile.TiffWriter(tmp_path / "huge.tif") as tif:  # a header of 40000 x 40000, no pixels behind it
        tif.write(shape=(40000, 40000), dtype=np.uint8)
    with pytest.raises(ImageError, match="more than the 1073741824 an image may have"):
        read_image(tmp_path / "huge.tif")


NAMES = ("blue", "green", "red", "rededge", "nir", "thermal")  # the scene model's camera, in frame order


def test_a_view_draws_the_bands_named_red_green_and_blue_as_colour(spectral):
    _, image, _ = spectral
    plain = view_rgb(image)  # the first three bands as R, G, B
    assert np.array_equal(view_rgb(image, names=NAMES), plain[..., ::-1])  # red, green, blue are bands 2, 1, 0
    assert np.array_equal(view_rgb(image, names=("R", "G", "B", "x", "y", "z")), plain)
    assert np.array_equal(view_rgb(image, names=("red", "green", "nir", "w", "x", "y")), plain)  # no blue: false colour


def test_the_report_draws_a_named_multi_spectral_capture_in_its_colours(fake_robot, host, tmp_path):
    text = robot_toml({"hal": {"scene": "mixed", "size": [60, 80], "pixel_format": "MSP6"}, "skip": None,
                       "features": {"space": "raw", "band_names": list(NAMES)}}, IDLE)
    rt, tr = fake_robot(text)
    rt.boot()
    for cid, name, args in ((1, pk.CommandName.SEND_MASK, {"seq": 1}), (2, pk.CommandName.CAPTURE, {})):
        tr.receive(pk.encode(pk.CommandPacket(cid, name, args)))
        rt.step()
    frame, labels = rt.hal.camera.capture(), rt.hal.camera.last_mask  # the same view again
    with Store.open(tmp_path / "named.db") as store:
        rx = Receiver(store)
        for _, body in tr.sent:
            rx.handle(body)
    code, _, err = host("report", "--db", tmp_path / "named.db", "--out", tmp_path / "rep", "--quiet")
    assert code == 0, err
    (drawn_path,) = (tmp_path / "rep").glob("*_correlated.png")
    drawn = read_image(drawn_path)
    # R, G, B of the picture follow the bands named red, green, blue: the materials' order in each
    for channel, band in enumerate((2, 1, 0)):
        means = [float(drawn[..., channel][labels == lab].mean()) for lab in np.unique(labels)]
        real = [float(frame[..., band][labels == lab].mean()) for lab in np.unique(labels)]
        assert np.argsort(means).tolist() == np.argsort(real).tolist(), (channel, means, real)


def test_fit_names_a_tiffs_bands_for_the_models_and_the_reports_colours(host, spectral, tmp_path):
    d, image, mask = spectral
    names = ",".join(NAMES)
    code, out, err = host("fit", d / "view.tif", "--mask", d / "mask.png", "--band-names", names, "--json")
    assert code == 0, err
    assert tuple(json.loads(out)["bands"]) == NAMES
    code, _, err = host("fit", d / "view.tif", "--mask", d / "mask.png", "--band-names", names, "--angle", 60,
                        "--db", tmp_path / "named.db")
    assert code == 0, err
    code, _, err = host("report", "--db", tmp_path / "named.db", "--out", tmp_path / "rep", "--quiet")
    assert code == 0, err
    drawn = read_image(tmp_path / "rep" / "robothost_060.0_0_correlated.png")
    for channel, band in enumerate((2, 1, 0)):  # R, G, B from the bands named red, green, blue
        means = [float(drawn[..., channel][mask == lab].mean()) for lab in np.unique(mask)]
        real = [float(image[..., band][mask == lab].mean()) for lab in np.unique(mask)]
        assert np.argsort(means).tolist() == np.argsort(real).tolist(), (channel, means, real)
    for args, words in ((("--band-names", "a,b"), "2 names for an image of 6 bands"),
                        (("--band-names", "a,a,b,c,d,e"), "a name repeats"),
                        (("--band-names", names, "--space", "rgb"), "use it with --space raw")):
        code, _, err = host("fit", d / "view.tif", "--mask", d / "mask.png", *args)
        assert code == 2 and words in err and len(err.strip().splitlines()) == 1, err


def test_ingest_names_a_folders_raw_bands_and_refuses_a_count_that_does_not_fit(host, spectral, tmp_path):
    d, image, _ = spectral
    folder = tmp_path / "shots"
    folder.mkdir()
    for i in range(2):
        tifffile.imwrite(folder / f"v{i}.tif", image, photometric="minisblack", planarconfig="contig")
    code, _, err = host("ingest", folder, "--layout", "folder", "--db", tmp_path / "d.db", "--workers", 0,
                        "--quiet", "--band-names", ",".join(NAMES))
    assert code == 0, err
    with Store.open(tmp_path / "d.db") as store:
        assert [c.band_names for c in store.captures()] == [NAMES, NAMES]
    code, _, err = host("ingest", folder, "--layout", "folder", "--db", tmp_path / "e.db", "--workers", 0,
                        "--quiet", "--band-names", "red,green,blue")
    assert code == 2 and "3 band names for its 6 raw bands" in err and len(err.strip().splitlines()) == 1, err
