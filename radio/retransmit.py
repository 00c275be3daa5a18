"""The sender's retransmission state: a frame in flight and the retransmission timer
(RFC 6298's smoothed RTT and variance, clamped, with backoff after repeated timeouts)."""
from __future__ import annotations

from dataclasses import dataclass

DUPTHRESH = 3  # later frames that must arrive before a missing one counts as lost
BACKOFF = 2.0  # RTO growth after a timeout, until a fresh RTT sample
GRACE_TIMEOUTS = 2  # timeouts in a row before the RTO starts to grow
TAIL_COPIES, TAIL_FRAMES = 2, 4  # copies of each frame when at most TAIL_FRAMES time out


@dataclass
class InFlight:
    data: bytes
    ends: list[int]  # messages this frame completes
    sent_at: float = -1.0
    tries: int = 0
    xmit: int = 0  # transmission index: orders (re)transmissions for loss detection
    copies: int = 1  # back-to-back copies at the next retransmission
    sacked: bool = False
    lost: bool = False


class RetransmitTimer:
    def __init__(self, rto: float, min_rto: float, max_rto: float) -> None:
        self.rto, self.min_rto, self.max_rto = rto, min_rto, max_rto
        self._srtt: float | None = None
        self._rttvar = 0.0

    def sample(self, rtt: float) -> None:
        if self._srtt is None:
            self._srtt, self._rttvar = rtt, rtt / 2
        else:
            self._rttvar = 0.75 * self._rttvar + 0.25 * abs(self._srtt - rtt)
            self._srtt = 0.875 * self._srtt + 0.125 * rtt
        self.rto = min(self.max_rto, max(self.min_rto, self._srtt + 4 * self._rttvar))

    def back_off(self) -> None:
        self.rto = min(self.max_rto, BACKOFF * self.rto)
