"""The host's receiver: packets become stored captures, masks and unchanged markers, once each."""
import numpy as np
import pytest

from btf.fit.fitter import FrameFitter
from hal.interfaces import ViewAngles
from hal.scene import render
from radio import packets as pk
from radio.auth import MemoryCounterStore
from radio.link import Link
from radio.pump import LinkPump
from tests.support.packets import dependence_body, models_body
from tools.station.receiver import HostSession, ItemKind, Receiver, mask_key
from tools.store.database import Store

KEY = bytes(range(32))




@pytest.fixture
def store(tmp_path):
    with Store.open(tmp_path / "scene.db") as s:
        yield s


def test_a_models_packet_is_stored_with_the_robots_models_and_only_once(store):
    body, fits, _ = models_body(5)
    rx = Receiver(store, scene="mixed")
    first, again = rx.handle(body), rx.handle(body)
    assert first.kind is ItemKind.CAPTURE and first.stored and not again.stored
    (cap,) = store.captures(scene="mixed")
    assert (cap.robot, cap.sequence, cap.measured) == ("3", 5, (60.2, 0.1))
    stored = store.models(cap.id)
    assert set(stored) == set(fits)
    for k, r in fits.items():
        assert stored[k].count == r.count
        assert np.allclose(stored[k].percentiles, r.percentiles, atol=2 ** -9)
        assert stored[k].model.family == pk.decode(body).models[k].family
    assert rx.duplicates == 1


def test_censored_fractions_are_stored_per_band_as_the_robot_measured_them(store):
    rng = np.random.default_rng(4)
    frame = np.empty((200, 200, 2), dtype=np.uint8)
    frame[..., 0] = np.clip(np.rint(rng.normal(230, 30, (200, 200))), 0, 255)  # ~20% at 255
    frame[..., 1] = np.clip(np.rint(rng.normal(120, 20, (200, 200))), 0, 255)  # nothing clipped
    f = FrameFitter(1, 2)
    f.add(frame, np.zeros((200, 200), np.uint8))
    fits = f.fit()
    body = pk.encode_models(fits, robot_id=3, seq=1, time=1.0, commanded=(90.0, 0.0),
                            measured=(90.0, 0.0), feature_space="raw", bands=("A", "B"))
    Receiver(store).handle(body)
    (cap,) = store.captures()
    stored = {band: m for (_, band), m in store.models(cap.id).items()}
    saturated = float(np.mean(frame[..., 0] == 255))
    assert fits[(0, 0)].censored_high > 0.1
    assert stored[0].censored_high == pytest.approx(fits[(0, 0)].censored_high, abs=2e-5)
    assert stored[0].censored_high == pytest.approx(saturated, abs=0.02)
    assert (stored[1].censored_low, stored[1].censored_high) == (0.0, 0.0)
    assert stored[0].z == fits[(0, 0)].z


def test_unchanged_marker_files_a_capture_with_the_reference_models(store):
    body, _, _ = models_body(1)
    rx = Receiver(store)
    rx.handle(body)
    marker = pk.encode(pk.UnchangedPacket(3, 2, 200.0, (60.0, 0.0), (60.1, 0.0), 1))
    item = rx.handle(marker)
    assert item.kind is ItemKind.UNCHANGED and item.stored
    a, b = sorted(store.captures(), key=lambda c: c.sequence)
    assert store.models(a.id) == store.models(b.id)
    orphan = rx.handle(pk.encode(pk.UnchangedPacket(3, 9, 300.0, (60.0, 0.0), (60.0, 0.0), 7)))
    assert not orphan.stored and "not stored" in orphan.text


def test_mask_packets_are_stored_at_frame_size(store):
    _, _, mask = models_body(1)
    item = Receiver(store).handle(pk.encode_mask(mask, robot_id=3, seq=1))
    assert item.kind is ItemKind.MASK and item.stored
    got = store.mask(mask_key(1), "3")
    assert got.shape == mask.shape and set(np.unique(got)) == set(np.unique(mask))


def test_garbage_and_status_are_reported_not_stored(store):
    rx = Receiver(store)
    assert rx.handle(b"\x93\x01\x63junk").kind is ItemKind.BAD
    st = rx.handle(pk.encode(pk.StatusPacket(3, 1.0, pk.RobotState.IDLE, None, 0, 0, None, "boot")))
    assert st.kind is ItemKind.STATUS and "boot" in st.text
    assert store.captures() == []


class Pipe:
    """One end of an in-memory byte pipe pair."""

    timeout = 0.0

    def __init__(self):
        self.inbox = bytearray()
        self.peer = None

    @property
    def in_waiting(self):
        return len(self.inbox)

    def read(self, size=4096):
        data, self.inbox[:] = bytes(self.inbox[:size]), self.inbox[size:]
        return data

    def write(self, data):
        self.peer.inbox += data
        return len(data)

    def close(self):
        pass


def test_over_the_link_captures_are_stored_before_acknowledgement_and_commands_answered(store):
    a, b = Pipe(), Pipe()
    a.peer, b.peer = b, a
    t = [0.0]
    clock = lambda: t[0]
    robot = Link(1, 2, 1, KEY, MemoryCounterStore())
    host = HostSession(LinkPump(Link(2, 1, 1, KEY, MemoryCounterStore()), b, clock), Receiver(store))
    acked, got_cmd = set(), []
    ids = [robot.send(models_body(s, 30.0 + 10 * s)[0], 0.0) for s in range(3)]
    cid = host.command(pk.CommandName.STATUS)
    for _ in range(300):
        t[0] += 0.01
        robot.receive(a.read(), t[0])
        for ev in robot.pop_events():
            if hasattr(ev, "payload"):
                got_cmd.append(pk.decode(ev.payload))
                robot.send(pk.encode(pk.AckPacket(got_cmd[-1].command_id, "STATUS")), t[0])
            elif hasattr(ev, "msg_id"):
                acked.add(ev.msg_id)
        a.write(robot.poll(t[0]))
        host.step()
        if set(ids) <= acked and cid in host.answers:
            break
    assert set(ids) <= acked
    assert len(store.captures()) == 3
    assert got_cmd[0].name is pk.CommandName.STATUS
    assert host.answers[cid].text.startswith("ACK")




def test_dependence_in_a_models_packet_is_stored_and_reused_by_unchanged_markers(store):
    body, deps = dependence_body(1)
    assert deps
    rx = Receiver(store)
    assert "dependence" in rx.handle(body).text
    rx.handle(pk.encode(pk.UnchangedPacket(3, 2, 200.0, (60.0, 0.0), (60.1, 0.0), 1)))
    a, b = store.capture_by_seq("3", 1), store.capture_by_seq("3", 2)
    got = store.dependence(a.id)
    assert set(got) == set(deps)
    for lab, d in deps.items():  # int8 on the wire: within one step of 1/127
        assert np.allclose(got[lab].corr, d.corr, atol=1 / 127) and np.allclose(got[lab].dx, d.dx, atol=1 / 127)
    assert store.dependence(b.id) == got
    assert rx.rejected_extras == 0


def test_malformed_dependence_makes_the_packet_bad_and_stores_nothing(store):
    import msgpack

    items = msgpack.unpackb(models_body(1)[0])
    blob = bytearray(items[7])
    blob[10] |= 0x80  # flags a dependence section the blob does not hold
    items[7] = bytes(blob)
    rx = Receiver(store)
    item = rx.handle(msgpack.packb(items, use_bin_type=True))
    assert item.kind is ItemKind.BAD and "dependence" in item.text
    assert store.captures() == []


def test_pca_basis_arrives_once_per_scene_and_applies_to_later_captures(store):
    from btf.fit.features import PcaBasis

    view = render("mixed", ViewAngles(60.0, 0.0), (40, 48), seed=0)
    basis = PcaBasis.fit(view.image)
    rx = Receiver(store)
    first = rx.handle(models_body(1, extras=basis.to_extras(), space="pca")[0])
    rx.handle(models_body(2, 70.0, space="pca")[0])
    rx.handle(pk.encode(pk.UnchangedPacket(3, 3, 300.0, (80.0, 0.0), (80.0, 0.0), 1)))
    assert "PCA basis" in first.text
    for seq in (1, 2, 3):
        got = store.pca_basis(store.capture_by_seq("3", seq).id)
        assert got is not None and np.allclose(got.rotation, basis.rotation) and np.allclose(got.mean, basis.mean)
    bad = dict(basis.to_extras(), pca_rotation=[1.0, 2.0])
    item = rx.handle(models_body(4, space="pca", extras=bad)[0])
    assert item.stored and "PCA basis rejected" in item.text and rx.rejected_extras == 1


def test_synth_from_the_database_turns_received_pca_captures_back_into_rgb(tmp_path):
    from btf.fit.features import PcaBasis
    from tools.cli import main
    from tools.data.images import read_image, write_mask

    view = render("mixed", ViewAngles(60.0, 0.0), (40, 48), seed=0)
    basis = PcaBasis.fit(view.image)
    f = FrameFitter(4, 3)
    f.add(basis.apply(view.image), view.mask)
    body = pk.encode_models(f.fit(), robot_id=3, seq=1, time=1.0, commanded=(60.0, 0.0), measured=(60.0, 0.0),
                            feature_space="pca", bands=("P1", "P2", "P3"), extras=basis.to_extras())
    db = tmp_path / "scene.db"
    with Store.open(db) as s:
        Receiver(s).handle(body)
    write_mask(tmp_path / "mask.png", view.mask)
    out = tmp_path / "syn.png"
    assert main(["synth", "--db", str(db), "--mask", str(tmp_path / "mask.png"), "--angle", "60",
                 "--out", str(out)]) == 0
    syn = read_image(out)
    assert syn.shape == view.image.shape
    for lab in np.unique(view.mask):  # each region's mean colour comes back, not its components
        sel = view.mask == lab
        assert np.abs(syn[sel].mean(axis=0) - view.image[sel].mean(axis=0)).max() < 8, lab


def test_a_16_bit_capture_is_stored_at_its_depth(store):
    rng = np.random.default_rng(8)
    frame = np.clip(np.rint(rng.normal(30000, 900, (120, 160, 1))), 0, 65535).astype(np.uint16)
    f = FrameFitter(1, 1, bins=65536)
    f.add(frame, np.zeros((120, 160), np.uint8))
    fits = f.fit()
    body = pk.encode_models(fits, robot_id=3, seq=1, time=1.0, commanded=(90.0, 0.0), measured=(90.0, 0.0),
                            feature_space="raw", bands=("T",), levels=65536)
    Receiver(store).handle(body)
    (cap,) = store.captures()
    assert cap.levels == 65536
    assert store.models(cap.id)[(0, 0)].model == fits[(0, 0)].model
