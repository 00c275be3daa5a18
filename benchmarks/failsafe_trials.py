"""Failsafe trials on a real link: how late after `failsafe_s` the arm is held once the base stops.

A fake robot (`onboard.runtime.Runtime` on the fake HAL, sweeping) and a host (`radio.link.Link`
sending heartbeats, in a thread) talk over a pseudo-terminal pair. In each trial the host is
heard for a random 0.4-1.4 s, then falls silent: it keeps draining what the robot sends (so the
robot never blocks on a full pty) but neither feeds its link nor writes. The robot's
`arm.stop_and_hold` is timed; the lateness is that time less the host's last write less
`failsafe_s` (the last byte may reach the robot a little after it is written, so this is an
upper bound). Then the host speaks again, the failsafe clears and the sweep goes on to the next
trial. `background=False` runs the pose's camera and processing steps inline, as before the
pipeline serviced the link during them.
"""
from __future__ import annotations

import os
import random
import tempfile
import threading
import time
import tty
from dataclasses import dataclass
from pathlib import Path

from radio.auth import MemoryCounterStore
from radio.keys import load_key, write_key
from radio.link import Link
from radio.ports import FdPort
from radio.pump import LinkPump

CONFIG = ('robot_id = 9\nstate_dir = "state"\n[hal]\nbody = "fake"\nscene = "mixed"\nsize = [{h}, {w}]\n'
          '[link]\nkey_file = "robot.key"\nheartbeat_s = 0.2\nfailsafe_s = {failsafe}\n'
          '[sweep]\nstart = 90\nstop = 0\nstep = 1\n'
          'azimuths = [0, 30, 60, 90, 120, 150, 180, 210, 240, 270, 300, 330]\n'
          '[segment]\nmethod = "scene"\n'
          '[skip]\nmin_pixels = 20\nskip_measured_pose = false\n')


@dataclass(frozen=True)
class Trial:
    late_s: float  # held this long after failsafe_s had passed since the host's last write
    silent_s: float  # from the host's last write to the hold


class _Host(threading.Thread):
    """The base: heartbeats and acknowledgements, until told to fall silent."""

    def __init__(self, key: bytes, fd: int) -> None:
        super().__init__(daemon=True)
        self.pump = LinkPump(Link(2, 1, 1, key, MemoryCounterStore(wall=time.time), heartbeat=0.2,
                                  link_timeout=60), FdPort(fd, timeout=0.002))
        self.silent = threading.Event()
        self.stop = threading.Event()
        self.last_write = 0.0

    def run(self) -> None:
        port = self.pump.port
        while not self.stop.is_set():
            if self.silent.is_set():
                port.read(4096)  # drained, never heard: the robot must not block on the pty
                continue
            self.pump.read()
            out = self.pump.link.poll(time.monotonic(), self.pump.room())
            if out:
                port.write(out)
                self.last_write = time.monotonic()


def run_trials(size: tuple[int, int], trials: int, failsafe_s: float = 1.0, seed: int = 0,
               background: bool = True) -> list[Trial]:
    """`trials` failsafe trips of a robot sweeping at frame `size` (height, width)."""
    from hal.factory import build_hal
    from onboard import config
    from onboard.capture.segmentation import Segmentation
    from onboard.runtime import Mode, Runtime

    rng = random.Random(seed)
    with tempfile.TemporaryDirectory(prefix="btf-failsafe-") as tmp:
        work = Path(tmp)
        key = load_key(write_key(work / "robot.key"))
        (work / "robot.toml").write_text(CONFIG.format(h=size[0], w=size[1], failsafe=failsafe_s))
        cfg = config.load(work / "robot.toml")
        hal = build_hal(cfg.hal)
        hal.camera.open(size[1], size[0])
        master, slave = os.openpty()
        tty.setraw(master)
        tty.setraw(slave)
        robot_link = Link(1, 2, 1, key, MemoryCounterStore(wall=time.time), heartbeat=0.2, link_timeout=failsafe_s)
        rt = Runtime(cfg, hal, LinkPump(robot_link, FdPort(slave, timeout=0.002)), Segmentation(cfg, hal),
                     log=lambda line: None)
        if not background:
            rt.pipeline._worker = None  # every step inline, the link serviced only between them
        held: list[float] = []
        real_hold = hal.arm.stop_and_hold
        hal.arm.stop_and_hold = lambda: (real_hold(), held.append(time.monotonic()))
        host = _Host(key, master)
        host.start()
        out: list[Trial] = []
        try:
            rt.boot()
            for _ in range(trials):
                _turn_until(rt, lambda: rt.failsafe.link_up and rt.mode is not Mode.FAILSAFE, 30.0)
                _turn_until(rt, lambda: False, rng.uniform(0.4, 1.4))
                host.silent.set()
                n = len(held)
                _turn_until(rt, lambda: len(held) > n, failsafe_s + 30.0)
                silent = held[-1] - host.last_write
                out.append(Trial(silent - failsafe_s, silent))
                host.silent.clear()
        finally:
            host.stop.set()
            host.join(timeout=10)
            rt.outbox.close()
            hal.close()
            os.close(master)
            os.close(slave)
        return out


def _turn_until(rt, done, limit_s: float) -> None:
    """Turn the robot's loop as `btf-robot run` does until `done()` or `limit_s` passed."""
    end = time.monotonic() + limit_s
    while not done() and time.monotonic() < end:
        if rt.step() not in ("measured", "skipped"):
            rt.sleep(0.01)
