"""What the runtime's parts share: the configuration in force, the mode, the sweep in progress,
the last measured pose, and the arm's work (which a command or the failsafe may interrupt)."""
from __future__ import annotations

import enum
from collections import deque
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Iterator

from hal.interfaces import ViewAngles
from onboard.config import Config
from onboard.sweep.plan import SweepProgress
from radio.packets.schema import Recent


class Mode(enum.StrEnum):
    IDLE = "idle"
    SWEEPING = "sweeping"
    FAILSAFE = "failsafe"


class Interrupted(Exception):
    """ABORT, TORQUE_OFF, a new SWEEP or the failsafe took the arm while it was working."""


@dataclass
class RuntimeState:
    cfg: Config  # replaced whole by SET
    mode: Mode = Mode.IDLE
    progress: SweepProgress | None = None
    pose: ViewAngles | None = None  # the last measured view
    paused_reason: str = ""  # why acquisition waits (the outbox is full), "" when it does not
    device_gone: str = ""  # a device not there (unplugged): the sweep waits for it, "" when all answer
    disk: str = "ok"  # room under state_dir: ok | low | full (onboard.disk.Pressure)
    disk_free: int | None = None  # bytes free there, when known
    errors: deque[str] = field(default_factory=lambda: Recent(16))  # counts the older ones let go
    torque: bool = True  # the servos hold; False after TORQUE_OFF or a power-on that failed at boot
    # Commands are answered while the arm works (the pipeline services the link), so an
    # interrupting command or the failsafe must end that work, not be undone by it.
    busy: bool = False
    interrupt: str = ""

    @contextmanager
    def arm_work(self) -> Iterator[None]:
        """The arm is measuring a pose (or moving for a command) inside this block."""
        self.busy, self.interrupt = True, ""
        try:
            yield
        finally:
            self.busy, self.interrupt = False, ""

    def interrupt_work(self, why: str) -> None:
        """End the arm's work at its next link service, if it is working."""
        if self.busy:
            self.interrupt = why

    def check_interrupt(self) -> None:
        if self.interrupt:
            raise Interrupted(self.interrupt)
