"""`btf-host linktest`'s engine: a robot link and a host link, each bound to one end of a
simulated radio (`radio.channel_port.Cable`) by the same `LinkPump` the robot and the host
use, on a simulated clock. Forged frames (another key) and replays of genuine frames are
injected at the host."""
from __future__ import annotations

import random
from dataclasses import dataclass

from radio.auth import MemoryCounterStore
from radio.channel import ChannelConfig
from radio.channel_port import Cable, CableEnd
from radio.link import Acked, Delivered, Event, Link
from radio.pump import LinkPump


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


class _Recording:
    """A port that keeps the first reads it returns: genuine traffic, to replay later."""

    def __init__(self, port: CableEnd, keep: int = 64) -> None:
        self.port, self.keep, self.kept = port, keep, []
        self.timeout = 0.0

    @property
    def in_waiting(self) -> int:
        return self.port.in_waiting

    @property
    def out_waiting(self) -> int:
        return self.port.out_waiting

    def read(self, size: int = 1) -> bytes:
        data = self.port.read(size)
        if data and len(self.kept) < self.keep:
            self.kept.append(data)
        return data

    def write(self, data: bytes) -> int:
        return self.port.write(data)

    def close(self) -> None:
        self.port.close()


class _Tally:
    """What each end saw, judged against what was sent."""

    def __init__(self, msgs: dict[int, bytes]) -> None:
        self.msgs, self.cmds = msgs, {}
        self.got: dict[int, int] = {}
        self.got_cmd: dict[int, int] = {}
        self.order: list[int] = []
        self.acked: set[int] = set()
        self.cmd_acked: set[int] = set()
        self.corrupted = self.forged = self.payload_bytes = 0
        self.first_t: float | None = None
        self.last_t: float | None = None

    def at_host(self, events: list[Event], t: float) -> None:
        for ev in events:
            if isinstance(ev, Delivered):
                if ev.payload.startswith(b"FORGED"):
                    self.forged += 1
                elif self.msgs.get(ev.msg_id) != ev.payload:
                    self.corrupted += 1
                else:
                    self.got[ev.msg_id] = self.got.get(ev.msg_id, 0) + 1
                    self.order.append(ev.msg_id)
                    self.payload_bytes += len(ev.payload)
                    self.first_t = t if self.first_t is None else self.first_t
                    self.last_t = t
            elif isinstance(ev, Acked):
                self.cmd_acked.add(ev.msg_id)

    def at_robot(self, events: list[Event]) -> None:
        for ev in events:
            if isinstance(ev, Delivered):
                if self.cmds.get(ev.msg_id) != ev.payload:
                    self.forged += ev.payload.startswith(b"FORGED")
                    self.corrupted += not ev.payload.startswith(b"FORGED")
                else:
                    self.got_cmd[ev.msg_id] = self.got_cmd.get(ev.msg_id, 0) + 1
            elif isinstance(ev, Acked):
                self.acked.add(ev.msg_id)


def _inject(link: Link, wire: bytes, t: float, tally: _Tally, seen) -> None:
    """Feed bytes that never crossed the radio to `link`; a delivery of them is a forgery accepted."""
    seen(link.pop_events())  # what the link had queued already is genuine
    link.receive(wire, t)
    events = link.pop_events()
    tally.forged += sum(isinstance(ev, Delivered) for ev in events)
    seen([ev for ev in events if not isinstance(ev, Delivered)])


def run_linktest(config: ChannelConfig, packets: int = 500, seed: int = 0, *,
                 sizes: tuple[int, int] = (150, 400), commands: int = 20, forged: int = 50,
                 replays: int = 50, mtu: int = 100, step: float = 0.001,
                 max_seconds: float = 3600.0) -> LinktestResult:
    """A robot end streaming `packets` messages to a host end, which sends `commands` back,
    through two seeded channels; forged frames (wrong key) and replayed genuine frames are
    injected at the host. Returns what arrived, how, and how fast."""
    rng = random.Random(seed)
    key, bad_key = rng.randbytes(32), rng.randbytes(32)
    clock = [0.0]
    cable = Cable(config, (rng.randrange(1 << 30), rng.randrange(1 << 30)), lambda: clock[0])
    heard = _Recording(cable.ends[1])
    # Paced to the radio's transmit buffer: a step writes what the buffer has room for.
    robot = LinkPump(Link(1, 0, 7, key, MemoryCounterStore(), mtu=mtu), cable.ends[0],
                     lambda: clock[0], max_write=config.buffer)
    host = LinkPump(Link(0, 1, 7, key, MemoryCounterStore(), mtu=mtu), heard,
                    lambda: clock[0], max_write=config.buffer)
    forger = Link(1, 0, 7, bad_key, MemoryCounterStore(start=1 << 40), mtu=mtu)
    msgs = {i + 1: b"M" + rng.randbytes(rng.randint(*sizes) - 1) for i in range(packets)}
    tally = _Tally(msgs)
    next_msg = 1
    forged_at = sorted(rng.uniform(0, 5) for _ in range(forged))
    replay_at = sorted(rng.uniform(1, 6) for _ in range(replays))
    cmd_at = sorted(rng.uniform(0, 5) for _ in range(commands))
    t = 0.0
    while t < max_seconds:
        clock[0] = t
        while next_msg <= packets and robot.link.queued_bytes < 65536:
            robot.send(msgs[next_msg], msg_id=next_msg)
            next_msg += 1
        while cmd_at and cmd_at[0] <= t:
            cmd_at.pop(0)
            body = b"C" + rng.randbytes(rng.randint(8, 60))
            tally.cmds[host.send(body)] = body
        while forged_at and forged_at[0] <= t:
            forged_at.pop(0)
            forger.send(b"FORGED" + rng.randbytes(20), t, reliable=False)
            wire = forger.poll(t)
            _inject(host.link, wire, t, tally, lambda evs: tally.at_host(evs, t))
            _inject(robot.link, wire, t, tally, tally.at_robot)
        while replay_at and replay_at[0] <= t and heard.kept:
            replay_at.pop(0)
            _inject(host.link, rng.choice(heard.kept), t, tally, lambda evs: tally.at_host(evs, t))
        tally.at_host(host.step(), t)
        tally.at_robot(robot.step())
        if len(tally.acked) == packets and not cmd_at and tally.cmd_acked >= set(tally.cmds):
            break
        t += step
    return _result(config, tally, robot.link, host.link, t, max_seconds, packets, forged,
                   replays - len(replay_at))


def _result(config: ChannelConfig, tally: _Tally, robot: Link, host: Link, t: float,
            max_seconds: float, packets: int, forged: int, replays: int) -> LinktestResult:
    out_of_order = sum(1 for a, b in zip(tally.order, tally.order[1:]) if b <= a)
    span = (tally.last_t - 0.0) if tally.last_t else max_seconds
    rejected: dict[str, int] = {}
    for link in (host, robot):
        for k, v in link.stats().rejected.items():
            rejected[k] = rejected.get(k, 0) + v
    return LinktestResult(
        sent=packets, delivered=len(tally.got),
        delivered_twice=sum(1 for n in tally.got.values() if n > 1)
        + sum(1 for n in tally.got_cmd.values() if n > 1),
        out_of_order=out_of_order, corrupted_accepted=tally.corrupted, forged_accepted=tally.forged,
        commands_sent=len(tally.cmds), commands_delivered=len(tally.got_cmd),
        goodput=tally.payload_bytes / max(span, 1e-9) / ((1.0 - config.loss) * config.bandwidth),
        sim_seconds=round(t, 6), payload_bytes=tally.payload_bytes,
        retransmissions=robot.stats().retransmissions,
        repaired=robot.stats().repaired + host.stats().repaired,
        forged_injected=forged, replays_injected=replays, rejected=rejected)
