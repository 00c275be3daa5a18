"""The packet schema is declared once: the document is written from the declarations, every
kind decodes at each schema version it had (old bodies still decode), and a kind is refused at a
version it never had."""
import msgpack
import pytest

from radio import FrameError
from radio import packets as pk
from radio.packets.doc import document
from radio.packets.schema import layout
from tests.support import ROOT


def raw(*items) -> bytes:
    return msgpack.packb(list(items), use_bin_type=True)


def test_the_schema_document_is_written_from_the_declarations():
    assert (ROOT / "docs" / "packets.md").read_text() == document(), "run: python -m radio.packets > docs/packets.md"
    for kind, cls in pk.KINDS.items():
        assert f"## {kind.name} ({int(kind)})" in document()
        assert all(f"`{f.name}`" in document() for f in layout(cls))


def test_an_old_status_decodes_its_report_read_from_the_extras_it_named():
    body = raw(3, int(pk.Kind.STATUS), 2, 1.7e9, 3, 4500, 0, 1, 900, 6, "skipped pose: settle failed",
               {"mode": "sweeping", "sweep": 2, "skipped_index": 4, "skipped_elevation": 50.0, "skipped_azimuth": -10,
                "disk": "low", "disk_free": 10, "camera": 7})
    p = pk.decode(body)
    assert p.pose == (45.0, 0.0) and p.text == "skipped pose: settle failed"
    assert p.report == pk.StatusReport(mode="sweeping", disk=pk.Disk("low", 10), sweep=pk.SweepReport(
        2, skipped=pk.Kept((pk.SkippedPose(4, 50.0, 350.0, "settle failed"),))))
    assert p.extras["camera"] == 7  # of another type than it names: kept, not read
    assert pk.decode(pk.encode(p)) == p  # and it travels on at the newest version


def test_old_answers_and_refusals_decode():
    ping = pk.decode(raw(3, int(pk.Kind.ACK), 5, "PING", {"time": 1.7e9}))
    assert ping.name is pk.CommandName.PING and ping.extras == {"time": 1.7e9} and ping.status is None
    status = pk.decode(raw(3, int(pk.Kind.ACK), 6, "STATUS", {"mode": "idle", "skipped": ["4@50.0/0.0: x"]}))
    assert status.status is None and status.extras["mode"] == "idle"  # its report was flat extras then
    nack = pk.decode(raw(3, int(pk.Kind.NACK), 7, int(pk.Reason.BUSY), "busy"))
    assert nack.reason is pk.Reason.BUSY and nack.msg_id is None
    with pytest.raises(FrameError, match="the answer to GOTO lacks its azimuth"):
        pk.decode(raw(3, int(pk.Kind.ACK), 5, "GOTO", {"elevation": 10.0}))


def test_each_kind_is_encoded_at_its_newest_version_and_refused_at_one_it_never_had():
    assert {k: pk.version_of(k) for k in pk.Kind} == {
        k: 4 if k in (pk.Kind.STATUS, pk.Kind.ACK, pk.Kind.NACK) else 5 if k is pk.Kind.MODELS else 3 for k in pk.Kind}
    body = pk.encode(pk.LogPacket(1, 2.0, pk.LogLevel.INFO, "x"))
    assert body[1] == 3
    with pytest.raises(FrameError, match="unsupported schema version 4 for LOG"):
        pk.decode(bytes([body[0], 4]) + body[2:])
    with pytest.raises(FrameError, match="unsupported schema version 5 for STATUS"):
        pk.decode(raw(5, int(pk.Kind.STATUS)))
    with pytest.raises(FrameError, match="unsupported schema version 6"):
        pk.decode(raw(6, int(pk.Kind.MODELS)))


def test_the_cross_field_rules_hold_both_ways():
    with pytest.raises(ValueError, match="exactly when its reason is UNUSABLE"):
        pk.encode(pk.NackPacket(1, pk.Reason.BUSY, "busy", msg_id=4))
    with pytest.raises(ValueError, match="carries a STATUS report"):
        pk.encode(pk.AckPacket(1, "PING", {"time": 1.0}, status=pk.StatusReport()))
    with pytest.raises(ValueError, match="failsafe ends before it began"):
        pk.encode(pk.AckPacket(1, "STATUS", status=pk.StatusReport(failsafe=pk.Kept((pk.FailsafeEvent(5.0, 4.0),)))))
    refusal = pk.NackPacket(0, pk.Reason.UNUSABLE, "sweep id must be an integer", msg_id=2**56 + 9)
    assert pk.decode(pk.encode(refusal)) == refusal
