"""What the station says about refused frames: a likely wrong key in one line, another
transmitter once the robot is heard, the re-sync after a start as a re-sync, at most one event a
second per reason."""
from radio.events import LinkStats
from tools.station.rejected_frames import EVERY_S, RESYNC_S, WRONG_KEY_FRAMES, RejectedFrames


def stats(accepted: int = 0, **rejected: int) -> LinkStats:
    return LinkStats(0, 0, accepted, 0, 0, 0, 0, 0, dict(rejected))


def test_frames_failing_authentication_with_none_passing_are_said_as_a_wrong_key_with_the_fix():
    r = RejectedFrames(started=0.0)
    (early,) = r.update(stats(tag=WRONG_KEY_FRAMES - 1), 1.0)
    assert "tag mismatch: wrong key?" in early[0] and not early[1].get("wrong_key")
    assert r.wrong_key(stats(tag=WRONG_KEY_FRAMES - 1)) == ""
    (said,) = r.update(stats(tag=WRONG_KEY_FRAMES + 5), 2.0)
    text, fields = said
    assert text.startswith(f"wrong key? {WRONG_KEY_FRAMES + 5} frames failed authentication and none passed")
    assert "--key must hold the same key as the robot's link.key_file" in text and "still listening" in text
    assert fields == {"reason": "tag", "count": 6, "total": WRONG_KEY_FRAMES + 5, "cause": fields["cause"],
                      "wrong_key": True}
    assert len(text.splitlines()) == 1


def test_once_the_robots_frames_pass_failing_ones_are_another_transmitters():
    r = RejectedFrames(started=0.0)
    ((text, fields),) = r.update(stats(accepted=50, tag=40), 1.0)
    assert "another transmitter" in text and "wrong key" not in text and "wrong_key" not in fields
    assert r.wrong_key(stats(accepted=50, tag=40)) == ""


def test_each_reason_is_said_at_most_once_a_second_with_what_came_meanwhile():
    r = RejectedFrames(started=0.0)
    assert [f["count"] for _, f in r.update(stats(crc=3), 100.0)] == [3]
    assert r.update(stats(crc=9), 100.0 + EVERY_S / 2) == []
    ((text, fields),) = r.update(stats(crc=10), 100.0 + EVERY_S)
    assert (fields["count"], fields["total"]) == (7, 10) and "CRC error" in text
    assert r.update(stats(crc=10), 200.0) == []  # nothing new: nothing said


def test_the_robots_old_session_after_a_start_is_a_resync_said_with_the_link_up_not_refusals():
    r = RejectedFrames(started=0.0)
    assert r.update(stats(stale_session=5), 0.5) == []
    up = r.link_up(stats(accepted=3, stale_session=7), 0.8)
    assert up == " (re-synced after this station's start: 7 frames of the robot's earlier session set aside)"
    assert r.view(stats(accepted=3, stale_session=7, crc=1)).rejected == {"crc": 1}  # not refused frames
    assert r.link_up(stats(accepted=9, stale_session=7), 5.0) == ""  # said once
    # later frames of an old session are refusals again, said as such
    ((text, fields),) = r.update(stats(accepted=9, stale_session=9), 6.0)
    assert fields["count"] == 2 and "old session" in text
    assert r.view(stats(accepted=9, stale_session=9)).rejected == {"stale_session": 2}


def test_old_session_frames_long_after_the_start_are_refusals_not_a_resync():
    r = RejectedFrames(started=0.0)
    ((text, fields),) = r.update(stats(stale_session=4), RESYNC_S + 1.0)
    assert fields["count"] == 4 and r.link_up(stats(accepted=1, stale_session=4), RESYNC_S + 2.0) == ""
    assert r.view(stats(stale_session=4)).rejected == {"stale_session": 4}
