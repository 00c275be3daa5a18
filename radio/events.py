"""What a `radio.link.Link` reports: its events (one queue, `Link.pop_events`) and statistics."""
from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True, slots=True)
class Delivered:
    sender: int
    msg_id: int
    payload: bytes
    incarnation: bytes = b""  # the sender's state, named in its session's SYN (`Link(incarnation=)`)


@dataclass(frozen=True, slots=True)
class Acked:
    msg_id: int


@dataclass(frozen=True, slots=True)
class LinkUp:
    pass


@dataclass(frozen=True, slots=True)
class LinkDown:
    pass


@dataclass(frozen=True, slots=True)
class PeerStale:
    """Every authenticated frame from the peer is refused as stale or replayed: its counters
    are behind this end's. Raised once per run of refusals; `text` is the line to show."""

    sender: int
    refused: int
    text: str


Event = Delivered | Acked | LinkUp | LinkDown | PeerStale


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
