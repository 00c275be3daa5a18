"""Packet bodies: schema-versioned msgpack arrays, one frozen dataclass per kind.

A body is the msgpack array [SCHEMA_VERSION, kind, field, ...] with an optional trailing map
of extension fields (`extras`) that later schema growth may use; everything else is decoded
strictly. `decode` takes untrusted bytes: bounded unpacking, then the type and range of every
field is checked; anything wrong raises `radio.FrameError` with the reason. `encode` checks
its own output the same way, so a packet that encodes always decodes.

MODELS (schema 3, layout in `radio.packets.models`) carry each model as four percentiles in
fixed point: for 8-bit sensors 16-bit codes with a step of 2**-8 gray level, so each is within
2**-9 < 0.01 gray level of the fitted value, and the host recomputes the robot's models bit for
bit. An ordinary model costs 8 bytes; a label one bitmap bit and a varint of its pixel count and
z index; models that are not plain 2 bits in a records bitmap plus their record (1 byte for a
model read at another spread or centre than its label's). The benchmark frame of 8 labels x 3
bands with a maximal header is 279 bytes of body.
"""
from __future__ import annotations

import enum
import struct
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

from radio import FrameError
from radio.packets.base import (
    MAX_BODY,
    SCHEMA_VERSION,
    UINT32,
    Kind,
    angles_from_wire,
    angles_to_wire,
    pack_body,
    split_fields,
    unpack_body,
    want_enum,
    want_float,
    want_int,
    want_str,
)
from radio.packets.commands import CommandName, check_args
from radio.packets.mask import MAX_SIDE, MaskPacket, downsample_labels, mask_packet
from radio.packets.models import LabelModels, ModelsPacket, models_packet

__all__ = [
    "SCHEMA_VERSION", "MAX_BODY", "MAX_SIDE", "Kind", "CommandName", "Reason", "LogLevel",
    "RobotState", "LabelModels", "ModelsPacket", "UnchangedPacket", "MaskPacket", "StatusPacket",
    "CommandPacket", "AckPacket", "NackPacket", "LogPacket", "Packet", "encode", "decode",
    "encode_models", "encode_mask", "models_packet", "mask_packet", "downsample_labels",
]


class Reason(enum.IntEnum):
    """Why a command was refused (NACK)."""

    UNKNOWN_COMMAND = 1
    BAD_ARGUMENT = 2
    BUSY = 3
    OUT_OF_LIMITS = 4
    HARDWARE = 5
    OUTBOX_FULL = 6
    NOT_FOUND = 7
    INTERNAL = 8
    TORQUE_OFF = 9  # the servos were released (TORQUE_OFF): TORQUE_ON first


class LogLevel(enum.IntEnum):  # the values of the stdlib logging levels
    DEBUG = 10
    INFO = 20
    WARNING = 30
    ERROR = 40


class RobotState(enum.IntEnum):
    IDLE = 0
    MOVING = 1
    CAPTURING = 2
    SWEEPING = 3
    PAUSED = 4
    FAULT = 5


@dataclass(frozen=True, slots=True)
class UnchangedPacket:
    """A capture whose models all lie within tolerance of capture `ref_seq` at the same pose."""

    KIND: ClassVar[Kind] = Kind.UNCHANGED
    robot_id: int
    seq: int
    time: float
    commanded: tuple[float, float]
    measured: tuple[float, float]
    ref_seq: int
    extras: Mapping[str, Any] = field(default_factory=dict)

    def _wire(self) -> list:
        return [
            self.robot_id, self.seq, float(self.time),
            *angles_to_wire(self.commanded, "commanded"), *angles_to_wire(self.measured, "measured"),
            self.ref_seq,
        ]

    @classmethod
    def _from_wire(cls, f: list, extras: dict, compute: bool = True) -> UnchangedPacket:
        seq = want_int(f[1], "capture seq", 0, UINT32)
        ref = want_int(f[7], "reference seq", 0, UINT32)
        if ref >= seq:
            raise FrameError(f"reference capture {ref} is not before capture {seq}")
        return cls(
            want_int(f[0], "robot id", 0, 0xFFFF), seq, want_float(f[2], "time", 0.0),
            angles_from_wire(f[3], f[4], "commanded"), angles_from_wire(f[5], f[6], "measured"),
            ref, extras,
        )


@dataclass(frozen=True, slots=True)
class StatusPacket:
    """The robot's state; also the payload of every heartbeat."""

    KIND: ClassVar[Kind] = Kind.STATUS
    robot_id: int
    time: float
    state: RobotState
    pose: tuple[float, float] | None  # measured (elevation, azimuth), None if unknown
    outbox_pending: int
    outbox_bytes: int
    last_seq: int | None
    text: str = ""
    extras: Mapping[str, Any] = field(default_factory=dict)

    def _wire(self) -> list:
        pose = [None, None] if self.pose is None else angles_to_wire(self.pose, "pose")
        return [self.robot_id, float(self.time), int(self.state), *pose, self.outbox_pending,
                self.outbox_bytes, self.last_seq, self.text]

    @classmethod
    def _from_wire(cls, f: list, extras: dict, compute: bool = True) -> StatusPacket:
        pose = None if f[3] is None and f[4] is None else angles_from_wire(f[3], f[4], "pose")
        return cls(
            want_int(f[0], "robot id", 0, 0xFFFF), want_float(f[1], "time", 0.0),
            want_enum(f[2], RobotState, "robot state"), pose,
            want_int(f[5], "outbox pending", 0, UINT32), want_int(f[6], "outbox bytes", 0, 2**63 - 1),
            None if f[7] is None else want_int(f[7], "last seq", 0, UINT32),
            want_str(f[8], "status text"), extras,
        )


@dataclass(frozen=True, slots=True)
class CommandPacket:
    """A remote-control command; `command_id` makes retries idempotent. Its arguments are
    checked against the command table (`radio.packets.commands`)."""

    KIND: ClassVar[Kind] = Kind.COMMAND
    command_id: int
    name: CommandName
    args: Mapping[str, Any] = field(default_factory=dict)
    extras: Mapping[str, Any] = field(default_factory=dict)

    def _wire(self) -> list:
        args = {k: list(v) if isinstance(v, tuple) else v for k, v in self.args.items()}
        return [self.command_id, int(self.name), args]

    @classmethod
    def _from_wire(cls, f: list, extras: dict, compute: bool = True) -> CommandPacket:
        cid = want_int(f[0], "command id", 0, UINT32)
        name = want_enum(f[1], CommandName, "command")
        if not isinstance(f[2], dict):
            raise FrameError(f"{name.name} arguments must be a map")
        return cls(cid, name, check_args(name, f[2]), extras)


@dataclass(frozen=True, slots=True)
class AckPacket:
    """The robot accepted (and, for quick commands, carried out) command `command_id`."""

    KIND: ClassVar[Kind] = Kind.ACK
    command_id: int
    text: str = ""
    extras: Mapping[str, Any] = field(default_factory=dict)

    def _wire(self) -> list:
        return [self.command_id, self.text]

    @classmethod
    def _from_wire(cls, f: list, extras: dict, compute: bool = True) -> AckPacket:
        return cls(want_int(f[0], "command id", 0, UINT32), want_str(f[1], "ack text"), extras)


@dataclass(frozen=True, slots=True)
class NackPacket:
    """The robot refused command `command_id`, with a reason code and a human sentence."""

    KIND: ClassVar[Kind] = Kind.NACK
    command_id: int
    reason: Reason
    text: str = ""
    extras: Mapping[str, Any] = field(default_factory=dict)

    def _wire(self) -> list:
        return [self.command_id, int(self.reason), self.text]

    @classmethod
    def _from_wire(cls, f: list, extras: dict, compute: bool = True) -> NackPacket:
        return cls(want_int(f[0], "command id", 0, UINT32), want_enum(f[1], Reason, "nack reason"),
                   want_str(f[2], "nack text"), extras)


@dataclass(frozen=True, slots=True)
class LogPacket:
    KIND: ClassVar[Kind] = Kind.LOG
    robot_id: int
    time: float
    level: LogLevel
    text: str
    extras: Mapping[str, Any] = field(default_factory=dict)

    def _wire(self) -> list:
        return [self.robot_id, float(self.time), int(self.level), self.text]

    @classmethod
    def _from_wire(cls, f: list, extras: dict, compute: bool = True) -> LogPacket:
        return cls(want_int(f[0], "robot id", 0, 0xFFFF), want_float(f[1], "time", 0.0),
                   want_enum(f[2], LogLevel, "log level"), want_str(f[3], "log text"), extras)


Packet = (ModelsPacket | UnchangedPacket | MaskPacket | StatusPacket | CommandPacket
          | AckPacket | NackPacket | LogPacket)
_CLASSES: dict[Kind, Any] = {
    cls.KIND: cls for cls in (ModelsPacket, UnchangedPacket, MaskPacket, StatusPacket,
                              CommandPacket, AckPacket, NackPacket, LogPacket)
}
_NFIELDS = {Kind.MODELS: 6, Kind.UNCHANGED: 8, Kind.MASK: 8, Kind.STATUS: 9, Kind.COMMAND: 3,
            Kind.ACK: 2, Kind.NACK: 3, Kind.LOG: 4}


def _decode(body: bytes, compute: bool) -> Packet:
    items = unpack_body(body)
    kind = Kind(items[1])
    fields, extras = split_fields(items, kind, _NFIELDS[kind])
    return _CLASSES[kind]._from_wire(fields, extras, compute)


def decode(body: bytes) -> Packet:
    """Decode one untrusted packet body; raises FrameError naming what is wrong."""
    return _decode(body, compute=True)


def encode(packet: Packet) -> bytes:
    """The packet's body; raises ValueError if a field is out of the schema's range."""
    try:
        body = pack_body(packet.KIND, packet._wire(), packet.extras)
        _decode(body, compute=False)  # the decoder's checks are the one statement of the schema
    except (FrameError, OverflowError, TypeError, AttributeError, struct.error) as exc:
        raise ValueError(f"cannot encode {type(packet).__name__}: {exc}") from None
    return body


def encode_models(fits: Mapping, **kwargs: Any) -> bytes:
    """The MODELS body for the fitter's results {(label, band index): FittedModel}; see `models_packet`."""
    return encode(models_packet(fits, **kwargs))


def encode_mask(labels: Any, **kwargs: Any) -> bytes:
    """The MASK body for a frame's label map; see `mask_packet`."""
    return encode(mask_packet(labels, **kwargs))
