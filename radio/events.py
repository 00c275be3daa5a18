"""What a `radio.link.Link` reports: its events (one queue, `Link.pop_events`) and statistics."""
from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True, slots=True)
class Delivered:
    sender: int
    msg_id: int
    payload: bytes


@dataclass(frozen=True, slots=True)
class Acked:
    msg_id: int


@dataclass(frozen=True, slots=True)
class LinkUp:
    pass


@dataclass(frozen=True, slots=True)
class LinkDown:
    pass


Event = Delivered | Acked | LinkUp | LinkDown


class QueueFull(RuntimeError):
    """The link holds `max_queue_bytes` of unacknowledged data already; try again later."""


@dataclass(frozen=True, slots=True)
class LinkStats:
    frames_sent: int
    bytes_sent: int
    frames_accepted: int
    retransmissions: int
    delivered: int
    duplicates: int
    acked: int
    sessions_opened: int
    rejected: dict[str, int] = field(default_factory=dict)
    repaired: int = 0  # accepted frames whose single bit error the CRC corrected
