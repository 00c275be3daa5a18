"""Runtime wiring: HAL body choice, segmentation methods, MASK/PCA packets, SWEEP, 16-bit bands."""
import dataclasses
import json

import cv2
import msgpack
import numpy as np
import pytest

import hal.fakes.camera as fake_camera
import hal.scene
from btf.fit.features import PcaBasis
from hal.factory import build_hal
from hal.interfaces import HalError
from onboard import config
from onboard.capture.segmentation import Segmentation
from onboard.config import ConfigError
from radio import FrameError
from radio import packets as pk
from tests.support.robots import IDLE, robot_toml


def robot(scene: str, *changes: dict, idle: bool = True) -> str:
    """A fake robot on `scene` at 60 x 80 (no skip rule of its own), waiting for commands unless not `idle`."""
    return robot_toml({"hal": {"scene": scene, "size": [60, 80]}, "skip": None}, *changes, *((IDLE,) if idle else ()))


ISODATA = {"segment": {"method": "isodata", "split_std": 12, "subsample": 2000}}


def load(tmp_path, text):
    path = tmp_path / "robot.toml"
    path.write_text(text)
    return config.load(path)


def decoded(tr):
    return [pk.decode(body) for _, body in tr.sent]


def command(rt, tr, cid, name, **args):
    tr.receive(pk.encode(pk.CommandPacket(cid, name, args)))
    rt.step()
    return {p.command_id: p for p in decoded(tr) if isinstance(p, (pk.AckPacket, pk.NackPacket))}[cid]


def test_hal_body_is_never_a_silent_fake(tmp_path, monkeypatch):
    cfg = load(tmp_path, "[segment]\nmethod = 'isodata'\n")
    assert cfg.hal.body == ""
    with pytest.raises(HalError, match="no HAL body chosen"):
        build_hal(cfg.hal, env={})
    assert build_hal(cfg.hal, env={"BTF_HAL": "fake"}).body.value == "fake"
    with pytest.raises(ConfigError, match="needs hal.body = 'fake'"):
        monkeypatch.delenv("BTF_HAL", raising=False)
        load(tmp_path, "[segment]\nmethod = 'scene'\n")
    example = config.load("examples/robot.toml")
    assert example.hal.body == "fake"  # the example names its fake body


def test_scene_labels_come_from_the_frame_the_camera_rendered(fake_robot, monkeypatch):
    rt, tr = fake_robot(robot("mixed"))
    calls = []
    real = fake_camera.scene_radiance  # the fake camera renders through it (then exposes)
    monkeypatch.setattr(fake_camera, "scene_radiance", lambda *a, **k: calls.append(1) or real(*a, **k))
    monkeypatch.setattr(hal.scene, "render", lambda *a, **k: pytest.fail("rendered a second time"))
    monkeypatch.setattr(hal.scene, "scene_radiance", lambda *a, **k: pytest.fail("rendered a second time"))
    rt.boot()
    command(rt, tr, 1, pk.CommandName.CAPTURE)
    assert len(calls) == 1
    assert rt.captures.last_labels is rt.hal.camera.last_mask
    assert set(np.unique(rt.captures.last_labels)) == {1, 2}


def test_mask_is_sent_when_the_label_map_changes_and_on_request(fake_robot):
    rt, tr = fake_robot(robot("mixed"))
    rt.boot()
    C = pk.CommandName
    masks = lambda: [p for p in decoded(tr) if isinstance(p, pk.MaskPacket)]
    assert command(rt, tr, 1, C.SEND_MASK, seq=1).extras["next_capture"] is True  # the next capture's
    command(rt, tr, 2, C.CAPTURE)
    command(rt, tr, 3, C.CAPTURE)  # same view, same map: not sent again
    assert len(masks()) == 1
    # the change check compares the very map the MASK packet carried
    np.testing.assert_array_equal(masks()[0].label_map(), rt.pipeline.segmenter.segmenter.small)
    command(rt, tr, 4, C.SEND_MASK, seq=2)
    assert len(masks()) == 2 and masks()[-1].seq == 2
    command(rt, tr, 5, C.GOTO, elevation=30.0, azimuth=40.0)
    command(rt, tr, 6, C.CAPTURE)  # another view of the mixed plate: another map
    assert len(masks()) == 3


def test_mask_png_labels_the_frames(fake_robot, tmp_path):
    lab = np.zeros((60, 80), np.uint8)
    lab[:, 40:] = 3
    cv2.imwrite(str(tmp_path / "mask.png"), lab)
    rt, tr = fake_robot(robot("black", {"segment": {"method": "mask", "mask": "mask.png", "n_labels": 4}}))
    rt.boot()
    command(rt, tr, 1, pk.CommandName.CAPTURE)
    models = [p for p in decoded(tr) if isinstance(p, pk.ModelsPacket)]
    assert {lab.label for lab in models[0].labels} == {0, 3}
    assert [p for p in decoded(tr) if isinstance(p, pk.MaskPacket)]
    cv2.imwrite(str(tmp_path / "mask.png"), lab + 4)
    with pytest.raises(ConfigError, match="above the 4 labels"):
        Segmentation(rt.cfg, rt.hal)


def test_isodata_palette_survives_a_restart(fake_robot):
    text = robot("mixed", ISODATA)
    rt, tr = fake_robot(text)
    rt.boot()
    command(rt, tr, 1, pk.CommandName.CAPTURE)
    saved = json.loads((rt.cfg.state_dir / "palette.json").read_text())
    assert saved["entries"] == [list(e) for e in rt.pipeline.segmenter.segmenter.palette.entries]
    first = rt.captures.last_labels.copy()
    rt.outbox.close()
    rt2, tr2 = fake_robot(text)  # same state directory
    assert {**rt2.pipeline.segmenter.segmenter.palette.to_record(), "features": "rgb:"} == saved
    rt2.boot()
    command(rt2, tr2, 2, pk.CommandName.CAPTURE)
    assert (rt2.captures.last_labels == first).mean() > 0.99  # the same view keeps its labels
    (rt.cfg.state_dir / "palette.json").write_text("{not json")
    with pytest.raises(ConfigError, match="palette file"):
        Segmentation(rt.cfg, rt.hal)


def test_a_palette_saved_for_other_bands_is_replaced_not_matched(fake_robot):
    rt, tr = fake_robot(robot("mixed", ISODATA))
    rt.boot()
    assert isinstance(command(rt, tr, 1, pk.CommandName.CAPTURE), pk.AckPacket)
    rt.outbox.close()
    # The same state directory, now fitting gray: 3-band colour entries cannot label it.
    gray = robot("mixed", ISODATA, {"features": {"space": "gray"}})
    rt2, tr2 = fake_robot(gray)
    assert rt2.pipeline.segmenter.segmenter.palette.entries == []
    rt2.boot()
    ack = command(rt2, tr2, 2, pk.CommandName.CAPTURE)
    assert isinstance(ack, pk.AckPacket) and ack.extras["models"] >= 1
    saved = json.loads((rt.cfg.state_dir / "palette.json").read_text())
    assert saved["features"] == "gray:" and all(len(e) == 1 for e in saved["entries"])


def test_sweep_command_takes_start_stop_step_and_optional_azimuths(fake_robot):
    rt, tr = fake_robot(robot("black"))
    rt.boot()
    ack = command(rt, tr, 1, pk.CommandName.SWEEP, start=80.0, stop=60.0, step=10.0)
    assert ack.extras["poses"] == 3
    rt.run(lambda r: r.idle())
    models = [p for p in decoded(tr) if isinstance(p, pk.ModelsPacket)]
    assert [p.commanded for p in models] == [(80.0, 0.0), (70.0, 0.0), (60.0, 0.0)]
    assert command(rt, tr, 2, pk.CommandName.SWEEP, start=90, stop=70, step=10,
                   azimuths=[0.0, 90.0]).extras["poses"] == 6
    assert isinstance(command(rt, tr, 3, pk.CommandName.ABORT), pk.AckPacket)
    assert rt.progress.active is False


def test_sweep_command_schema_refuses_mixed_or_missing_forms():
    C = pk.CommandName
    for args in ({"start": 90.0, "stop": 30.0}, {"start": 90.0, "stop": 30.0, "step": 10.0, "elevations": [1.0]},
                 {"azimuths": [0.0]}, {"start": 90.0, "stop": 30.0, "step": 0.0}):
        raw = msgpack.packb([pk.SCHEMA_VERSION, int(pk.Kind.COMMAND), 1, int(C.SWEEP), args])
        with pytest.raises(FrameError, match="SWEEP|sweep step"):
            pk.decode(raw)
    ok = pk.decode(pk.encode(pk.CommandPacket(1, C.SWEEP, {"start": 90, "stop": 30, "step": 10})))
    assert ok.args == {"start": 90.0, "stop": 30.0, "step": 10.0}


def test_pca_basis_goes_once_with_the_scene_and_survives_a_restart(fake_robot):
    text = robot("mixed", {"features": {"space": "pca"}})
    rt, tr = fake_robot(text)
    rt.boot()
    for cid in (1, 2):
        command(rt, tr, cid, pk.CommandName.CAPTURE)
    models = [p for p in decoded(tr) if isinstance(p, pk.ModelsPacket)]
    basis = PcaBasis.from_extras(models[0].extras)
    assert basis == rt.pipeline.pca and PcaBasis.from_extras(models[1].extras) is None
    rt.outbox.close()
    rt2, tr2 = fake_robot(text)
    assert rt2.pipeline.pca == basis
    rt2.boot()
    command(rt2, tr2, 2, pk.CommandName.CAPTURE)
    assert all(PcaBasis.from_extras(p.extras) is None for p in decoded(tr2) if isinstance(p, pk.ModelsPacket))


def test_malformed_pca_extras_are_refused():
    basis = PcaBasis.fit(np.random.default_rng(0).integers(0, 256, (20, 20, 3), dtype=np.uint8))
    good = basis.to_extras()
    assert PcaBasis.from_extras(good) == basis
    for bad in ({**good, "pca_rotation": good["pca_rotation"][:-1]}, {"pca_mean": good["pca_mean"]},
                {**good, "pca_scale": ["x", 1.0, 1.0]}, {**good, "pca_scale": [0.0, 1.0, 1.0]}):
        with pytest.raises(ValueError, match="pca"):
            PcaBasis.from_extras(bad)


def test_sixteen_bit_multispectral_bands_through_the_runtime(fake_robot, tmp_path):
    raw = {"space": "raw", "bands": ["B0", "B3"], "bins_16bit": 65536}
    text = robot("mixed", {"features": raw, "hal": {"pixel_format": "MSP6"}})
    rt, tr = fake_robot(text)
    cam = rt.hal.camera
    rt.boot()
    assert isinstance(command(rt, tr, 1, pk.CommandName.CAPTURE), pk.AckPacket)
    models = [p for p in decoded(tr) if isinstance(p, pk.ModelsPacket)]
    assert models[0].levels == 65536 and models[0].bands == ("B0", "B3")
    frame = cam.capture()
    for (label, band), model in models[0].models.items():
        values = frame[..., (0, 3)[band]][cam.last_mask == label].astype(float)
        lo, hi = np.percentile(values, [1, 99])
        med = float(model.ppf(0.5))
        assert np.isfinite(med) and lo - 32 <= med <= hi + 32  # within a bin of the data
    rt_bad, tr_bad = fake_robot(robot("mixed", {"features": {**raw, "bands": ["B9"]}, "hal": {"pixel_format": "MSP6"}}))
    nack = command(rt_bad, tr_bad, 2, pk.CommandName.CAPTURE)
    assert isinstance(nack, pk.NackPacket) and "unknown band" in nack.text


def test_scene_labels_are_a_capability_a_hal_without_ground_truth_lacks(tmp_path):
    cfg = load(tmp_path, robot("mixed", idle=False))
    hal_ = build_hal(cfg.hal)
    assert hal_.ground_truth is hal_.camera  # the fake camera knows what it rendered
    with pytest.raises(ConfigError, match="segment.method = 'scene' needs ground truth"):
        Segmentation(cfg, dataclasses.replace(hal_, ground_truth=None))
    emulated = build_hal(dataclasses.replace(cfg.hal, body="emulated"))
    try:
        assert emulated.ground_truth is None
    finally:
        emulated.close()
