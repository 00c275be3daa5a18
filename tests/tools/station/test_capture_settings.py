"""The settings a capture was taken with: [camera] keys, the lock the robot insists on, and the
round trip robot -> MODELS -> database -> `btf-host decode`."""
import json
import sqlite3

import pytest
from hypothesis import given
from hypothesis import strategies as st

from btf.capture_settings import CaptureSettings
from btf.codec import PercentileCodec
from hal.factory import build_hal
from onboard import config
from onboard.config import ConfigError
from radio import FrameError
from radio import packets as pk
from radio.auth import MemoryCounterStore
from radio.keys import load_key, write_key
from radio.link import Link
from radio.packets.camera import decode_camera, encode_camera
from tests.support.databases import older_database
from tests.support.robots import IDLE, robot_toml
from tools.analysis.radiometry import settings_json
from tools.cli import main as host
from tools.station.receiver import Receiver
from tools.store.database import CorruptDatabase, Store

FIELD = {"hal": {"scene": "field", "size": [60, 80], "reference": True}, "sweep": {"start": 90, "stop": 80, "step": 10}}
LOCKED = {"camera": {"exposure": 20000, "gain": 2, "white_balance": "5000K", "reference_label": 7}}
CODEC = PercentileCodec.for_levels(256)


def decoded(tr):
    return [pk.decode(body) for _, body in tr.sent]


def models(tr):
    return [p for p in decoded(tr) if isinstance(p, pk.ModelsPacket)]


def sweep(rt):
    rt.run(lambda r: r.progress is not None and r.idle())


# -- the wire ------------------------------------------------------------------------------

levels = st.integers(128, 65535).map(lambda c: CODEC.decode([c])[0])  # values the codec holds exactly
settings = st.builds(
    lambda reference, clipped, **kw: CaptureSettings(reference=reference,
                                                     reference_clipped=0.0 if reference is None else clipped, **kw),
    exposure_us=st.one_of(st.none(), st.integers(1, 2**32 - 1).map(float)),
    gain=st.one_of(st.none(), st.integers(0, 2**20).map(lambda g: g / 256)),
    white_balance_kelvin=st.one_of(st.none(), st.integers(1000, 20000).map(float)),
    sensor_temperature_c=st.one_of(st.none(), st.integers(-4000, 9000).map(lambda c: c / 100)),
    unlocked=st.booleans(),
    reference=st.one_of(st.none(), st.tuples(levels, levels, levels)),
    clipped=st.integers(0, 255).map(lambda c: c / 255))


@given(settings)
def test_every_settings_record_comes_back_from_the_wire_as_it_went(s):
    blob = encode_camera(s, 3, CODEC, [1, 2])
    back, end = decode_camera(blob, 0, 3, CODEC, [1, 2])
    assert end == len(blob) and back == s


@given(st.binary(max_size=64), st.sampled_from([256, 65536]))
def test_arbitrary_bytes_are_a_settings_record_or_a_frame_error(blob, levels):
    try:
        s, end = decode_camera(blob, 0, 3, PercentileCodec.for_levels(levels), [3, 6])
    except FrameError:
        return
    assert end <= len(blob) and isinstance(s, CaptureSettings)


def test_a_locked_capture_costs_ten_bytes_and_brackets_name_their_labels():
    s = CaptureSettings(20000.0, 2.0, 5000.0, sensor_temperature_c=25.05)
    assert len(encode_camera(s, 3, CODEC, [3])) == 10
    b = CaptureSettings(40000.0, 1.0, brackets=(12000.0,), bracketed={3: 1})
    back, _ = decode_camera(encode_camera(b, 3, CODEC, [3, 6]), 0, 3, CODEC, [3, 6])
    assert back.exposure_of(3) == 12000.0 and back.exposure_of(6) == 40000.0
    with pytest.raises(ValueError, match="no models"):
        encode_camera(b, 3, CODEC, [6])


@pytest.mark.parametrize(("blob", "message"), [
    (b"", "ends inside its flags"),
    (bytes([0x18, 10, 10]), "temperature and gains"),
    (bytes([0x02, 0x80]), "ends inside a varint"),
    (bytes([0x40, 0]), "ends inside its reference levels"),
    (bytes([0x80, 1, 5, 0]), "with the capture's own"),
    (bytes([0x82, 100, 1, 5, 1, 9, 1]), "not increasing or not in the capture"),
    (bytes([0x82, 100, 1, 5, 1, 3, 2]), "outside 1..1"),
    (bytes([0x82, 100, 0]), "bracket exposures|exposures \\(1"),
])
def test_a_bad_camera_section_is_refused_naming_the_field(blob, message):
    with pytest.raises(FrameError, match=message):  # the one-byte flags robots sent before schema 5
        decode_camera(blob, 0, 3, CODEC, [3], version=4)


# -- config and the lock ---------------------------------------------------------------------

@pytest.mark.parametrize(("text", "message"), [
    ('[camera]\nexposure = "fast"\n', "exposure must be a number or 'auto'"),
    ('[camera]\nwhite_balance = "1.2"\nbracket_limit = 1.5\n', "bracket_limit must lie in"),
    ('[camera]\nbracket_limit = 0.2\n[features]\nspace = "hsv"\n', "bracket_limit needs features.space"),
    ('[camera]\nreference_label = 7\n[segment]\nmethod = "isodata"\n', "reference_label needs segment.method"),
    ('[camera]\nexposure = true\n', "must be a string"),
])
def test_bad_camera_keys_are_one_line_naming_the_key(tmp_path, text, message):
    (tmp_path / "r.toml").write_text('[hal]\nbody = "fake"\n' + text)
    with pytest.raises(ConfigError, match=message) as err:
        config.load(tmp_path / "r.toml")
    assert "\n" not in str(err.value)


def test_numbers_auto_and_hold_are_all_camera_values(tmp_path):
    (tmp_path / "r.toml").write_text('[camera]\nexposure = 2500\ngain = "auto"\nwhite_balance = "hold"\n')
    cam = config.load(tmp_path / "r.toml").camera
    assert (cam.exposure, cam.gain, cam.white_balance) == ("2500", "auto", "hold")


def test_a_camera_that_keeps_its_automatics_is_refused_unless_allow_auto_then_flagged(fake_robot, tmp_path):
    def robot(camera, where):
        hal = build_hal({"body": "fake", "scene": "field", "size": (60, 80), "camera_honours_lock": False})
        hal.camera.open(80, 60)
        return fake_robot(robot_toml(FIELD, camera), where=where, hal=hal)

    rt, tr = robot({}, tmp_path / "strict")
    sweep(rt)
    skipped = [p for p in decoded(tr) if isinstance(p, pk.StatusPacket) and p.report.sweep and p.report.sweep.skipped]
    assert not models(tr) and len(skipped) == 2
    assert all("camera does not hold its lock" in p.text and "allow_auto" in p.text for p in skipped)
    rt, tr = robot({"camera": {"allow_auto": True}}, tmp_path / "lenient")
    sweep(rt)
    assert len(models(tr)) == 2 and all(p.camera.unlocked for p in models(tr))


def test_set_changes_the_camera_at_run_time_and_the_next_capture_says_so(fake_robot):
    rt, tr = fake_robot(robot_toml(FIELD, LOCKED, IDLE))
    rt.boot()
    for cid, name, args in ((1, pk.CommandName.SET, {"key": "camera.exposure", "value": 5000}),
                            (2, pk.CommandName.SET, {"key": "camera.white_balance", "value": "warm"}),
                            (3, pk.CommandName.CAPTURE, {})):
        tr.receive(pk.encode(pk.CommandPacket(cid, name, args)))
        rt.step()
    answers = {p.command_id: p for p in decoded(tr) if isinstance(p, (pk.AckPacket, pk.NackPacket))}
    assert answers[1].extras["locked"] and "exposure 5000 us" in answers[1].extras["camera"]
    assert answers[2].reason is pk.Reason.BAD_ARGUMENT and "white balance" in answers[2].text
    assert isinstance(answers[3], pk.AckPacket)
    (p,) = models(tr)
    assert p.camera.exposure_us == 5000.0 and p.camera.gain == 2.0 and not p.camera.unlocked


# -- the round trip ---------------------------------------------------------------------------

def test_settings_round_trip_robot_packet_database_decode(fake_robot, tmp_path, capsys):
    rt, tr = fake_robot(robot_toml(FIELD, LOCKED))
    taken = []
    shoot = rt.pipeline.shoot
    rt.pipeline.shoot = lambda *a: taken.append(shoot(*a)) or taken[-1]
    sweep(rt)
    sent = models(tr)
    assert len(sent) == 2 and [c.camera for c in taken] != [None, None]
    for robot_side, p in zip(taken, sent):
        r, w = robot_side.camera, p.camera
        assert (w.exposure_us, w.gain, w.white_balance_kelvin) == (20000.0, 2.0, 5000.0)
        assert w.sensor_temperature_c == pytest.approx(r.sensor_temperature_c, abs=0.005)
        assert w.reference == pytest.approx(r.reference, abs=2 ** -9) and len(w.reference) == 3
        assert 60 < w.reference[0] < 200 and w.reference_clipped == 0.0 and not w.unlocked
    with Store.open(tmp_path / "scene.db") as store:
        rx = Receiver(store, scene="field")
        for _, body in tr.sent:
            rx.handle(body)
        stored = sorted(store.captures(), key=lambda c: c.sequence)
        assert [c.camera for c in stored] == [p.camera for p in sent]
    key = write_key(tmp_path / "link.key")
    first = next(body for _, body in tr.sent if isinstance(pk.decode(body), pk.ModelsPacket))
    assert host(["decode", str(recording(key, first, tmp_path)), "--key", str(key)]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    (shown,) = [r for r in rows if r.get("type") == "MODELS"]
    assert shown["camera"] == settings_json(sent[0].camera)
    assert shown["camera"]["exposure_us"] == 20000.0 and shown["camera"]["white_balance_kelvin"] == 5000.0


def recording(key_path, body, tmp_path):
    """The bytes a serial port would carry for `body` sent over an authenticated link."""
    robot = Link(1, 2, 1, load_key(key_path), MemoryCounterStore())
    robot.send(body, 0.0)
    data = robot.poll(0.0)
    host_end = Link(2, 1, 1, load_key(key_path), MemoryCounterStore())
    host_end.receive(data, 0.1)
    robot.receive(host_end.poll(0.1), 0.1)
    data += robot.poll(0.2)
    path = tmp_path / "stream.bin"
    path.write_bytes(data)
    return path


def test_an_older_database_gains_the_camera_table_and_a_bad_row_is_one_line(tmp_path):
    db = older_database(tmp_path / "old.db", 6, "DROP TABLE capture_camera;")
    with Store.open(db) as s:
        (c,) = s.captures()
        assert c.camera is None
        s.add_capture("1", 2, 2.0, (80.0, 0.0), (80.0, 0.0), "rgb", ("R", "G", "B"), {},
                      camera=CaptureSettings(1000.0, 1.0, reference=(50.0, 60.0, 70.0)))
    con = sqlite3.connect(db)
    con.execute("UPDATE capture_camera SET reference = 'not json'")
    con.commit()
    con.close()
    with Store.open(db) as s, pytest.raises(CorruptDatabase, match="camera settings hold broken JSON"):
        s.captures()


def test_nonsense_a_device_reports_is_recorded_as_not_reported():
    from hal.interfaces import CameraSettings
    from onboard.capture.camera_lock import CameraLock

    lock = CameraLock(camera=None, cfg=config.CameraConfig())
    s = lock.record(CameraSettings(1e13, 1e9, 5500.0, sensor_temperature_c=-500.0))
    assert (s.exposure_us, s.gain, s.white_balance_kelvin, s.sensor_temperature_c) == (None, None, 5500.0, None)
    assert decode_camera(encode_camera(s, 3, CODEC, []), 0, 3, CODEC, [])[0] == s
