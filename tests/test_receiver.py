"""The host's receiver: packets become stored captures, masks and unchanged markers, once each."""
import numpy as np
import pytest

from hal.interfaces import ViewAngles
from hal.scene import render
from onboard.fit import FrameFitter
from radio import packet as pk
from radio.auth import MemoryCounterStore
from radio.link import Link
from tools.receiver import HostSession, ItemKind, Receiver, mask_key
from tools.store import Store

KEY = bytes(range(32))


def models_body(seq, elevation=60.0, scene="mixed"):
    view = render(scene, ViewAngles(elevation, 0.0), (40, 48), seed=0)
    f = FrameFitter(4, 3)
    f.add(view.image, view.mask)
    fits = f.fit()
    body = pk.encode_models(fits, robot_id=3, seq=seq, time=100.0 + seq, commanded=(elevation, 0.0),
                            measured=(elevation + 0.2, 0.1), feature_space="rgb", bands=("R", "G", "B"))
    return body, fits, view.mask


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
    stored = {(m.label, m.band): m for m in store.models(cap.id)}
    assert set(stored) == set(fits)
    for k, r in fits.items():
        assert stored[k].count == r.count
        assert np.allclose(stored[k].percentiles, r.percentiles, atol=2 ** -9)
        assert stored[k].model.family == pk.decode(body).models[k].family
    assert rx.duplicates == 1


def test_unchanged_marker_files_a_capture_with_the_reference_models(store):
    body, _, _ = models_body(1)
    rx = Receiver(store)
    rx.handle(body)
    marker = pk.encode(pk.UnchangedPacket(3, 2, 200.0, (60.0, 0.0), (60.1, 0.0), 1))
    item = rx.handle(marker)
    assert item.kind is ItemKind.UNCHANGED and item.stored
    a, b = sorted(store.captures(), key=lambda c: c.sequence)
    assert [m.model for m in store.models(a.id)] == [m.model for m in store.models(b.id)]
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

    def __init__(self):
        self.inbox = bytearray()
        self.peer = None

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
    host = HostSession(Link(2, 1, 1, KEY, MemoryCounterStore()), b, Receiver(store), clock)
    acked, got_cmd = set(), []
    ids = [robot.send(models_body(s, 30.0 + 10 * s)[0], 0.0) for s in range(3)]
    cid = host.command(pk.CommandName.STATUS)
    for _ in range(300):
        t[0] += 0.01
        for ev in robot.receive(a.read(), t[0]):
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
