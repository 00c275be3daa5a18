"""The robot never sends what the link cannot carry: the largest capture it can make is sent
within one link message (the smallest regions left out, and said), and an outbox row longer than
the link's message is set aside while the rows after it go on."""
from onboard.capture.filing import Captures
from onboard.config import Config
from onboard.link.outbox import Outbox
from onboard.link.service import LinkService
from onboard.state import RuntimeState
from radio import packets as pk
from radio.auth import MemoryCounterStore
from radio.channel import ChannelConfig
from radio.channel_port import Cable
from radio.link import Delivered, Link
from radio.pump import LinkPump
from tests.support.worst_case import LABELS, worst_view

KEY = bytes(range(32))


def test_the_worst_case_robot_sends_packets_that_all_fit_and_says_which_regions_it_left_out(tmp_path):
    state = RuntimeState(Config(state_dir=tmp_path))
    with Outbox(tmp_path / "outbox.sqlite") as box:
        captures = Captures(state, box, lambda: 1.7e9)
        cap = worst_view()
        seq, packets, _ = captures.packets(cap)
    assert packets and all(len(body) <= pk.MAX_BODY for _, body in packets)
    (models,) = [pk.decode(body) for kind, body in packets if kind == pk.Kind.MODELS]
    sent = {x.label for x in models.labels}
    left_out = set(range(LABELS)) - sent
    # The largest regions travel (region `label` holds 100 + label pixels), as many as fit.
    assert left_out and sent == set(range(min(sent), LABELS)) and len(sent) > LABELS // 3
    assert set(models.dependence) == sent and set(models.camera.bracketed) <= sent
    assert models.models[(LABELS - 1, 15)] is not None and len(models.fits) == 16 * len(sent)
    (said,) = [e for e in state.errors if e.startswith(f"capture {seq}: ")]
    assert f"the {len(left_out)} smallest of its {LABELS} regions left out (labels 0, 1, 2" in said
    assert "exceed the link's largest message, 65536 bytes" in said and "segment.n_labels" in said


def test_an_outbox_row_longer_than_a_link_message_is_set_aside_and_the_rows_after_it_are_delivered(tmp_path):
    clock = [0.0]
    cable = Cable(ChannelConfig(loss=0.05, latency=0.01), clock=lambda: clock[0])
    robot_pump = LinkPump(Link(1, 2, 1, KEY, MemoryCounterStore()), cable.ends[0], clock=lambda: clock[0])
    host = LinkPump(Link(2, 1, 1, KEY, MemoryCounterStore()), cable.ends[1], clock=lambda: clock[0])
    state = RuntimeState(Config(state_dir=tmp_path))
    with Outbox(tmp_path / "outbox.sqlite") as box:
        # A row written before the bound (an older robot's): longer than any link message.
        long_id = box.put(int(pk.Kind.MODELS), b"m" * (pk.MAX_BODY + 100))
        later = {box.put(int(pk.Kind.LOG), b"row %d" % i): b"row %d" % i for i in range(12)}
        service = LinkService(robot_pump, box, state)
        got = []
        while clock[0] < 30.0 and len(box):
            service.read(clock[0])
            service.write(clock[0])
            got += [(e.msg_id, e.payload) for e in host.step() if isinstance(e, Delivered)]
            clock[0] += 0.01
        assert got == list(later.items()) and len(box) == 0
        count, (letter,) = box.dead_letters()
        assert count == 1 and letter.msg_id == long_id and letter.body == b"m" * (pk.MAX_BODY + 100)
        assert "exceeds the link's largest" in letter.reason
    assert any(f"message {long_id} not sent" in e and "set aside" in e for e in state.errors)
