"""The failsafe: once the link has been up, its loss (no heartbeat from the base for
`link.failsafe_s`) stops the arm where it is and pauses what the robot was doing; when the link
returns the robot resumes it and sends a STATUS reporting the failsafe. Before the base was ever
heard, an autonomous sweep runs and its packets wait in the outbox."""
from __future__ import annotations

from typing import Callable

from hal.arm import Arm
from onboard.state import Mode, RuntimeState
from radio import packets as pk
from radio.packets.schema import Recent

EVENTS_KEPT = 8


class Failsafe:
    def __init__(self, state: RuntimeState, arm: Arm, wall: Callable[[], float],
                 send_status: Callable[[str, pk.StatusReport], None]) -> None:
        self.state, self.arm, self.wall, self.send_status = state, arm, wall, send_status
        self.link_up = False
        self.ever_up = False
        self.events: Recent = Recent(EVENTS_KEPT)  # {"since", "until"} wall times
        self._resume_mode = Mode.IDLE

    @property
    def active(self) -> bool:
        return self.state.mode is Mode.FAILSAFE

    def link_changed(self, up: bool) -> None:
        if up == self.link_up:
            return
        self.link_up = up
        if up:
            self.ever_up = True
            # Nothing to re-offer: the link holds every message until it is acknowledged,
            # across link loss (a new session re-sends it).
            if self.active:
                event = self.events[-1]
                event["until"] = self.wall()
                self.state.mode = self._resume_mode
                self.send_status("failsafe: link lost, arm held", pk.StatusReport(
                    failsafe=pk.Kept((pk.FailsafeEvent(event["since"], event["until"]),))))
        elif self.ever_up and not self.active:
            self._trip()

    def _trip(self) -> None:
        self._resume_mode = self.state.mode
        self.state.mode = Mode.FAILSAFE
        self.state.interrupt_work("failsafe")
        self.events.append({"since": self.wall(), "until": None})
        try:
            self.arm.stop_and_hold()
        except Exception as exc:  # the arm must not end the loop; say why in STATUS
            self.state.errors.append(f"failsafe hold: {type(exc).__name__}: {exc}")
