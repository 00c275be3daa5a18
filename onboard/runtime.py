"""The robot's main loop, and the parts it turns.

One thread turns `step()`: service the link (`LinkService`: acknowledgements clear the
outbox, the outbox feeds the link), answer commands (`Dispatcher`), follow the link's
state (`Failsafe`), watch the disk (`Disk`), and measure the next pose of an active sweep
(`SweepControl`, filing each capture with `Captures`); `Status` says what the robot is doing.
What they share is one `RuntimeState`. Every packet goes through the outbox first and leaves
it only when the base acknowledged it; faults become retries, then a skipped pose with its
reason; no exception ends the loop. `open_state` opens the outbox a runtime works from.
"""
from __future__ import annotations

import logging
import time
from collections import deque
from typing import Callable

from hal.controls import describe
from hal.devices import Hal
from hal.interfaces import DeviceGone
from onboard.capture.filing import PCA_KEY, SPACE_KEY, Captures, read_pca, read_space
from onboard.capture.pipeline import Pipeline, PoseSkipped
from onboard.capture.segmentation import Segmentation
from onboard.config import Config
from onboard.disk import Disk, Pressure
from onboard.dispatch import Dispatcher
from onboard.failsafe import Failsafe
from onboard.link.outbox import NO_ROOM, Outbox, OutboxError, free_bytes, open_outbox
from onboard.link.service import LinkService
from onboard.link.status import Status, sweep_report
from onboard.link.transport import Transport
from onboard.state import Mode, RuntimeState
from onboard.sweep.control import SweepControl
from onboard.sweep.plan import SweepProgress
from onboard.watchdog import Notifier
from radio import packets as pk
from radio.link import Delivered, LinkDown, LinkUp, PeerStale

__all__ = ["Mode", "Runtime", "open_state"]
log = logging.getLogger("btf.robot")  # one short line per pose, command and link change


def open_state(cfg: Config) -> tuple[Outbox, Disk, str]:
    """The outbox under `state_dir`, the disk it lives on, and what opening it took ("" when
    nothing): a damaged outbox is moved aside and a new one, a new incarnation, started. A disk
    too full to open it even without the reserve raises OutboxError (the environment: retry)."""
    cfg.state_dir.mkdir(parents=True, exist_ok=True)
    disk = Disk(cfg.state_dir, cfg.disk_min_free_bytes, cfg.disk_reserve_bytes)
    path = cfg.state_dir / "outbox.sqlite"
    try:
        outbox, note = open_outbox(path, cfg.outbox_quota_bytes)
    except OutboxError as exc:
        if "full" not in str(exc).lower() and free_bytes(cfg.state_dir) >= NO_ROOM:
            raise
        disk.write_failed(str(exc))  # the reserve is for this: room to open the outbox and drain it
        outbox, note = open_outbox(path, cfg.outbox_quota_bytes)
    return outbox, disk, note


class Runtime:
    def __init__(
        self,
        cfg: Config,
        hal: Hal,
        transport: Transport,
        segmenter: Segmentation,
        outbox: Outbox | None = None,
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
        sleep: Callable[[float], None] = time.sleep,
        notifier: Notifier | None = None,
        new_sweep: bool = False,
        disk: Disk | None = None,
        log: Callable[[str], None] = log.warning,
    ) -> None:
        self.hal, self.transport, self.segmenter = hal, transport, segmenter
        self.clock, self.wall, self.sleep, self.log = clock, wall, sleep, log
        cfg.state_dir.mkdir(parents=True, exist_ok=True)
        self.state = RuntimeState(cfg)
        # `is None`, not `or`: an empty outbox is falsy (it has a length).
        if outbox is None:
            outbox, disk, note = open_state(cfg)
            if note:
                self.note(note)
        self.outbox = outbox
        self.disk = disk if disk is not None else Disk(cfg.state_dir, cfg.disk_min_free_bytes,
                                                       cfg.disk_reserve_bytes)
        self.outbox.on_full = lambda: self.disk.write_failed("a write found the disk full")
        self._unheld_said = False
        self.notifier = notifier if notifier is not None else Notifier(address="")
        self.pipeline = Pipeline(lambda: self.state.cfg, hal, segmenter, pump=self._pump, sleep=sleep,
                                 resend_mask=segmenter.force_send)
        self.pipeline.pca = read_pca(self.outbox.state(PCA_KEY), cfg.state_dir / "pca.json")
        if cfg.features.space == "auto":
            self.pipeline.keep_space(read_space(self.outbox.state(SPACE_KEY)))
        self.link = LinkService(transport, self.outbox, self.state, on_ack=self._room_freed)
        self._sessions_heard = 0  # sessions the base opened that this robot has told its state
        self.captures = Captures(self.state, self.outbox, wall)
        self.failsafe = Failsafe(self.state, hal.arm, wall, lambda text, report: self.status.send(text, report))
        self.status = Status(self.state, self.outbox, self.captures, self.pipeline, self.failsafe, self.link,
                             self.notifier, wall)
        # Captures stop short of the quota, so replies and STATUS still fit when they do.
        self.sweep = SweepControl(self.state, self.outbox, self.pipeline, self.captures, self.status,
                                  self.notifier, reserve=self.outbox.quota_bytes // 8, new_sweep=new_sweep,
                                  clock=clock)
        self.dispatch = Dispatcher(self.state, self.outbox, self.link, self.failsafe, self.status, self.pipeline,
                                   self.captures, self.sweep, hal.arm, hal.servo_bus, segmenter, wall)

    # What a caller watches, from the shared state.
    @property
    def cfg(self) -> Config:
        return self.state.cfg

    @property
    def mode(self) -> Mode:
        return self.state.mode

    @property
    def progress(self) -> SweepProgress | None:
        return self.state.progress

    @property
    def paused_reason(self) -> str:
        return self.state.paused_reason

    @property
    def errors(self) -> deque[str]:
        return self.state.errors

    def _room_freed(self) -> None:
        self.sweep.full_until_ack = False

    def note(self, line: str) -> None:
        """Something a person should know: one log line, and the errors STATUS carries."""
        self.state.errors.append(line)
        self.log(line)

    def watch_disk(self) -> None:
        """Follow the room under state_dir; a change of pressure is said in a STATUS."""
        s, disk = self.state, self.disk
        pressure, s.disk_free = disk.pressure(), disk.free()
        if disk.unheld and not self._unheld_said:
            self._unheld_said = True
            self.note(f"disk: {disk.unheld}; a full disk may then stop acknowledged rows being deleted")
        if pressure.value == s.disk:
            return
        s.disk = pressure.value
        if pressure is Pressure.OK:
            text = f"disk has room again ({s.disk_free} bytes free): acquisition resumes"
        else:
            need = disk.min_free + (disk.reserve if pressure is Pressure.FULL else 0)
            text = (f"disk {pressure.value}: {s.disk_free} bytes free under {self.cfg.state_dir}; "
                    f"acquisition paused until {need} are free")
        self.note(text)
        self.status.send(text)  # every STATUS says the disk

    def service(self) -> None:
        """Read link events, answer commands, feed the link from the outbox."""
        now = self.clock()
        for event in self.link.read(now):
            if isinstance(event, (LinkUp, LinkDown)):
                self._link_changed(isinstance(event, LinkUp))
            elif isinstance(event, Delivered):
                self.dispatch.on_body(event.payload)
            elif isinstance(event, PeerStale):
                self.note(f"link: {event.text}")
        stats = self.link.stats()
        if stats is not None and stats.sessions_opened > self._sessions_heard:
            # a station (re)started opens a session while the link stays up: the whole report tells it
            # the robot, its pose and the sweep at once, where an idle robot would otherwise say nothing
            self._sessions_heard = stats.sessions_opened
            self.status.send("the base opened a session", self.status.report())
        self.link.write(now)
        self.notifier.kick()

    def _link_changed(self, up: bool) -> None:
        held = self.failsafe.active
        self.failsafe.link_changed(up)
        if up:
            log.info("link up: the base is heard%s", "; failsafe cleared, resuming" if held else "")
        else:
            log.info("link down: the base has been silent for %.1f s%s", self.cfg.link.failsafe_s,
                     "; failsafe: arm stopped and held" if self.failsafe.active and not held else "")

    def _pump(self) -> None:
        """Service the link while the arm works; end that work when it was interrupted."""
        try:
            self.service()
        except Exception as exc:  # a link fault is not the pose's fault
            self.state.errors.append(f"{type(exc).__name__}: {exc}")
        self.state.check_interrupt()

    # -- the loop --------------------------------------------------------------------
    def boot(self) -> None:
        try:
            self.pipeline.retry("torque on", self.hal.arm.enable)
            self.state.torque = True
        except (PoseSkipped, DeviceGone) as exc:
            self.state.torque = False  # GOTO and SWEEP say to send torque-on
            self.state.errors.append(exc.reason if isinstance(exc, PoseSkipped) else str(exc))
        self.watch_disk()
        camera = self.lock_camera()
        swept = None
        if self.cfg.sweep.autostart or self.sweep.new_sweep:
            boot = self.sweep.autostart()
            swept = sweep_report(self.progress, boot=boot.value)
        self.notifier.ready(f"btf-robot running: {self.mode.value}")
        self.status.send("boot", pk.StatusReport(camera=camera, sweep=swept))
        sweep = "" if swept is None else f", sweep {swept.id} {swept.boot}"
        log.info("boot: robot %d on the %s HAL, mode %s%s%s", self.cfg.robot_id, self.hal.body.value,
                 self.mode.value, sweep, "" if self.state.torque else "; torque is off (power-on failed)")

    def lock_camera(self) -> str:
        """Lock the camera as `[camera]` says; one line for STATUS, with why it will not measure."""
        try:
            granted = self.pipeline.lock_camera()
        except PoseSkipped as exc:
            self.state.errors.append(exc.reason)
            return exc.reason
        why = self.pipeline.lock.refusal(granted) if self.pipeline.lock is not None else ""
        if why:
            self.state.errors.append(why)
            self.notifier.status(why)
        return why or describe(granted)

    def step(self) -> str:
        """One turn of the loop; what the sweep did ("" when nothing). Never raises."""
        try:
            self.service()
            self.watch_disk()
            if self.mode is Mode.SWEEPING:
                result = self.sweep.step()
                self.service()
                return result
        except Exception as exc:
            self.state.errors.append(f"{type(exc).__name__}: {exc}")
        return ""

    def idle(self) -> bool:
        """Nothing to do: no active sweep and every packet acknowledged."""
        return self.mode is not Mode.SWEEPING and len(self.outbox) == 0

    def run(self, stop: Callable[["Runtime"], bool] = lambda rt: False, tick_s: float = 0.01) -> int:
        self.boot()
        while not stop(self):
            # Rest unless a pose was just done: a paused sweep (outbox full) must not spin.
            if self.step() not in ("measured", "skipped"):
                self.sleep(tick_s)
        return 0
