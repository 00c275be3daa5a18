"""COMMAND: a remote-control command from the base; `command_id` makes retries idempotent.
Its arguments are checked against the command table (`radio.packets.commands`)."""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

from radio import FrameError
from radio.packets.base import UINT32, Kind
from radio.packets.commands import CommandName, check_args
from radio.packets.schema import Choice, Declared, FieldType, Int, wire


class Arguments(FieldType):
    """A map of the command's arguments, as the command table declares them."""

    def check(self, v: Any, name: str) -> dict:
        if not isinstance(v, dict):
            raise FrameError(f"{name} must be a map")
        return v  # checked against the named command's table entry, once the name is known

    def to_wire(self, v: Any, name: str) -> dict:
        return {k: list(x) if isinstance(x, tuple) else x for k, x in v.items()}

    def describe(self) -> str:
        return "map: the command table's arguments of the command"


@dataclass(frozen=True, slots=True)
class CommandPacket(Declared):
    """A remote-control command; `command_id` makes retries idempotent."""

    KIND: ClassVar[Kind] = Kind.COMMAND
    command_id: int = wire(Int(0, UINT32), "the command's id: a retry of it has the same", label="command id")
    name: CommandName = wire(Choice(CommandName), "which command", label="command")
    args: Mapping[str, Any] = wire(Arguments(), "its arguments", label="arguments", factory=dict)
    extras: Mapping[str, Any] = field(default_factory=dict)

    @classmethod
    def from_values(cls, values: dict[str, Any], extras: dict, version: int, compute: bool = True) -> CommandPacket:
        values["args"] = check_args(values["name"], values["args"])
        return super(CommandPacket, cls).from_values(values, extras, version, compute)
