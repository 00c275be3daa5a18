"""LOG: a line of the robot's log, with its level."""
from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

from radio.packets.base import Kind
from radio.packets.schema import Choice, Declared, Int, Text, wire
from radio.packets.status import TIME


class LogLevel(enum.IntEnum):  # the values of the stdlib logging levels
    DEBUG = 10
    INFO = 20
    WARNING = 30
    ERROR = 40


@dataclass(frozen=True, slots=True)
class LogPacket(Declared):
    """A line of the robot's log."""

    KIND: ClassVar[Kind] = Kind.LOG
    robot_id: int = wire(Int(0, 0xFFFF), "the robot", label="robot id")
    time: float = wire(TIME, "the robot's clock, seconds since 1970")
    level: LogLevel = wire(Choice(LogLevel), "the line's level", label="log level")
    text: str = wire(Text(), "the line", label="log text")
    extras: Mapping[str, Any] = field(default_factory=dict)
