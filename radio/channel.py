"""A seeded channel simulator: loss (independent or Gilbert-Elliott bursts), bit errors,
duplication, reordering, latency and a bandwidth cap, on a simulated clock.

The written byte stream is cut into radio packets at frame boundaries (as a
packetizing serial radio would), at most `packet_size` bytes each; every packet
occupies the channel for len/bandwidth seconds, whether or not it arrives.
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


@dataclass(frozen=True, slots=True)
class LinktestResult:
    sent: int
    delivered: int
    delivered_twice: int
    out_of_order: int
    corrupted_accepted: int
    forged_accepted: int
    commands_sent: int
    commands_delivered: int
    goodput: float  # payload bytes/s over (1 - loss) x bandwidth
    sim_seconds: float
    payload_bytes: int
    retransmissions: int
    repaired: int  # frames accepted after a single bit error was corrected, both ends
    forged_injected: int
    replays_injected: int
    rejected: dict[str, int]


def run_linktest(config: ChannelConfig, packets: int = 500, seed: int = 0, *,
                 sizes: tuple[int, int] = (150, 400), commands: int = 20, forged: int = 50,
                 replays: int = 50, mtu: int = 100, step: float = 0.001,
                 max_seconds: float = 3600.0) -> LinktestResult:
    """A robot end streaming `packets` messages to a host end, which sends `commands` back,
    through two seeded channels; forged frames (wrong key) and replayed genuine frames are
    injected at the host. Returns what arrived, how, and how fast."""
    from radio.auth import MemoryCounterStore
    from radio.link import Acked, Delivered, Link

    rng = random.Random(seed)
    key, bad_key = rng.randbytes(32), rng.randbytes(32)
    robot = Link(1, 0, 7, key, MemoryCounterStore(), mtu=mtu)
    host = Link(0, 1, 7, key, MemoryCounterStore(), mtu=mtu)
    forger = Link(1, 0, 7, bad_key, MemoryCounterStore(start=1 << 40), mtu=mtu)
    up, down = Channel(config, rng.randrange(1 << 30)), Channel(config, rng.randrange(1 << 30))
    msgs = {i + 1: b"M" + rng.randbytes(rng.randint(*sizes) - 1) for i in range(packets)}
    cmds: dict[int, bytes] = {}
    got: dict[int, int] = {}
    got_cmd: dict[int, int] = {}
    order: list[int] = []
    corrupted = forged_ok = 0
    acked: set[int] = set()
    cmd_acked: set[int] = set()
    first_t = last_t = None
    payload_bytes = 0
    next_msg = 1
    captured: list[bytes] = []
    forged_at = sorted(rng.uniform(0, 5) for _ in range(forged))
    replay_at = sorted(rng.uniform(1, 6) for _ in range(replays))
    cmd_at = sorted(rng.uniform(0, 5) for _ in range(commands))
    t = 0.0
    while t < max_seconds:
        while next_msg <= packets and robot.queued_bytes < 65536:
            robot.send(msgs[next_msg], t, msg_id=next_msg)
            next_msg += 1
        while cmd_at and cmd_at[0] <= t:
            cmd_at.pop(0)
            body = b"C" + rng.randbytes(rng.randint(8, 60))
            cmds[host.send(body, t)] = body
        while forged_at and forged_at[0] <= t:
            forged_at.pop(0)
            forger.send(b"FORGED" + rng.randbytes(20), t, reliable=False)
            wire = forger.poll(t)
            for ev in host.receive(wire, t) + robot.receive(wire, t):
                forged_ok += isinstance(ev, Delivered)
        while replay_at and replay_at[0] <= t and captured:
            replay_at.pop(0)
            for ev in host.receive(rng.choice(captured), t):
                forged_ok += isinstance(ev, Delivered)
        up.transmit(robot.poll(t, up.room(t)), t)
        down.transmit(host.poll(t, down.room(t)), t)
        arrived = up.deliver(t)
        if arrived and len(captured) < 64:
            captured.append(arrived)
        for ev in host.receive(arrived, t) + host.pop_events():
            if isinstance(ev, Delivered):
                if ev.payload.startswith(b"FORGED"):
                    forged_ok += 1
                elif msgs.get(ev.msg_id) != ev.payload:
                    corrupted += 1
                else:
                    got[ev.msg_id] = got.get(ev.msg_id, 0) + 1
                    order.append(ev.msg_id)
                    payload_bytes += len(ev.payload)
                    first_t = t if first_t is None else first_t
                    last_t = t
            elif isinstance(ev, Acked):
                cmd_acked.add(ev.msg_id)
        for ev in robot.receive(down.deliver(t), t) + robot.pop_events():
            if isinstance(ev, Delivered):
                if cmds.get(ev.msg_id) != ev.payload:
                    forged_ok += ev.payload.startswith(b"FORGED")
                    corrupted += not ev.payload.startswith(b"FORGED")
                else:
                    got_cmd[ev.msg_id] = got_cmd.get(ev.msg_id, 0) + 1
            elif isinstance(ev, Acked):
                acked.add(ev.msg_id)
        if len(acked) == packets and not cmd_at and cmd_acked >= set(cmds):
            break
        t += step
    out_of_order = sum(1 for a, b in zip(order, order[1:]) if b <= a)
    span = (last_t - 0.0) if last_t else max_seconds
    rejected: dict[str, int] = {}
    for link in (host, robot):
        for k, v in link.stats().rejected.items():
            rejected[k] = rejected.get(k, 0) + v
    return LinktestResult(
        sent=packets, delivered=len(got),
        delivered_twice=sum(1 for n in got.values() if n > 1)
        + sum(1 for n in got_cmd.values() if n > 1),
        out_of_order=out_of_order, corrupted_accepted=corrupted, forged_accepted=forged_ok,
        commands_sent=len(cmds), commands_delivered=len(got_cmd),
        goodput=payload_bytes / max(span, 1e-9) / ((1.0 - config.loss) * config.bandwidth),
        sim_seconds=round(t, 6), payload_bytes=payload_bytes,
        retransmissions=robot.stats().retransmissions,
        repaired=robot.stats().repaired + host.stats().repaired,
        forged_injected=forged, replays_injected=replays - len(replay_at), rejected=rejected)
