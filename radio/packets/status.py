"""STATUS: the robot's state, and its report as one typed record (`StatusReport`).

Every STATUS (boot, a skipped pose, the sweep done, the failsafe over, the disk) carries the
report's fields it has something to say about; the answer to the STATUS command (an ACK,
`radio.packets.answers`) carries the whole report. Nested records travel as tagged maps: a
field added later is a new tag, so the report grows without limit of count, and each list
keeps its newest items with the number of older ones left out (`radio.packets.schema.Latest`).

Schema 4 added the report; a schema-3 STATUS (its state in free-form extras) still decodes,
its report read from the extras it named.
"""
from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

from radio import FrameError
from radio.packets.base import INT64, MAX_TIME, UINT32, UINT64, Kind
from radio.packets.schema import (
    Angles,
    Choice,
    Declared,
    Flag,
    Float,
    Int,
    Kept,
    Latest,
    ListOf,
    Maybe,
    Record,
    Text,
    Word,
    wire,
)

TIME = Float(0.0, MAX_TIME)  # wall-clock seconds since 1970
LINE = Text(300)  # a fault, an error, a reason: one line a person reads
MODES = ("idle", "sweeping", "failsafe")  # onboard.state.Mode
DISK_STATES = ("ok", "low", "full")  # onboard.disk.Pressure
BOOTS = ("started", "resumed", "finished", "stopped")  # onboard.sweep.plan.Boot
MAX_POSES = 4096  # onboard.sweep.plan.MAX_POSES
PLAN_ANGLES = 256  # angles of a plan a STATUS lists (more: the plan is left out, and says so)


class RobotState(enum.IntEnum):
    IDLE = 0
    MOVING = 1
    CAPTURING = 2
    SWEEPING = 3
    PAUSED = 4
    FAULT = 5


@dataclass(frozen=True, slots=True)
class Disk:
    state: str = wire(Word(DISK_STATES), "room under the robot's state_dir", tag=1)
    free: int | None = wire(Maybe(Int(0, INT64)), "bytes free there", tag=2, default=None)


@dataclass(frozen=True, slots=True)
class Rejection:
    reason: str = wire(Text(32, empty=False), "why the robot's link refused frames (radio.frame.Reason)", tag=1)
    count: int = wire(Int(0, INT64), "frames refused for it", tag=2)


@dataclass(frozen=True, slots=True)
class FailsafeEvent:
    since: float = wire(TIME, "when the base fell silent and the arm was held", tag=1)
    until: float | None = wire(Maybe(TIME), "when the link came back; nil while it lasts", tag=2, default=None)

    def problem(self) -> str:
        return "" if self.until is None or self.until >= self.since else "failsafe ends before it began"


@dataclass(frozen=True, slots=True)
class SkippedPose:
    index: int = wire(Int(0, MAX_POSES - 1), "the pose's index in the plan", tag=1)
    elevation: float = wire(Float(-90.0, 90.0), "its commanded elevation, degrees", tag=2)
    azimuth: float = wire(Float(0.0, 360.0), "its commanded azimuth, degrees in [0, 360)", tag=3)
    reason: str = wire(LINE, "why it was skipped (its last try, when tried again)", tag=4)
    tries: int | None = wire(Maybe(Int(1, 1000)), "times it was tried, when more than once", tag=5, default=None)


@dataclass(frozen=True, slots=True)
class Plan:
    """A sweep's poses (`onboard.sweep.plan.SweepPlan`): elevations start..stop by step, or the
    listed ones, at each azimuth."""

    start: float = wire(Float(-90.0, 90.0), "first elevation", tag=1)
    stop: float = wire(Float(-90.0, 90.0), "last elevation", tag=2)
    step: float = wire(Float(1e-6, 180.0), "elevation step", tag=3)
    azimuths: tuple[float, ...] = wire(ListOf(Float(-3600.0, 3600.0), PLAN_ANGLES, 1), "azimuths", tag=4)
    elevations: tuple[float, ...] = wire(ListOf(Float(-90.0, 90.0), PLAN_ANGLES), "listed elevations "
                                         "(empty: start..stop by step)", tag=5, default=())

    def to_record(self) -> dict:
        """As `SweepPlan.to_record` gives it."""
        return {"start": self.start, "stop": self.stop, "step": self.step, "azimuths": list(self.azimuths),
                "elevations": list(self.elevations)}


@dataclass(frozen=True, slots=True)
class SweepReport:
    id: int = wire(Int(0, UINT32), "the sweep's number", tag=1)
    next: int | None = wire(Maybe(Int(0, MAX_POSES)), "index of the next pose to measure", tag=2, default=None)
    poses: int | None = wire(Maybe(Int(0, MAX_POSES)), "poses in the plan", tag=3, default=None)
    active: bool | None = wire(Maybe(Flag()), "whether it runs (not done, not stopped)", tag=4, default=None)
    plan: Plan | None = wire(Maybe(Record(Plan)), "its plan", tag=5, default=None)
    plan_left_out: bool | None = wire(Maybe(Flag()), f"the plan lists more than {PLAN_ANGLES} angles and "
                                      "was left out", tag=6, default=None)
    skipped: Kept | None = wire(Maybe(Latest(Record(SkippedPose), 16)), "poses skipped", tag=7, default=None)
    measured: int | None = wire(Maybe(Int(0, MAX_POSES)), "poses measured (when it is done)", tag=8, default=None)
    boot: str | None = wire(Maybe(Word(BOOTS)), "what the robot's start did with it", tag=9, default=None)
    missing: Kept | None = wire(Maybe(Latest(Record(SkippedPose), 64)), "poses not measured when it ended, "
                                "each with why (after every try)", tag=10, default=None)

    def problem(self) -> str:
        if self.next is not None and self.poses is not None and self.next > self.poses:
            return f"next pose {self.next} beyond the plan's {self.poses}"
        return ""


@dataclass(frozen=True, slots=True)
class DeadLetter:
    msg_id: int = wire(Int(0, UINT64), "the robot's message the base refused", tag=1)
    kind: Kind | None = wire(Maybe(Choice(Kind)), "its packet kind, when the robot still held it", tag=2,
                             default=None)
    reason: str = wire(LINE, "the base's reason", tag=3, default="")
    time: float | None = wire(Maybe(TIME), "when it was set aside", tag=4, default=None)


@dataclass(frozen=True, slots=True)
class DeadLetters:
    count: int = wire(Int(0, INT64), "messages the base refused, set aside and never sent again", tag=1)
    latest: Kept = wire(Latest(Record(DeadLetter), 4), "the newest of them", tag=2, factory=Kept)


@dataclass(frozen=True, slots=True)
class StatusReport:
    """The robot's state. None: not said in this packet."""

    mode: str | None = wire(Maybe(Word(MODES)), "what the robot is doing", tag=1, default=None)
    outbox: int | None = wire(Maybe(Int(0, UINT32)), "packets waiting for the base's acknowledgement", tag=2,
                              default=None)
    paused: str | None = wire(Maybe(LINE), "why acquisition waits (\"\": it does not)", tag=3, default=None)
    disk: Disk | None = wire(Maybe(Record(Disk)), "room on the robot's disk", tag=4, default=None)
    rejected: Kept | None = wire(Maybe(Latest(Record(Rejection), 32)), "frames the robot's link refused, by reason",
                                 tag=5, default=None)
    failsafe: Kept | None = wire(Maybe(Latest(Record(FailsafeEvent), 8)), "the failsafe's holds", tag=6,
                                 default=None)
    failsafe_s: float | None = wire(Maybe(Float(0.0, 86400.0)), "silence from the base after which the arm "
                                    "is held, seconds", tag=7, default=None)
    torque: bool | None = wire(Maybe(Flag()), "whether the servos hold", tag=8, default=None)
    faults: Kept | None = wire(Maybe(Latest(LINE, 8)), "the capture pipeline's faults", tag=9, default=None)
    errors: Kept | None = wire(Maybe(Latest(LINE, 16)), "errors a person should know of", tag=10, default=None)
    sweep: SweepReport | None = wire(Maybe(Record(SweepReport)), "the sweep", tag=11, default=None)
    camera: str | None = wire(Maybe(LINE), "what the camera holds (at boot)", tag=12, default=None)
    dead_letters: DeadLetters | None = wire(Maybe(Record(DeadLetters)), "messages the base refused", tag=13,
                                            default=None)
    pose_ms: float | None = wire(Maybe(Float(0.0, 3.6e6)), "the last pose's compute, features to encoded "
                                 "packets, milliseconds", tag=14, default=None)


@dataclass(frozen=True, slots=True)
class StatusPacket(Declared):
    """The robot's state; also the payload of every heartbeat."""

    KIND: ClassVar[Kind] = Kind.STATUS
    robot_id: int = wire(Int(0, 0xFFFF), "the robot", label="robot id")
    time: float = wire(TIME, "the robot's clock, seconds since 1970")
    state: RobotState = wire(Choice(RobotState), "its state", label="robot state")
    pose: tuple[float, float] | None = wire(Angles(optional=True), "measured (elevation, azimuth), nil if unknown")
    outbox_pending: int = wire(Int(0, UINT32), "packets in its outbox")
    outbox_bytes: int = wire(Int(0, INT64), "bytes of its outbox quota in use")
    last_seq: int | None = wire(Maybe(Int(0, UINT32)), "its last capture's number")
    text: str = wire(Text(), "what happened, for a person", label="status text", default="")
    extras: Mapping[str, Any] = field(default_factory=dict)
    report: StatusReport = wire(Record(StatusReport), "the report's fields this STATUS says", since=4,
                                factory=StatusReport)

    @classmethod
    def from_values(cls, values: dict[str, Any], extras: dict, version: int, compute: bool = True) -> StatusPacket:
        if version < 4:
            values["report"] = legacy_report(extras, values["text"])
        return super(StatusPacket, cls).from_values(values, extras, version, compute)


def legacy_report(extras: Mapping[str, Any], text: str) -> StatusReport:
    """The report a schema-3 STATUS named in its extras (what the robots of then sent: mode,
    camera, disk, the sweep, its skipped pose and count measured); a key of another type is
    left in the extras unread."""
    x = dict(extras)

    def get(key: str, kind: Any) -> Any:
        try:
            return kind.check(x[key], key) if key in x else None
        except FrameError:
            return None

    disk, sweep_id = get("disk", Word(DISK_STATES)), get("sweep", Int(0, UINT32))
    sweep = None
    if sweep_id is not None:
        index = get("skipped_index", Int(0, MAX_POSES - 1))
        el, az = get("skipped_elevation", Float(-90.0, 90.0, True)), get("skipped_azimuth", Float(-3600.0, 3600.0, True))
        skipped = None
        if index is not None and el is not None and az is not None:
            reason = LINE.fit(text.removeprefix("skipped pose: "))
            skipped = Kept((SkippedPose(index, el, az % 360.0, reason),))
        measured = get("measured", Int(0, MAX_POSES)) if text == "sweep done" else None
        sweep = SweepReport(sweep_id, skipped=skipped, measured=measured, boot=get("sweep_state", Word(BOOTS)))
    return StatusReport(mode=get("mode", Word(MODES)), camera=get("camera", LINE),
                        disk=None if disk is None else Disk(disk, get("disk_free", Int(0, INT64))), sweep=sweep)
