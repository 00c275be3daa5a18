"""Packet bodies: schema-versioned msgpack arrays, one frozen dataclass per kind, one module per
kind (`models`: MODELS and UNCHANGED, `mask`, `status`, `command`, `answers`: ACK and NACK, `log`).

A body is the msgpack array [version, kind, field, ...] with an optional trailing map of
extension fields (`extras`). Each kind's fields are declared once, with their types and bounds
(`radio.packets.schema`); the same declarations encode, decode and write the schema's document
(`python -m radio.packets`, docs/packets.md). `decode` takes untrusted bytes: bounded unpacking,
then the type and range of every field, nested records included, is checked; anything wrong
raises `radio.FrameError` with the reason. `encode` fits what a sender may cut (a long text, the
oldest items of a bounded list, counted) and checks its own output the same way, so a packet
that encodes always decodes.

A kind is encoded at its newest schema version (3; 4 for STATUS, ACK and NACK, 5 for MODELS,
whose layouts grew); its older layouts still decode.

MODELS (schema 5, layout in `radio.packets.models`) carry each model as four percentiles in
fixed point: for 8-bit sensors 16-bit codes with a step of 2**-8 gray level, so each is within
2**-9 < 0.01 gray level of the fitted value, and the host recomputes the robot's models bit for
bit. An ordinary model costs 8 bytes; a label one bitmap bit and a varint of its pixel count and
z index; models that are not plain 2 bits in a records bitmap plus their record (1 byte for a
model read at another spread or centre than its label's). The benchmark frame of 8 labels x 3
bands with a maximal header is 279 bytes of body.
"""
from __future__ import annotations

import struct
from collections.abc import Mapping
from typing import Any

from radio import FrameError
from radio.packets.answers import AckPacket, NackPacket, Reason
from radio.packets.base import (
    MAX_BODY,
    NEWEST_VERSION,
    SCHEMA_VERSION,
    Kind,
    PacketTooLarge,
    pack_body,
    split_fields,
    unpack_body,
)
from radio.packets.command import CommandPacket
from radio.packets.commands import CommandName
from radio.packets.log import LogLevel, LogPacket
from radio.packets.mask import MAX_SIDE, MaskPacket, downsample_labels, mask_packet
from radio.packets.models import LabelModels, ModelsPacket, UnchangedPacket, models_packet
from radio.packets.schema import Kept, layout, newest, values_from_wire, values_to_wire, width
from radio.packets.status import (
    DeadLetter,
    DeadLetters,
    Disk,
    FailsafeEvent,
    Plan,
    Rejection,
    RobotState,
    SkippedPose,
    StatusPacket,
    StatusReport,
    SweepReport,
)

__all__ = [
    "SCHEMA_VERSION", "NEWEST_VERSION", "MAX_BODY", "MAX_SIDE", "Kind", "CommandName", "Reason", "LogLevel",
    "RobotState", "LabelModels", "ModelsPacket", "UnchangedPacket", "MaskPacket", "StatusPacket",
    "CommandPacket", "AckPacket", "NackPacket", "LogPacket", "Packet", "KINDS", "encode", "decode",
    "encode_models", "encode_mask", "models_packet", "mask_packet", "downsample_labels", "StatusReport",
    "SweepReport", "Plan", "SkippedPose", "FailsafeEvent", "Rejection", "Disk", "DeadLetter", "DeadLetters",
    "Kept", "version_of", "PacketTooLarge",
]

Packet = (ModelsPacket | UnchangedPacket | MaskPacket | StatusPacket | CommandPacket
          | AckPacket | NackPacket | LogPacket)
KINDS: dict[Kind, Any] = {
    cls.KIND: cls for cls in (ModelsPacket, UnchangedPacket, MaskPacket, StatusPacket,
                              CommandPacket, AckPacket, NackPacket, LogPacket)
}


def version_of(kind: Kind) -> int:
    """The schema version `kind` is encoded at."""
    return newest(KINDS[kind])


def _decode(body: bytes, compute: bool) -> Packet:
    items = unpack_body(body)
    version, kind = items[0], Kind(items[1])
    cls = KINDS[kind]
    if version > newest(cls):
        raise FrameError(f"unsupported schema version {version} for {kind.name} (at most {newest(cls)})")
    fields, extras = split_fields(items, kind, width(cls, version))
    return cls.from_values(values_from_wire(layout(cls, version), fields), extras, version, compute)


def decode(body: bytes) -> Packet:
    """Decode one untrusted packet body; raises FrameError naming what is wrong."""
    return _decode(body, compute=True)


def encode(packet: Packet) -> bytes:
    """The packet's body; raises ValueError if a field is out of the schema's range, and
    PacketTooLarge (a ValueError) if the body would be longer than a link message (MAX_BODY)."""
    try:
        cls = type(packet)
        given = packet.wire_values()
        values = {f.name: f.type.fit(given[f.name]) for f in layout(cls)}
        body = pack_body(cls.KIND, newest(cls), values_to_wire(layout(cls), values), packet.extras)
        if len(body) > MAX_BODY:
            raise PacketTooLarge(f"{cls.KIND.name} body of {len(body)} bytes exceeds the link's largest "
                                 f"message, {MAX_BODY} bytes")
        _decode(body, compute=False)  # the decoder's checks are the one statement of the schema
    except (FrameError, OverflowError, TypeError, AttributeError, KeyError, struct.error) as exc:
        raise ValueError(f"cannot encode {type(packet).__name__}: {exc}") from None
    return body


def encode_models(fits: Mapping, **kwargs: Any) -> bytes:
    """The MODELS body for the fitter's results {(label, band index): FittedModel}; see `models_packet`."""
    return encode(models_packet(fits, **kwargs))


def encode_mask(labels: Any, **kwargs: Any) -> bytes:
    """The MASK body for a frame's label map; see `mask_packet`."""
    return encode(mask_packet(labels, **kwargs))
