"""The HTML report: images, histograms and tables from a database; bad databases refused."""
import numpy as np
import pytest

from radio import packets as pk
from tests.support.packets import filled_database, models_body
from tests.support.spaces import stored_plate
from tools.cli import main
from tools.report.document import write_report
from tools.station.receiver import Receiver
from tools.store.database import Store


def test_report_has_the_captures_models_synthetic_images_and_histograms(tmp_path):
    db = filled_database(tmp_path / "scene.db")
    with Store.open(db) as s:
        html = write_report(s, tmp_path / "rep").read_text()
    assert html.count("<div class=capture ") == 2  # one section per capture
    assert "SU" in html or "SB" in html or "SL" in html or "NORMAL" in html.upper()
    pngs = sorted(p.name for p in (tmp_path / "rep").glob("*.png"))
    assert len([p for p in pngs if p.endswith("_synthetic.png")]) == 2
    assert len([p for p in pngs if p.endswith("_hist.png")]) == 2


def test_report_cli_refuses_missing_corrupt_and_empty_databases(tmp_path, capsys):
    assert main(["report", "--db", str(tmp_path / "none.db"), "--out", str(tmp_path / "r")]) == 2
    bad = tmp_path / "bad.db"
    bad.write_bytes(b"garbage" * 50)
    assert main(["report", "--db", str(bad), "--out", str(tmp_path / "r")]) == 2
    assert bad.read_bytes() == b"garbage" * 50
    with Store.open(tmp_path / "empty.db"):
        pass
    assert main(["report", "--db", str(tmp_path / "empty.db"), "--out", str(tmp_path / "r")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and "no such file" in err[0] and "not an SQLite" in err[1] and "no captures" in err[2]
    assert main(["report", "--db", str(filled_database(tmp_path / "ok.db")), "--out", str(tmp_path / "r")]) == 0
    assert (tmp_path / "r" / "index.html").is_file()


def test_captures_with_dependence_show_independent_and_correlated_synthesis_beside_measured(tmp_path):
    from hal.interfaces import ViewAngles
    from hal.scene import render
    from tests.support.packets import dependence_body

    with Store.open(tmp_path / "scene.db") as s:
        rx = Receiver(s, scene="mixed")
        rx.handle(pk.encode_mask(models_body(1, 60.0)[2], robot_id=3, seq=1))
        rx.handle(dependence_body(1, 60.0)[0])
        rx.handle(models_body(2, 70.0)[0])  # no dependence: independent synthesis only
        page = write_report(s, tmp_path / "rep",
                            measured=lambda c: render(c.scene, ViewAngles(c.elevation, 0.0), (40, 48), seed=0).image)
        html = page.read_text()
    pngs = {p.name for p in (tmp_path / "rep").glob("*.png")}
    assert {p for p in pngs if p.endswith("_correlated.png")} == {"mixed_060.2_1_correlated.png"}
    assert {"mixed_060.2_1_measured.png", "mixed_060.2_1_synthetic.png"} <= pngs
    first = html[html.index("seq 1)"):html.index("seq 2)")]
    assert first.index("measured") < first.index("independent pixels") < first.index("grain and band correlation")
    from tools.data.images import read_image

    meas, ind, cor = (read_image(tmp_path / "rep" / f"mixed_060.2_1_{k}.png") for k in ("measured", "synthetic", "correlated"))

    mask = models_body(1, 60.0)[2]
    region = mask == np.bincount(mask.ravel()).argmax()

    def rg(img):  # red-green correlation inside the largest region: bands drawn apart lose it
        return np.corrcoef(img[region][:, 0].astype(float), img[region][:, 1].astype(float))[0, 1]
    assert abs(rg(cor) - rg(meas)) < 0.1 < abs(rg(ind) - rg(meas))


def test_a_dataset_capture_is_shown_beside_the_image_it_was_fitted_from(tmp_path):
    """The report and the page find a dataset's frame where ingest found it (`Frames`)."""
    from btf.fit.fitter import FrameFitter
    from hal.interfaces import ViewAngles
    from hal.scene import render
    from tools.data.images import read_image, write_image
    from tools.report.capture_views import Frames

    view = render("mixed", ViewAngles(50.0, 0.0), (40, 48), seed=0)
    write_image(tmp_path / "plate.png", view.image)
    fitter = FrameFitter(4, 3)
    fitter.add(view.image, view.mask)
    robot = f"dataset:{tmp_path}"
    with Store.open(tmp_path / "scene.db") as s:
        s.add_capture(robot, 1, 0.0, None, (50.0, 0.0), "rgb", ("R", "G", "B"), fitter.fit(),
                      scene="plates", source="plate.png")
        s.add_mask(f"{robot}/1", view.mask, robot)
        html = write_report(s, tmp_path / "rep", measured=Frames()).read_text()
        (cap,) = s.captures()
    assert np.array_equal(read_image(tmp_path / "rep" / "plates_050.0_1_measured.png"), view.image)
    assert html.index("measured") < html.index("synthesized")
    (tmp_path / "plate.png").unlink()  # a dataset moved away: no frame, no error
    assert Frames()(cap) is None


def test_image_files_stay_in_the_report_folder_and_two_captures_never_share_one(tmp_path):
    """Scene and robot names become file names: a path in them stays inside the folder, and two
    datasets whose folders share a name (the same scene, angle and number) keep their own images."""
    from btf.fit.fitter import FrameFitter
    from hal.interfaces import ViewAngles
    from hal.scene import render
    from tools.data.images import read_image

    views = [render(scene, ViewAngles(50.0, 0.0), (40, 48), seed=0) for scene in ("mixed", "white", "black", "mixed")]
    out = tmp_path / "deep" / "rep"
    out.parent.mkdir()
    with Store.open(tmp_path / "scene.db") as s:
        for k, (robot, scene) in enumerate([("dataset:/a/photos", "photos"), ("dataset:/b/photos", "photos"),
                                            ("7", "../escaped"), ("cam/1", "")]):
            fitter = FrameFitter(4, 3)
            fitter.add(views[k].image, views[k].mask)
            s.add_capture(robot, 1, 0.0, None, (50.0, 0.0), "rgb", ("R", "G", "B"), fitter.fit(), scene=scene)
            s.add_mask(f"{robot}/1", views[k].mask, robot)
        write_report(s, out)
    assert not list(tmp_path.glob("*.png")) and not list((tmp_path / "deep").glob("*.png"))
    pngs = sorted(p.name for p in out.glob("*_synthetic.png"))
    assert len(pngs) == 4 and all("/" not in p and not p.startswith(".") for p in pngs), pngs
    first, second = (read_image(out / p) for p in pngs if p.startswith("photos_"))
    assert not np.array_equal(first, second)  # the white plate's and the mixed one's, each its own


@pytest.mark.parametrize("space", ["pca", "hsv"])
def test_hsv_and_pca_captures_are_drawn_as_pictures_in_the_scenes_colours(host, tmp_path, space):
    """Their syntheses turned back into RGB (pca through the stored basis) look like the photograph."""
    from tools.data.images import read_image

    db, photo, labels = stored_plate(host, tmp_path, space)
    with Store.open(db) as s:
        write_report(s, tmp_path / "rep")
    drawn = {k: read_image(tmp_path / "rep" / f"robothost_050.0_0_{k}.png") for k in ("synthetic", "correlated")}
    for name, image in drawn.items():
        assert image.shape == photo.shape, name
        for label in np.unique(labels):
            region = labels == label
            assert np.abs(image[region].mean(0) - photo[region].mean(0)).max() < 10, (name, label)
