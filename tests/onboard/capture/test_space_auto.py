"""`[features] space = "auto"`: the robot resolves its feature space once per scene from the
first frame, by the host's criterion, says why in the first MODELS, keeps it across a restart,
and the station records it."""
from __future__ import annotations

import json

import numpy as np
import pytest

from btf.fit import space_choice
from btf.fit.features import compute
from onboard import config
from onboard.capture import space_auto
from onboard.config import ConfigError
from radio import packets as pk
from tests.support.images import public_photos
from tests.support.robots import IDLE, robot_toml
from tests.support.runtime import decoded
from tools.station.receiver import Receiver
from tools.store.database import Store

AUTO = {"features": {"space": "auto"}}


def robot(scene: str, *changes: dict) -> str:
    """A fake robot on `scene` at 60 x 80, waiting for commands."""
    return robot_toml({"hal": {"scene": scene, "size": [60, 80]}, "skip": None}, *changes, IDLE)


def command(rt, tr, cid, name, **args):
    tr.receive(pk.encode(pk.CommandPacket(cid, name, args)))
    rt.step()


def test_a_colour_frame_is_judged_in_rgb_hsv_and_pca_and_a_one_band_or_deep_frame_is_not():
    photo = public_photos(96)["astronaut"]
    spec, choice = space_auto.resolve(photo, classes=4)
    assert spec.space.value == choice.space and choice.space in space_auto.COLOUR_SPACES
    assert choice.reason.startswith(choice.space)
    # every other frame gets a space that reads it, at its own depth: a mono or thermal camera's
    # one band is gray, 16-bit colour and a multi-spectral camera's bands are raw
    deep = photo.astype(np.uint16) * 257
    cases = [(photo[..., :1], "gray", ("Y",), 256), (deep[..., :1], "gray", ("Y",), 65536),
             (photo[..., 0], "gray", ("Y",), 256),
             (deep, "raw", ("B0", "B1", "B2"), 65536),
             (np.dstack([photo, photo[..., :2]]), "raw", ("B0", "B1", "B2", "B3", "B4"), 256)]
    for frame, space, bands, levels in cases:
        spec, choice = space_auto.resolve(frame, 4)
        features = compute(frame, spec)
        assert (choice.space, features.band_names, features.levels) == (space, bands, levels), choice.reason
        assert np.array_equal(features.data, frame.reshape(features.data.shape)) and choice.reason.startswith(space)


NAMES = ("blue", "green", "red", "rededge", "nir", "thermal")


@pytest.mark.parametrize("names", [(), NAMES])
def test_a_multi_spectral_camera_on_auto_sends_its_own_bands_and_says_why(fake_robot, tmp_path, names):
    text = robot("mixed", AUTO, {"hal": {"pixel_format": "MSP6"}, "features": {"band_names": list(names)}})
    rt, tr = fake_robot(text)
    rt.boot()
    command(rt, tr, 1, pk.CommandName.CAPTURE)
    (models,) = [p for p in decoded(tr) if isinstance(p, pk.ModelsPacket)]
    assert models.feature_space == "raw" and models.bands == (names or tuple(f"B{k}" for k in range(6)))
    assert models.levels == 65536 and models.extras[space_choice.EXTRA_KEY].startswith("raw: a frame of 6 16-bit")
    rt.outbox.close()
    again, tr2 = fake_robot(text)  # a restart keeps the space chosen, and the names with it
    again.boot()
    command(again, tr2, 2, pk.CommandName.CAPTURE)
    (kept,) = [p for p in decoded(tr2) if isinstance(p, pk.ModelsPacket) and p.seq > models.seq]
    assert (kept.feature_space, kept.bands) == ("raw", models.bands)


def test_the_judged_lattice_is_bounded_at_any_frame_size():
    frame = np.zeros((1000, 1500, 3), np.uint8)
    sub = space_auto.lattice(frame, 1 << 16)
    assert sub.shape[0] * sub.shape[1] <= 1 << 16 and sub.shape[0] >= 150
    assert space_auto.lattice(frame[:100, :100]).shape == (100, 100, 3)


def test_auto_with_bands_is_refused(tmp_path):
    path = tmp_path / "robot.toml"
    path.write_text(robot("mixed", {"features": {"space": "auto", "bands": ["R"]}}))
    with pytest.raises(ConfigError, match="features.space = 'auto' leave it empty"):
        config.load(path)


def test_the_robot_chooses_once_says_why_once_and_keeps_it_across_a_restart(fake_robot, tmp_path):
    text = robot("mixed", AUTO)
    rt, tr = fake_robot(text)
    rt.boot()
    for cid in (1, 2):
        command(rt, tr, cid, pk.CommandName.CAPTURE)
    models = [p for p in decoded(tr) if isinstance(p, pk.ModelsPacket)]
    first, second = models
    reason = first.extras[space_choice.EXTRA_KEY]
    assert first.feature_space == second.feature_space != "auto" and reason.startswith(first.feature_space)
    assert space_choice.EXTRA_KEY not in second.extras
    # the station stores the reason with the capture; the later capture of the scene inherits it
    with Store.open(tmp_path / "s.db") as store:
        rx = Receiver(store)
        items = [rx.handle(body) for _, body in tr.sent]
        assert any("chosen automatically" in i.text for i in items if i is not None)
        caps = sorted(store.captures(), key=lambda c: c.sequence)
        assert [store.space_choice(c.id) for c in caps] == [reason, reason]
    rt.outbox.close()
    rt2, tr2 = fake_robot(text)
    rt2.boot()
    command(rt2, tr2, 3, pk.CommandName.CAPTURE)
    again = [p for p in decoded(tr2) if isinstance(p, pk.ModelsPacket) and p.seq > second.seq]
    assert [p.feature_space for p in again] == [first.feature_space]
    assert space_choice.EXTRA_KEY not in again[0].extras
    assert json.loads(rt2.outbox.state("space_auto"))["space"] == first.feature_space
