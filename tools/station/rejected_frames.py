"""What the station says about the frames its link refuses. The link counts them by reason; here
the counts become events with their likely cause, at most once a second per reason, and never a
reason to stop: anyone on the radio can send frames that fail, so they are counted, said and
refused while the station goes on listening.

Two cases are said in words of their own:
- Frames failing authentication while none has passed: most likely a wrong key, said in one line
  with the fix (again each second it goes on). Once the robot's frames pass, failing ones are
  another transmitter's.
- Right after the station starts, the robot's frames of its session with the previous station
  (`stale_session`) until it opens one with this station: a re-sync, said with the link-up event
  and kept out of the refused counts the snapshot shows, so that an operator does not take a
  restart for an attack.
"""
from __future__ import annotations

import dataclasses

from radio.events import LinkStats
from tools.station.log import likely_cause

WRONG_KEY_FRAMES = 8  # frames failing authentication, none passing: the key is likely wrong
EVERY_S = 1.0  # an event per reason at most this often
RESYNC_S = 10.0  # how long after the start the robot's frames of an old session count as the re-sync
TAG, STALE = "tag", "stale_session"


def _frames(n: int) -> str:
    return f"{n} frame{'s' * (n != 1)}"


def wrong_key_line(failed: int, accepted: int) -> str:
    """The one line saying the key is likely wrong, from the frames that failed authentication and
    those accepted ('' while it is not likely)."""
    if failed < WRONG_KEY_FRAMES or accepted:
        return ""
    return (f"wrong key? {_frames(failed)} failed authentication and none passed: --key must hold the same "
            "key as the robot's link.key_file")


class RejectedFrames:
    """Fed the link's counters after each turn (`update`); `wall` is the wall clock in seconds."""

    def __init__(self, started: float) -> None:
        self._said: dict[str, int] = {}  # counts already said (or set aside), by reason
        self._said_at: dict[str, float] = {}
        self._resync_until: float | None = started + RESYNC_S  # None once the re-sync is over
        self.resynced = 0  # frames of the robot's old session set aside as the re-sync
        self._wrong_key_said = False

    def wrong_key(self, st: LinkStats) -> str:
        """The one line saying the key is likely wrong ('' while it is not)."""
        return wrong_key_line(st.rejected.get(TAG, 0), st.frames_accepted)

    def view(self, st: LinkStats) -> LinkStats:
        """The link's counters with the re-sync's frames out of the refused ones."""
        if not self.resynced:
            return st
        rejected = dict(st.rejected)
        left = rejected.pop(STALE, 0) - self.resynced
        if left > 0:
            rejected[STALE] = left
        return dataclasses.replace(st, rejected=rejected)

    def link_up(self, st: LinkStats, wall: float) -> str:
        """What the first link-up event after the start adds about the re-sync ('' for none)."""
        if self._resync_until is None:
            return ""
        self._set_aside(st, wall)
        self._resync_until = None
        n = self.resynced
        return f" (re-synced after this station's start: {_frames(n)} of the robot's earlier session set aside)" * (n > 0)

    def update(self, st: LinkStats, wall: float) -> list[tuple[str, dict]]:
        """The events (text, fields) for what the link refused since they were last said; the
        fields are `reason`, `count` (new), `total`, `cause`, and `wrong_key` (True) when it is said."""
        self._set_aside(st, wall)
        out = []
        for reason, total in st.rejected.items():
            new = total - self._said.get(reason, 0)
            wrong_key = reason == TAG and bool(self.wrong_key(st))
            first = wrong_key and not self._wrong_key_said  # said at once, whatever was said just before
            if new <= 0 or wall - self._said_at.get(reason, -1e9) < EVERY_S and not first:
                continue
            self._said[reason], self._said_at[reason] = total, wall
            self._wrong_key_said |= wrong_key
            cause = likely_cause(reason)
            text = f"{_frames(new)} refused: {cause}"
            if wrong_key:
                text = self.wrong_key(st) + " (still listening)"
            elif reason == TAG and st.frames_accepted:
                cause = "authentication failed while the robot's frames pass: another transmitter, with another key"
                text = f"{_frames(new)} refused: {cause}"
            fields = {"reason": reason, "count": new, "total": total, "cause": cause}
            out.append((text, {**fields, "wrong_key": True} if wrong_key else fields))
        return out

    def _set_aside(self, st: LinkStats, wall: float) -> None:
        """During the re-sync, the robot's frames of its old session are not refusals to say."""
        if self._resync_until is None:
            return
        if wall >= self._resync_until:
            self._resync_until = None
            return
        new = st.rejected.get(STALE, 0) - self._said.get(STALE, 0)
        if new > 0:
            self.resynced += new
            self._said[STALE] = st.rejected[STALE]
