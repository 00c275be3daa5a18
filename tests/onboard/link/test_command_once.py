"""A command runs once, even when the robot is killed and the base re-sends it.

The base retries a command with the same id until it hears the answer; after a robot
restart the link's dedup window is gone, so the runtime itself must recognise the id."""
import pytest

from onboard.link.outbox import REMEMBERED_REPLIES, Outbox, Reply
from radio import packets as pk
from tests.support.robots import IDLE, robot_toml

CONFIG = robot_toml(IDLE)
C = pk.CommandName


class Crash(BaseException):
    """The process dies here (not an Exception: the runtime's guards do not catch it)."""


def robot(fake_robot, state_dir):
    rt, tr = fake_robot(CONFIG, where=state_dir)
    rt.boot()
    return rt, tr


def send(rt, tr, cid, name, **args):
    tr.receive(pk.encode(pk.CommandPacket(cid, name, args)))
    for _ in range(3):
        rt.step()


def sent(*transports):
    return [(body, pk.decode(body)) for tr in transports for _, body in tr.sent]


def answers(cid, *transports):
    return [body for body, p in sent(*transports)
            if isinstance(p, (pk.AckPacket, pk.NackPacket)) and p.command_id == cid]


def captures(*transports):
    """What a host keeps: one capture per sequence number, however often it was re-sent."""
    return {p.seq for _, p in sent(*transports) if isinstance(p, pk.ModelsPacket)}


def die_at_commit(rt, k, after):
    """Kill the robot at its k-th outbox commit from now, before or after it is durable."""
    real, calls = rt.outbox.commit, []

    def commit(*a, **kw):
        calls.append(1)
        if len(calls) == k and not after:
            raise Crash()
        out = real(*a, **kw)
        if len(calls) == k:
            raise Crash()
        return out

    rt.outbox.commit = commit
    return calls


@pytest.mark.parametrize("after", [False, True], ids=["kill-before-commit", "kill-after-commit"])
def test_a_capture_killed_at_any_commit_and_resent_after_restart_is_captured_once(fake_robot, tmp_path, after):
    (tmp_path / "count").mkdir()
    rt, _ = robot(fake_robot, tmp_path / "count")
    commits = die_at_commit(rt, 0, after)
    send(rt, rt.transport, 42, C.CAPTURE)
    assert len(commits) >= 1
    for k in range(1, len(commits) + 1):
        state = tmp_path / f"kill{k}"
        state.mkdir()
        rt, tr = robot(fake_robot, state)
        die_at_commit(rt, k, after)
        with pytest.raises(Crash):
            send(rt, tr, 42, C.CAPTURE)
        rt.outbox.close()
        rt2, tr2 = robot(fake_robot, state)  # restarted; the base re-sends the command, twice
        send(rt2, tr2, 42, C.CAPTURE)
        send(rt2, tr2, 42, C.CAPTURE)
        assert len(captures(tr, tr2)) == 1, k
        replies = answers(42, tr, tr2)
        assert replies and len(set(replies)) == 1  # the same answer every time
        ack = pk.decode(replies[0])
        assert isinstance(ack, pk.AckPacket) and ack.extras["seq"] in captures(tr, tr2)
        assert len(rt2.outbox) == 0  # every answer was sent and acknowledged
        rt2.outbox.close()


def test_a_capture_answered_after_a_restart_is_not_captured_again(fake_robot, tmp_path):
    rt, tr = robot(fake_robot, tmp_path)
    send(rt, tr, 7, C.CAPTURE)
    rt.outbox.close()
    rt2, tr2 = robot(fake_robot, tmp_path)
    send(rt2, tr2, 7, C.CAPTURE)  # the base never heard the answer: it asks again
    assert len(captures(tr, tr2)) == 1
    assert len(set(answers(7, tr, tr2))) == 1 and len(answers(7, tr2)) == 1
    send(rt2, tr2, 8, C.CAPTURE)  # a new command id is a new capture
    assert len(captures(tr, tr2)) == 2


def test_a_retried_goto_or_set_is_answered_from_memory_without_running_again(fake_robot, tmp_path):
    rt, tr = robot(fake_robot, tmp_path)
    moves = []
    real_move = rt.pipeline.move
    rt.pipeline.move = lambda view: (moves.append(view.elevation), real_move(view))[1]
    send(rt, tr, 1, C.GOTO, elevation=60.0, azimuth=0.0)
    send(rt, tr, 2, C.GOTO, elevation=40.0, azimuth=0.0)
    send(rt, tr, 1, C.GOTO, elevation=60.0, azimuth=0.0)
    assert moves == [60.0, 40.0]  # the arm stays where the newer command put it
    assert len(answers(1, tr)) == 2 and len(set(answers(1, tr))) == 1
    send(rt, tr, 3, C.SET, key="skip.min_pixels", value=5)
    send(rt, tr, 4, C.SET, key="skip.min_pixels", value=9)
    send(rt, tr, 3, C.SET, key="skip.min_pixels", value=5)
    assert rt.cfg.skip.min_pixels == 9
    assert len(set(answers(3, tr))) == 1
    # A refusal is remembered too: the same request gets the same reason.
    send(rt, tr, 5, C.SET, key="hal.scene", value="white")
    send(rt, tr, 5, C.SET, key="hal.scene", value="white")
    nacks = answers(5, tr)
    assert len(nacks) == 2 and len(set(nacks)) == 1
    assert pk.decode(nacks[0]).reason is pk.Reason.BAD_ARGUMENT


def test_a_retried_command_whose_answer_is_still_queued_is_not_answered_twice(fake_robot, tmp_path):
    rt, tr = robot(fake_robot, tmp_path)
    tr.auto_ack = False
    send(rt, tr, 11, C.PING)
    send(rt, tr, 11, C.PING)
    assert len(answers(11, tr)) == 1
    assert len(rt.outbox) == 2  # the boot STATUS and the one answer


def test_the_robot_remembers_only_the_last_replies(tmp_path):
    with Outbox(tmp_path / "o.sqlite") as box:
        total = REMEMBERED_REPLIES + 4
        for cid in range(total):
            box.commit(reply=Reply(cid, int(pk.Kind.ACK), pk.encode(pk.AckPacket(cid, "PING", {"time": 1.0}))))
        kept = [cid for cid in range(total) if box.remembered(cid) is not None]
        assert kept == list(range(4, total))
        last = box.remembered(total - 1)
        assert pk.decode(last.body).command_id == total - 1 and box.kind_of(last.msg_id) == int(pk.Kind.ACK)
    with Outbox(tmp_path / "o.sqlite") as box:  # and it survives a restart
        assert box.remembered(total - 1) == last and box.remembered(3) is None


def test_a_forgotten_command_id_runs_again(fake_robot, tmp_path, monkeypatch):
    monkeypatch.setattr("onboard.link.outbox.REMEMBERED_REPLIES", 2)
    rt, tr = robot(fake_robot, tmp_path)
    send(rt, tr, 1, C.SET, key="skip.min_pixels", value=5)
    send(rt, tr, 2, C.SET, key="skip.min_pixels", value=9)
    send(rt, tr, 1, C.SET, key="skip.min_pixels", value=5)
    assert rt.cfg.skip.min_pixels == 9  # still remembered
    send(rt, tr, 3, C.PING)
    send(rt, tr, 1, C.SET, key="skip.min_pixels", value=5)
    assert rt.cfg.skip.min_pixels == 5  # forgotten past the bound: a new request


def test_a_reply_with_a_bad_command_id_is_refused(tmp_path):
    with Outbox(tmp_path / "o.sqlite") as box, pytest.raises(ValueError, match="command id"):
        box.commit(reply=Reply(-1, int(pk.Kind.ACK), b"x"))
    with Outbox(tmp_path / "o.sqlite") as box:
        assert len(box) == 0
