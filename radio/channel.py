"""A seeded channel simulator: loss (independent or Gilbert-Elliott bursts), bit errors,
duplication, reordering, latency and a bandwidth cap, on a simulated clock.

The written byte stream is cut into radio packets at frame boundaries (as a
packetizing serial radio would), at most `packet_size` bytes each; every packet
occupies the channel for len/bandwidth seconds, whether or not it arrives.
`radio.channel_port` makes ports of it (and the `btfsim://` URL); `radio.linktest` runs two
links through it.
"""
from __future__ import annotations

import heapq
import random
import re
from dataclasses import dataclass

_FRAMES = re.compile(rb"\x00[^\x00]+\x00|[^\x00]+|\x00+")


@dataclass(frozen=True, slots=True)
class ChannelConfig:
    loss: float = 0.0  # mean packet loss
    bursty: bool = False  # Gilbert-Elliott bursts instead of independent loss
    burst_len: float = 4.0  # mean packets per burst
    ber: float = 0.0  # bit error rate on packets that arrive
    dup: float = 0.0
    reorder: float = 0.0  # probability a packet is held back behind later ones
    latency: float = 0.01  # seconds, one way
    bandwidth: float = 31250.0  # bytes per second (250 kbit/s)
    packet_size: int = 100
    buffer: int = 400  # bytes the sender may queue ahead of the air

    def __post_init__(self) -> None:
        for name in ("loss", "dup", "reorder"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise ValueError(f"{name} {getattr(self, name)} outside [0, 1)")
        if not 0.0 <= self.ber < 0.5:
            raise ValueError(f"ber {self.ber} outside [0, 0.5)")
        if self.burst_len < 1.0:
            raise ValueError(f"burst_len {self.burst_len} below 1")
        if self.latency < 0 or self.bandwidth <= 0 or self.packet_size < 1 or self.buffer < 1:
            raise ValueError("latency, bandwidth, packet_size and buffer must be positive")


class Channel:
    """One direction of a simulated radio."""

    def __init__(self, config: ChannelConfig, seed: int = 0) -> None:
        self.config = config
        self._rng = random.Random(seed)
        self._bad = False
        self._free_at = 0.0  # when the air is free for the next packet
        self._heap: list[tuple[float, int, bytes]] = []
        self._n = 0
        self.packets = self.lost = self.corrupted = self.duplicated = self.reordered = 0

    def backlog(self, now: float) -> int:
        """Bytes written and not yet on the air at `now`."""
        return int(max(0.0, self._free_at - now) * self.config.bandwidth)

    def room(self, now: float) -> int:
        """Bytes the sender may write now without exceeding the transmit buffer."""
        backlog = max(0.0, self._free_at - now) * self.config.bandwidth
        return max(0, int(self.config.buffer - backlog))

    def transmit(self, data: bytes, now: float) -> None:
        cfg = self.config
        for m in _FRAMES.finditer(data):
            unit = m.group()
            for i in range(0, len(unit), cfg.packet_size):
                self._packet(unit[i:i + cfg.packet_size], now)

    def _lost(self) -> bool:
        cfg, rng = self.config, self._rng
        if not cfg.bursty:
            return rng.random() < cfg.loss
        # Gilbert: bad state loses everything; stationary P(bad) equals the mean loss.
        leave = 1.0 / cfg.burst_len
        enter = cfg.loss * leave / (1.0 - cfg.loss)
        self._bad = (rng.random() >= leave) if self._bad else (rng.random() < enter)
        return self._bad

    def _packet(self, pkt: bytes, now: float) -> None:
        cfg, rng = self.config, self._rng
        self.packets += 1
        start = max(now, self._free_at)
        self._free_at = start + len(pkt) / cfg.bandwidth
        if self._lost():
            self.lost += 1
            return
        copies = 2 if rng.random() < cfg.dup else 1
        self.duplicated += copies - 1
        for _ in range(copies):
            out = self._flip(pkt)
            t = self._free_at + cfg.latency
            if rng.random() < cfg.reorder:
                self.reordered += 1
                t += rng.uniform(1.0, 4.0) * cfg.packet_size / cfg.bandwidth
            self._n += 1
            heapq.heappush(self._heap, (t, self._n, out))

    def _flip(self, pkt: bytes) -> bytes:
        ber = self.config.ber
        if ber <= 0.0:
            return pkt
        nbits = 8 * len(pkt)
        # Binomial count by Poisson approximation keeps this cheap for tiny BER.
        k, p, u = 0, pow(1.0 - ber, nbits), self._rng.random()
        cum = p
        while u > cum and k < nbits:
            k += 1
            p *= (nbits - k + 1) / k * ber / (1.0 - ber)
            cum += p
        if k == 0:
            return pkt
        self.corrupted += 1
        buf = bytearray(pkt)
        for bit in self._rng.sample(range(nbits), k):
            buf[bit // 8] ^= 1 << (bit % 8)
        return bytes(buf)

    def deliver(self, now: float) -> bytes:
        """Bytes that have arrived by `now`, in arrival order."""
        out = bytearray()
        while self._heap and self._heap[0][0] <= now:
            out += heapq.heappop(self._heap)[2]
        return bytes(out)

    def next_arrival(self) -> float | None:
        return self._heap[0][0] if self._heap else None
