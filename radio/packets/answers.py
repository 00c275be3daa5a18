"""ACK and NACK: the robot's answers to commands, and the base's refusal of a robot's message.

An ACK's text is its command's name; its extras are the command's answer, each value checked
against the command table (`radio.packets.commands.COMMANDS[name].answer`); the answer to
STATUS carries the robot's whole report (`status`, schema 4). A NACK refuses a command with a
reason and a sentence, or (reason UNUSABLE, schema 4) tells the robot that the base could not
use its message `msg_id`: the robot sets that message aside and never sends it again.
"""
from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

from radio.packets.base import UINT32, UINT64, Kind
from radio.packets.commands import CommandName, check_answer
from radio.packets.schema import Choice, Declared, Int, Maybe, Record, Text, wire
from radio.packets.status import StatusReport


class Reason(enum.IntEnum):
    """Why a command was refused (NACK), or (UNUSABLE) why the base refused a robot's message."""

    UNKNOWN_COMMAND = 1
    BAD_ARGUMENT = 2
    BUSY = 3
    OUT_OF_LIMITS = 4
    HARDWARE = 5
    OUTBOX_FULL = 6
    NOT_FOUND = 7
    INTERNAL = 8
    TORQUE_OFF = 9  # the servos were released (TORQUE_OFF): TORQUE_ON first
    UNUSABLE = 10  # the base could not use the robot's message `msg_id`: it is set aside


@dataclass(frozen=True, slots=True)
class AckPacket(Declared):
    """The robot accepted (and, for quick commands, carried out) command `command_id`."""

    KIND: ClassVar[Kind] = Kind.ACK
    command_id: int = wire(Int(0, UINT32), "the command answered", label="command id")
    text: str = wire(Text(), "the command's name", label="ack text", default="")
    extras: Mapping[str, Any] = field(default_factory=dict)  # the answer (the command table's `answer`)
    status: StatusReport | None = wire(Maybe(Record(StatusReport)), "STATUS's answer: the robot's whole report",
                                       since=4, default=None)

    @property
    def name(self) -> CommandName | None:
        """The command answered, as the ACK names it."""
        return CommandName.__members__.get(self.text)

    @classmethod
    def from_values(cls, values: dict[str, Any], extras: dict, version: int, compute: bool = True) -> AckPacket:
        name = CommandName.__members__.get(values["text"])
        if name is not None and not (version < 4 and name is CommandName.STATUS):  # its report was the extras then
            extras = check_answer(name, extras)
        return super(AckPacket, cls).from_values(values, extras, version, compute)

    def problem(self) -> str:
        if self.status is not None and self.name is not CommandName.STATUS:
            return f"an answer to {self.text or 'a command'} carries a STATUS report"
        return ""


@dataclass(frozen=True, slots=True)
class NackPacket(Declared):
    """Command `command_id` refused, with a reason code and a human sentence; or (UNUSABLE) the
    robot's message `msg_id` refused by the base."""

    KIND: ClassVar[Kind] = Kind.NACK
    command_id: int = wire(Int(0, UINT32), "the command refused (0 for a message)", label="command id")
    reason: Reason = wire(Choice(Reason), "why", label="nack reason")
    text: str = wire(Text(), "why, for a person", label="nack text", default="")
    extras: Mapping[str, Any] = field(default_factory=dict)
    msg_id: int | None = wire(Maybe(Int(0, UINT64)), "the robot's message the base refused (UNUSABLE only)",
                              since=4, label="message id", default=None)

    def problem(self) -> str:
        if (self.reason is Reason.UNUSABLE) != (self.msg_id is not None):
            return "a NACK names a refused message (msg_id) exactly when its reason is UNUSABLE"
        return ""
