"""The file a replayed frame came from: in the capture's settings, on the wire (MODELS schema 5,
older bodies still decoding), in the host's database and in the report's source line."""
import dataclasses

import pytest
from hypothesis import given
from hypothesis import strategies as st

from btf.capture_settings import MAX_SOURCE, CaptureSettings, bounded_source
from btf.codec import PercentileCodec
from radio import FrameError
from radio import packets as pk
from radio.packets.camera import decode_camera, encode_camera
from radio.packets.models import ModelsPacket
from tests.support.databases import older_database
from tests.support.replay import models, robot_text, run_sweep, write_shots
from tools.report.look import capture_source
from tools.store.database import Store

CODEC = PercentileCodec.for_levels(256)
SOURCES = st.text(st.characters(min_codepoint=32, max_codepoint=0x2FFF), min_size=1, max_size=80).filter(str.isprintable)


@given(SOURCES)
def test_any_path_is_bounded_to_a_source_the_wire_carries_as_it_went(path):
    source = bounded_source(path)
    assert len(source.encode("utf-8")) <= MAX_SOURCE
    if len(path.encode("utf-8")) <= MAX_SOURCE:
        assert source == path
    else:  # the end of the path, where the file's name is, marked as cut
        assert source.startswith("…") and path.endswith(source[1:])
    s = CaptureSettings(10_000.0, 1.0, 5500.0, source=source)
    blob = encode_camera(s, 3, CODEC, [1])
    assert decode_camera(blob, 0, 3, CODEC, [1]) == (s, len(blob))


def test_the_source_costs_its_bytes_and_one_of_flags_and_only_schema_five_has_it():
    plain = CaptureSettings(20000.0, 2.0, 5000.0, sensor_temperature_c=25.05)
    named = dataclasses.replace(plain, source="shots/shot_10.png")
    assert len(encode_camera(plain, 3, CODEC, [3])) == 10
    assert len(encode_camera(named, 3, CODEC, [3])) == 10 + 1 + 1 + len("shots/shot_10.png")
    with pytest.raises(ValueError, match="needs schema 5"):
        encode_camera(named, 3, CODEC, [3], version=4)
    with pytest.raises(ValueError, match="source must be printable"):
        CaptureSettings(source="x" * (MAX_SOURCE + 1))
    with pytest.raises(ValueError, match="source must be printable"):
        CaptureSettings(source="a\nb")


@pytest.mark.parametrize(("blob", "message"), [
    (bytes([0x80]), "ends inside a varint"),
    (bytes([0x80, 0x04]), "name fields this schema does not have"),
    (bytes([0x80, 0x02, 0]), "source of 0 bytes"),
    (bytes([0x80, 0x02, 5, 65]), "source of 5 bytes"),
    (bytes([0x80, 0x02, 2, 0xC3, 0x28]), "not UTF-8"),
    (bytes([0x80, 0x02, 1, 7]), "unprintable"),
])
def test_a_bad_source_is_refused_naming_the_field(blob, message):
    with pytest.raises(FrameError, match=message):
        decode_camera(blob, 0, 3, CODEC, [3])


def test_a_models_body_from_before_schema_five_still_decodes_with_its_camera(monkeypatch):
    camera = CaptureSettings(40000.0, 1.0, 5000.0, brackets=(12000.0,), bracketed={0: 1})
    packet = pk.models_packet({}, robot_id=1, seq=2, time=3.0, commanded=(90.0, 0.0), measured=(90.0, 0.0),
                              feature_space="rgb", bands=("R", "G", "B"), camera=camera)
    packet = dataclasses.replace(packet, camera=dataclasses.replace(camera, brackets=(), bracketed={}))
    monkeypatch.setattr(ModelsPacket, "BYTES_SINCE", 4)  # what a robot of schema 4 sent
    old = pk.encode(packet)
    monkeypatch.undo()
    assert old[1] == 4 and pk.encode(packet)[1] == 5
    assert pk.decode(old).camera == packet.camera == pk.decode(pk.encode(packet)).camera
    assert len(pk.encode(packet)) == len(old)  # flags below 0x80: the same byte at either schema


def test_each_replayed_capture_carries_its_file_to_the_host_and_the_report(fake_robot, tmp_path):
    shots = write_shots(tmp_path / "shots")
    packets, sources = run_sweep(fake_robot, robot_text(f"replay:{shots}", loop=True))
    sent = models(packets)
    assert [p.camera.source.rsplit("/", 1)[-1] for p in sent] == [sources[round(p.commanded[0])] for p in sent]
    assert all(p.camera.source == bounded_source(str(shots / sources[round(p.commanded[0])])) for p in sent)
    with Store.open(tmp_path / "host.db") as store:
        for p in sent:
            store.add_capture("1", p.seq, p.time, p.commanded, p.measured, p.feature_space, p.bands, p.fits,
                              camera=p.camera)
        back = store.captures()
    assert sorted(c.camera.source for c in back) == sorted(p.camera.source for p in sent)
    line = capture_source(back[0])
    assert line.endswith(f"; frame from file {back[0].camera.source}")


def test_an_older_database_gains_the_source_column_and_keeps_its_rows(tmp_path):
    camera = CaptureSettings(1000.0, 1.0)  # as schema 9 stored it: no source column
    db = older_database(tmp_path / "old.db", 9, "ALTER TABLE capture_camera DROP COLUMN source;", camera=camera)
    with Store.open(db) as s:
        (old,) = s.captures()
        assert old.camera == camera and old.camera.source is None
        s.add_capture("1", 2, 2.0, (80.0, 0.0), (80.0, 0.0), "rgb", ("R", "G", "B"), {},
                      camera=dataclasses.replace(camera, source="frames/a.png"))
        assert {c.sequence: c.camera.source for c in s.captures()} == {1: None, 2: "frames/a.png"}
