"""The station's events, one declaration each: a frozen dataclass per kind, whose fields are its
JSON form (`to_json`: {"kind", "time" (ISO 8601, UTC), "t" (epoch s), "text", "tone", ...its
fields}). The log writes that form a line and `line()` on stderr; the control socket, `btf-host
watch` and the operator's page get the same form and render it from what it declares: its
`text`, its `tone` ("ok", "bad" or "") and whether a person is shown it (`shown`: the station's
own STATUS polls are not). `python -m tools.station.events` lists every kind and its fields.

`text` is the one line a person reads; the other fields are for programs.
"""
from __future__ import annotations

import dataclasses
import enum
from dataclasses import dataclass
from typing import Any, ClassVar

from radio.packets.base import iso_time


class Tone(enum.StrEnum):
    PLAIN = ""
    OK = "ok"
    BAD = "bad"


@dataclass(frozen=True)
class Event:
    KIND: ClassVar[str] = ""
    t: float  # wall-clock seconds
    text: str

    @property
    def tone(self) -> Tone:
        return Tone.PLAIN

    @property
    def shown(self) -> bool:
        """Whether `watch` and the page list it."""
        return True

    def to_json(self) -> dict[str, Any]:
        fields = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name not in ("t", "text")}
        return {"kind": self.KIND, "time": iso_time(self.t), "t": round(self.t, 3), "text": self.text,
                "tone": self.tone.value, **({} if self.shown else {"shown": False}), **fields}


def line(ev: dict[str, Any], timed: bool = False) -> str:
    """An event's JSON form as one line for a person (the station's stderr, `btf-host watch`)."""
    return f"{ev.get('time') or '?'} " * timed + f"{ev.get('kind')}: {ev.get('text')}"


@dataclass(frozen=True)
class PacketEvent(Event):
    """A packet from the robot: its robot, capture number (or last capture, for STATUS) and
    whether it was stored anew."""

    robot: int | None = None
    seq: int | None = None
    stored: bool = False


@dataclass(frozen=True)
class CaptureEvent(PacketEvent):
    """A capture filed: `capture` is the row the snapshot lists (robot, seq, angles, regions)."""

    KIND: ClassVar[str] = "capture"
    capture: dict | None = None


@dataclass(frozen=True)
class UnchangedEvent(CaptureEvent):
    """A capture whose models are an earlier one's at the same pose."""

    KIND: ClassVar[str] = "unchanged"


@dataclass(frozen=True)
class MaskEvent(PacketEvent):
    KIND: ClassVar[str] = "mask"


@dataclass(frozen=True)
class StatusEvent(PacketEvent):
    """A STATUS, or the answer to the station's own STATUS request (`poll`: not shown, not logged)."""

    KIND: ClassVar[str] = "status"
    packet: dict | None = None  # `tools.station.receiver.packet_json`
    poll: bool = False

    @property
    def shown(self) -> bool:
        return not self.poll


@dataclass(frozen=True)
class FailsafeReport(StatusEvent):
    """The robot's STATUS saying the failsafe held the arm."""

    KIND: ClassVar[str] = "failsafe"

    @property
    def tone(self) -> Tone:
        return Tone.BAD


@dataclass(frozen=True)
class LogEvent(PacketEvent):
    KIND: ClassVar[str] = "log"
    packet: dict | None = None


@dataclass(frozen=True)
class OtherEvent(PacketEvent):
    KIND: ClassVar[str] = "other"
    packet: dict | None = None


@dataclass(frozen=True)
class RefusedEvent(PacketEvent):
    """A message the station could not use: kept raw in the database (`rejected`: its row in
    rejected_packets) and refused to the robot (a NACK UNUSABLE naming `msg_id`), which sets it
    aside; `told`: whether the NACK went out."""

    KIND: ClassVar[str] = "bad"
    msg_id: int | None = None
    reason: str = ""
    size: int = 0
    rejected: int | None = None
    told: bool = False

    @property
    def tone(self) -> Tone:
        return Tone.BAD


@dataclass(frozen=True)
class CommandEvent(Event):
    """A command sent to the robot."""

    KIND: ClassVar[str] = "command"
    command_id: int = 0
    name: str = ""
    args: dict = dataclasses.field(default_factory=dict)


@dataclass(frozen=True)
class AnswerEvent(Event):
    """The robot's ACK or NACK of a command (`answer`: as `Station.submit`'s future gives it)."""

    KIND: ClassVar[str] = "answer"
    command_id: int = 0
    ok: bool = False
    answer: dict = dataclasses.field(default_factory=dict)

    @property
    def tone(self) -> Tone:
        return Tone.OK if self.ok else Tone.BAD


@dataclass(frozen=True)
class LinkEvent(Event):
    """The link went up or down, or (`stale`) the robot's counters are behind."""

    KIND: ClassVar[str] = "link"
    up: bool = False
    stale: bool = False

    @property
    def tone(self) -> Tone:
        return Tone.OK if self.up and not self.stale else Tone.BAD


@dataclass(frozen=True)
class RejectedEvent(Event):
    """Frames the link refused since the last such event, for `reason`, with its likely cause;
    `wrong_key`: none has passed, and the line says the key is likely wrong."""

    KIND: ClassVar[str] = "rejected"
    reason: str = ""
    count: int = 0
    total: int = 0
    cause: str = ""
    wrong_key: bool = False

    @property
    def tone(self) -> Tone:
        return Tone.BAD


@dataclass(frozen=True)
class StationEvent(Event):
    """The station started, stopped, or failed (`failed`)."""

    KIND: ClassVar[str] = "station"
    failed: bool = False

    @property
    def tone(self) -> Tone:
        return Tone.BAD if self.failed else Tone.PLAIN


@dataclass(frozen=True)
class LostEvent(Event):
    """A subscriber fell behind: `count` events were dropped from its queue (`tools.station.bus`)."""

    KIND: ClassVar[str] = "lost"
    count: int = 0

    @property
    def tone(self) -> Tone:
        return Tone.BAD


KINDS: dict[str, type[Event]] = {cls.KIND: cls for cls in (
    CaptureEvent, UnchangedEvent, MaskEvent, StatusEvent, FailsafeReport, LogEvent, OtherEvent, RefusedEvent,
    CommandEvent, AnswerEvent, LinkEvent, RejectedEvent, StationEvent, LostEvent)}


def schema() -> str:
    """Every kind and its fields, for a person."""
    out = []
    for kind, cls in KINDS.items():
        fields = ", ".join(f.name for f in dataclasses.fields(cls) if f.name not in ("t", "text"))
        out.append(f"{kind}: {fields or '-'}\n    {' '.join((cls.__doc__ or '').split())}")
    return "\n".join(out)


if __name__ == "__main__":
    print(schema())
