"""Bracketing a saturated region, synthesis at a chosen exposure, and drift normalised by the
grey reference card (`compare` and `synth`)."""
import dataclasses
import json

import numpy as np
import pytest

from benchmarks.clipped_truth import exposure_saturating, hidden_error, host_models, robot_pipeline, unclipped
from btf.capture_settings import CaptureSettings, scaled
from btf.johnson import Family, Johnson
from hal.interfaces import ViewAngles
from hal.scene import Label, render
from onboard.link.bodies import models_body
from radio import packets as pk
from tools.analysis.radiometry import RadiometryWarning, adjusted
from tools.cli import main as host
from tools.data.images import read_image, write_image, write_mask
from tools.station.receiver import Receiver
from tools.store.database import Store

SIZE = (240, 320)
VIEW = ViewAngles(90.0)


@pytest.fixture(scope="module")
def bright():
    """The field straight down, exposed so that 40% of the tan sand's red band clips at 255,
    captured by the robot with censoring alone and with bracketing (limit 20%)."""
    exposure = exposure_saturating("field", VIEW, SIZE, Label.TAN_SAND, 0, 0.40)
    censored = robot_pipeline("field", SIZE, exposure, 0.0).shoot(VIEW, VIEW)
    bracketed = robot_pipeline("field", SIZE, exposure, 0.2).shoot(VIEW, VIEW)
    return exposure, censored, bracketed


def test_bracketing_halves_the_error_of_a_region_forty_percent_saturated(bright):
    exposure, censored, bracketed = bright
    assert censored.results[(Label.TAN_SAND, 0)].censored_high == pytest.approx(0.40, abs=0.01)
    assert censored.camera.brackets == () and not censored.camera.bracketed
    (shorter,) = bracketed.camera.brackets
    assert shorter < 0.6 * exposure and bracketed.camera.bracketed[Label.TAN_SAND] == 1
    assert max(bracketed.results[(Label.TAN_SAND, b)].censored_high for b in range(3)) < 0.01
    assert Label.GRASS not in bracketed.camera.bracketed  # nothing of it clips: not taken again
    truth, mask = unclipped("field", VIEW, SIZE, exposure)
    alone = hidden_error(host_models(censored), truth, mask, Label.TAN_SAND)
    with_brackets = hidden_error(host_models(bracketed), truth, mask, Label.TAN_SAND)
    assert with_brackets <= 0.5 * alone, (alone, with_brackets)


def test_the_packet_says_which_exposure_fitted_each_region_and_the_host_scales_it_back(bright, tmp_path):
    exposure, _, bracketed = bright
    _, body = models_body(1, 7, 0.0, "rgb", bracketed)
    p = pk.decode(body)
    assert p.camera.bracketed == bracketed.camera.bracketed
    assert p.camera.exposure_of(Label.TAN_SAND) == round(bracketed.camera.brackets[0])
    with Store.open(tmp_path / "b.db") as store:
        Receiver(store, scene="field").handle(body)
        (cap,) = store.captures()
        at_own = store.models_by_angle()[cap.elevation]
    factor = p.camera.exposure_us / p.camera.exposure_of(Label.TAN_SAND)
    raw = p.models[(Label.TAN_SAND, 0)]
    assert at_own[(Label.TAN_SAND, 0)].ppf(0.5) == pytest.approx(factor * raw.ppf(0.5), rel=1e-9)
    assert at_own[(Label.GRASS, 0)] == p.models[(Label.GRASS, 0)]  # not bracketed: as fitted


def test_synth_at_a_chosen_exposure_clips_what_a_longer_one_would(bright, tmp_path, capsys):
    exposure, _, bracketed = bright
    _, body = models_body(1, 7, 0.0, "rgb", bracketed)
    db = tmp_path / "b.db"
    with Store.open(db) as store:
        Receiver(store, scene="field").handle(body)
    truth_mask = render("field", VIEW, size=SIZE).mask
    write_mask(tmp_path / "mask.png", truth_mask)
    shown = {}
    for name, extra in (("own", []), ("short", ["--exposure", str(exposure / 4)]), ("long", ["--exposure", str(4 * exposure)])):
        out = tmp_path / f"{name}.png"
        assert host(["synth", "--db", str(db), "--mask", str(tmp_path / "mask.png"), "--angle", "90",
                     "--out", str(out), *extra]) == 0
        img = read_image(out)[truth_mask == Label.TAN_SAND][:, 0]
        shown[name] = (float(np.mean(img == 255)), float(np.median(img)))
    # At its own exposure the tan sand clips as the camera saw it (40%); 4x shorter, nothing clips.
    assert shown["own"][0] == pytest.approx(0.40, abs=0.04)
    assert shown["short"][0] < 0.01 and shown["long"][0] > 0.9
    real = render("field", VIEW, size=SIZE, exposure=exposure / 4 / 10_000).image[truth_mask == Label.TAN_SAND][:, 0]
    assert shown["short"][1] == pytest.approx(float(np.median(real)), abs=3)
    assert host(["synth", "--db", str(db), "--mask", str(tmp_path / "mask.png"), "--angle", "90",
                 "--out", str(tmp_path / "x.png"), "--exposure", "0"]) == 2
    assert "--exposure 0: must lie in 1..100000000 microseconds" in capsys.readouterr().err


def _drifting_sweep(tmp_path):
    """Three captures of the white plate with the grey card; the lamp is 20% brighter for the
    last one while the camera stays at 10 ms."""
    pipe = robot_pipeline("white", (120, 160), 10_000.0, 0.0, reference=True)
    db = tmp_path / "drift.db"
    with Store.open(db) as store:
        rx = Receiver(store, scene="white")
        for seq, (elevation, lamp) in enumerate(((90.0, 1.0), (75.0, 1.0), (60.0, 1.2)), start=1):
            view = ViewAngles(elevation)
            pipe.move(view)
            pipe.lock.set_exposure(10_000.0 * lamp)  # more light on the sensor ...
            cap = pipe.shoot(view, view)
            cap = dataclasses.replace(cap, camera=dataclasses.replace(cap.camera, exposure_us=10_000.0))  # ... same 10 ms
            rx.handle(models_body(1, seq, 0.0, "rgb", cap)[1])
            assert cap.camera.reference is not None
    return db


def test_normalising_by_the_reference_takes_out_a_lamp_that_drifted(tmp_path):
    db = _drifting_sweep(tmp_path)
    with Store.open(db) as store:
        drifted = min(c.elevation for c in store.captures())  # filed under the tracker's angle
    truth = render("white", ViewAngles(60.0), size=(120, 160), reference=True)
    write_mask(tmp_path / "mask.png", truth.mask)
    true_mean = truth.image[truth.mask == Label.WHITE_SAND].mean()
    means = {}
    for name, extra in (("as measured", []), ("normalised", ["--normalise-reference"])):
        out = tmp_path / f"{name}.png"
        assert host(["synth", "--db", str(db), "--mask", str(tmp_path / "mask.png"), "--angle", str(drifted),
                     "--out", str(out), *extra]) == 0
        means[name] = read_image(out)[truth.mask == Label.WHITE_SAND].mean()
    assert means["as measured"] / true_mean == pytest.approx(1.2, abs=0.03)
    assert means["normalised"] / true_mean == pytest.approx(1.0, abs=0.03)


def test_compare_with_the_reference_label_cancels_a_change_of_exposure(tmp_path, capsys):
    ref = render("field", ViewAngles(70.0), size=(120, 160), reference=True)
    brighter = render("field", ViewAngles(70.0), size=(120, 160), reference=True, exposure=1.25)
    write_image(tmp_path / "ref.png", ref.image)
    write_image(tmp_path / "test.png", brighter.image)
    write_mask(tmp_path / "mask.png", ref.mask)
    totals = {}
    for name, extra in (("plain", []), ("normalised", ["--reference-label", "7"])):
        assert host(["compare", str(tmp_path / "ref.png"), str(tmp_path / "test.png"), "--mask",
                     str(tmp_path / "mask.png"), "--json", *extra]) == 0
        doc = json.loads(capsys.readouterr().out)
        totals[name] = doc["total"]["hist_diff"]
    assert doc["reference"]["label"] == 7 and doc["reference"]["factors"] == pytest.approx([0.8] * 3, abs=0.01)
    assert totals["normalised"] < 0.25 * totals["plain"]
    assert host(["compare", str(tmp_path / "ref.png"), str(tmp_path / "test.png"), "--reference-label", "7"]) == 2
    assert "needs --mask" in capsys.readouterr().err


def test_scaled_models_and_captures_that_cannot_be_normalised():
    m = Johnson(Family.SU, 0.3, 1.2, 100.0, 20.0)
    assert scaled(m, 2.0).ppf(0.9) == pytest.approx(2.0 * m.ppf(0.9))
    assert scaled(Johnson.constant(7.0), 3.0).xi == 21.0
    with pytest.raises(ValueError):
        scaled(m, 0.0)
    models = {(1, 0): m}
    with pytest.warns(RadiometryWarning, match="no reference level"):
        out = adjusted(models, CaptureSettings(10_000.0, 1.0), target=(100.0,), base_exposure_us=10_000.0)
    assert out[(1, 0)] == m
    clipped = CaptureSettings(10_000.0, 1.0, reference=(250.0,), reference_clipped=0.3)
    with pytest.warns(RadiometryWarning, match="clipped"):
        adjusted(models, clipped, target=(100.0,))
