"""The station's store with every acknowledged capture on stable storage: captures a second
through the receiver (decode, store, commit) with synchronous=NORMAL (no fsync at a commit:
not durable), FULL with one commit a capture, and FULL with one commit a group of captures (the
station's group commit: one a turn of the link, however many packets the turn delivered);
against the captures a second the link can carry at all."""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from benchmarks.common import Context, Section
from btf.fit.fitter import FrameFitter
from hal.interfaces import ViewAngles
from hal.scene import render
from radio import packets as pk
from radio.auth import MemoryCounterStore
from radio.events import Delivered
from radio.link import Link
from tools.station.receiver import Receiver
from tools.store.database import Store

KEY = bytes(range(32))
BAUD_BYTES_S = 115200 / 10  # the station's default --baud, 8N1
RADIO_BYTES_S = 250_000 / 8  # a 250 kbit/s radio (the link benchmark's)
MODES = (("NORMAL", 1), ("FULL", 1), ("FULL", 4), ("FULL", 16))


def capture_bodies(n: int, size: tuple[int, int] = (120, 160)) -> list[bytes]:
    """n MODELS bodies as the fake robot sends them (12 views, renumbered)."""
    fits = []
    for el in np.linspace(90.0, 35.0, 12):
        view = render("mixed", ViewAngles(float(el), 0.0), size, seed=0)
        f = FrameFitter(int(view.mask.max()) + 1, 3)
        f.add(view.image, view.mask)
        fits.append((float(el), f.fit()))
    out = []
    for seq in range(1, n + 1):
        el, fit = fits[seq % len(fits)]
        out.append(pk.encode_models(fit, robot_id=1, seq=seq, time=1e9 + seq, commanded=(el, 0.0),
                                    measured=(el - 0.1, 0.0), feature_space="rgb", bands=("R", "G", "B")))
    return out


def store_rate(bodies: list[bytes], where: Path, sync: str, group: int) -> float:
    """Captures a second stored through a Receiver, one commit a `group` of them."""
    with Store.open(where / f"{sync}-{group}-{time.monotonic_ns()}.db") as store:
        store._conn.execute(f"PRAGMA synchronous = {sync}")
        rx = Receiver(store)
        t0 = time.perf_counter()
        for i in range(0, len(bodies), group):
            with store.batch():
                for body in bodies[i:i + group]:
                    rx.handle(body)
        return len(bodies) / (time.perf_counter() - t0)


def wire_bytes(bodies: list[bytes]) -> float:
    """Bytes the robot's link writes a capture (framing, authentication, ARQ; no loss)."""
    robot = Link(1, 2, 1, KEY, MemoryCounterStore(), heartbeat=1.0)
    host = Link(2, 1, 1, KEY, MemoryCounterStore(), heartbeat=1.0)
    for body in bodies:
        robot.send(body, 0.0)
    got, now = 0, 0.0
    while got < len(bodies) and now < 600.0:
        host.receive(robot.poll(now), now)
        robot.receive(host.poll(now), now)
        got += sum(isinstance(ev, Delivered) for ev in host.pop_events())
        robot.pop_events()
        now += 0.01
    assert got == len(bodies), f"the link delivered {got} of {len(bodies)}"
    return robot.stats().bytes_sent / len(bodies)


def run(ctx: Context) -> Section:
    n, repeat = ctx.pick((300, 5), (30, 1))
    bodies = capture_bodies(n)
    rates: dict[tuple[str, int], float] = {m: 0.0 for m in MODES}
    ctx.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="btf-store-", dir=ctx.out) as tmp:  # on a disk, not a tmpfs
        for r in range(repeat):  # rounds interleaved, so that other load hits every mode alike
            for mode in (MODES if r % 2 == 0 else MODES[::-1]):
                rates[mode] = max(rates[mode], store_rate(bodies, Path(tmp), *mode))
    per = wire_bytes(bodies)
    radio, serial = RADIO_BYTES_S / per, BAUD_BYTES_S / per
    lines = [f"{n} MODELS packets of the fake robot ({np.mean([len(b) for b in bodies]):.0f} B each), decoded and "
             f"stored by the station's receiver into a fresh database on the results directory's disk; best of "
             f"{repeat} interleaved rounds.", "",
             "| synchronous | commit | durable when acknowledged | captures/s | x the 250 kbit/s radio's most |",
             "|---|---|---|---:|---:|"]
    for (sync, group), rate in rates.items():
        commit = "each capture" if group == 1 else f"each group of {group} (group commit)"
        lines.append(f"| {sync} | {commit} | {'no' if sync == 'NORMAL' else 'yes'} | {rate:.0f} | {rate / radio:.1f}x |")
    full = rates[("FULL", 1)]
    lines += ["", f"The link writes {per:.0f} B a capture (frames, tags, ARQ; no loss), so the radio carries at most "
              f"{radio:.0f} captures/s at 250 kbit/s and {serial:.0f} at the station's default 115200 baud, "
              "with nothing else on the air. Durability costs one fsync a commit: FULL with a commit a capture runs "
              f"at {full / rates[('NORMAL', 1)]:.2f}x NORMAL's rate here; the station commits once a turn of the "
              "link (synchronous=FULL, every packet the turn delivered in one transaction, before its "
              "acknowledgements leave), which under a burst is the group commit's rate."]
    return Section("Store: captures a second with every acknowledged capture on stable storage", lines)
