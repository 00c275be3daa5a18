"""Sweep control: start, resume, stop, and measure the next pose of the sweep.

Exactly once: a pose's packets, the sweep progress that marks it done and the next capture
sequence are one outbox transaction (`Outbox.commit`), so a kill at any instant leaves the
pose queued and done, or neither; the host drops re-sent rows by (robot, incarnation, seq).
Faults become retries, then a skipped pose with its reason; the sweep goes on, and after its
last planned pose measures again each pose a device fault skipped (`[sweep] retry_skipped`
more tries each). Its last STATUS lists the poses still missing, each with why. A full outbox
or a disk short of room pauses it; the pose is measured again when there is room. A device that
is gone (unplugged) pauses it too, said in a STATUS and the log: the pose is tried again every
PROBE_S, and once the device answers the sweep resumes (said again), nothing skipped for it.
"""
from __future__ import annotations

import copy
import logging
import time
from typing import Callable

from onboard.capture.filing import Captures
from hal.interfaces import DeviceGone, ViewAngles
from onboard.capture.pipeline import FittedView, Pipeline, PoseSkipped
from onboard.link.outbox import DiskFull, Outbox, OutboxFull
from onboard.link.status import Status, skipped_pose, sweep_report
from onboard.state import Interrupted, Mode, RuntimeState
from onboard.sweep.plan import Boot, SweepPlan, SweepProgress, SweepStore
from onboard.watchdog import Notifier
from radio import packets as pk

log = logging.getLogger("btf.robot")


def same_direction(a: ViewAngles, b: ViewAngles, tol: float) -> bool:
    """Two commanded poses that look the same way: at the zenith the azimuth does not matter."""
    if abs(a.elevation - b.elevation) > tol:
        return False
    return a.elevation >= 90.0 - tol or abs((a.azimuth - b.azimuth + 180.0) % 360.0 - 180.0) <= tol


class AlreadyMeasured(PoseSkipped):
    """The plan asks again for a direction measured earlier in this sweep (at `view`): nothing to send."""

    def __init__(self, view: ViewAngles, reason: str) -> None:
        super().__init__(reason)
        self.view = view
PROBE_S = 1.0  # while a device is gone, how often its pose is tried again


class SweepControl:
    def __init__(self, state: RuntimeState, outbox: Outbox, pipeline: Pipeline, captures: Captures,
                 status: Status, notifier: Notifier, reserve: int, new_sweep: bool = False,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.state, self.outbox, self.pipeline, self.captures = state, outbox, pipeline, captures
        self.status, self.notifier = status, notifier
        self.sweeps = SweepStore(outbox, legacy_dir=state.cfg.state_dir)
        self.reserve = reserve  # outbox bytes kept free for replies and STATUS
        self.new_sweep = new_sweep
        self.full_until_ack = False  # a commit hit the quota: measure again after an ACK
        self.clock = clock
        self._probe_at = 0.0  # when a pose waiting for a device that is gone is tried again

    def plan(self) -> SweepPlan:
        s = self.state.cfg.sweep
        return SweepPlan(s.start, s.stop, s.step, s.azimuths)

    def _in_force(self, progress: SweepProgress) -> SweepProgress:
        """`progress` with the configuration's tries of a skipped pose (a SET changes them)."""
        progress.retry_skipped = self.state.cfg.sweep.retry_skipped
        return progress

    def start(self, plan: SweepPlan | None = None) -> SweepProgress:
        """A new sweep (of the config's plan unless one is given), saved before it begins."""
        self.state.progress = self._in_force(self.sweeps.start(self.plan() if plan is None else plan))
        self.state.mode = Mode.SWEEPING
        return self.state.progress

    def begin(self, progress: SweepProgress) -> None:
        """`progress` (a new sweep already committed) is the sweep now."""
        self.state.progress, self.state.mode = self._in_force(progress), Mode.SWEEPING

    def autostart(self) -> Boot:
        """At boot: resume an interrupted sweep; never restart a finished one on its own."""
        progress, boot = self.sweeps.autostart(self.plan(), new=self.new_sweep)
        self.state.progress = self._in_force(progress)
        self.new_sweep = False
        if boot in (Boot.STARTED, Boot.RESUMED):
            self.state.mode = Mode.SWEEPING
        return boot

    def stop(self) -> None:
        p = self.state.progress
        if p is not None:
            p.active = False
            self.sweeps.save(p)
        if self.state.mode is Mode.SWEEPING:
            self.state.mode = Mode.IDLE

    def step(self) -> str:
        """Measure the next pose of the sweep; returns what happened ("measured", "skipped",
        "interrupted", "paused" or "done").

        The pose's packets and the progress past it are committed together; when the
        outbox cannot take them, nothing changes and the pose is measured again later."""
        p = self.state.progress
        if p is not None:
            self._in_force(p)
        if p is None or p.done:
            return "done"
        if self.outbox.full_for(self.reserve) or self.full_until_ack:
            self.state.paused_reason = "outbox full: acquisition paused until the host acknowledges"
            return "paused"
        if self.state.disk != "ok":  # the disk is short of room: nothing more is measured until it is not
            self.state.paused_reason = (f"disk {self.state.disk}: {self.state.disk_free} bytes free under "
                                        f"{self.state.cfg.state_dir}; acquisition paused until there is room")
            return "paused"
        if self.state.device_gone and self.clock() < self._probe_at:
            return "paused"
        nxt, cap, reason, fault, covered = copy.deepcopy(p), None, "", False, None
        try:
            with self.state.arm_work():
                cap = self._measure(p)
        except Interrupted:  # the command or failsafe that interrupted has set the state
            return "interrupted"
        except DeviceGone as exc:
            return self._gone(str(exc))
        except AlreadyMeasured as exc:
            reason, covered = exc.reason, exc.view
        except PoseSkipped as exc:
            reason, fault = exc.reason, exc.fault
        except Exception as exc:
            # A fault the pipeline did not foresee skips the pose with its reason
            # instead of failing the same pose forever.
            reason = f"internal: {type(exc).__name__}: {exc}"
        self._back()
        return self._file(p, nxt, cap, reason, fault, covered)

    def _gone(self, why: str) -> str:
        """A device is not there: nothing measured, nothing skipped; the pose is tried again in
        PROBE_S. The first time, said (log, errors, STATUS)."""
        self._probe_at = self.clock() + PROBE_S
        if not self.state.device_gone:
            self.state.device_gone = f"{why}; sweep paused until it answers again"
            text = f"device gone: {self.state.device_gone}"
            self.state.errors.append(text)
            log.warning("%s", text)
            self.status.send(text, pk.StatusReport(paused=self.state.device_gone))
        return "paused"

    def _back(self) -> None:
        """The devices answer again (the pose went through, or failed for another reason): said."""
        if self.state.device_gone:
            text = f"devices answer again: sweep resumes (was: {self.state.device_gone.split('; sweep paused')[0]})"
            self.state.device_gone = ""
            log.warning("%s", text)
            self.status.send(text, pk.StatusReport(paused=self.state.paused_reason))

    def _measure(self, p: SweepProgress) -> FittedView:
        commanded = p.current()
        cfg = self.state.cfg
        tol = cfg.sweep.pose_tolerance_deg
        # a plan's pose in a direction it already measured (the zenith at each azimuth): not moved to again
        same = next((v for i, v in p.measured if same_direction(p.plan.pose(i), commanded, tol)), None)
        if cfg.skip.skip_measured_pose and same is not None:
            raise AlreadyMeasured(same, f"the direction of a pose measured in this sweep (at {same.elevation:.1f}°, "
                                  f"{same.azimuth:.1f}°)")
        self.pipeline.move(commanded)
        measured = self.pipeline.measure_view()
        if cfg.skip.skip_measured_pose and p.already_measured(measured, tol):
            raise PoseSkipped(f"already measured in this sweep (measured {measured.elevation:.1f}°, "
                              f"{measured.azimuth:.1f}°)")
        return self.pipeline.shoot(commanded, measured)

    def _file(self, p: SweepProgress, nxt: SweepProgress, cap: FittedView | None, reason: str,
              fault: bool = False, covered: ViewAngles | None = None) -> str:
        """Commit the pose's packets (or its skip) with the progress past it; a pose `covered`
        (the direction of one measured in this sweep, as the zenith is at every azimuth) counts as
        measured, by that capture."""
        index, again = p.current_index(), p.retrying
        if cap is None and covered is not None:
            nxt.record_measured(covered)
            packets, state, result = [], {}, "measured"
        elif cap is None:
            skipped = nxt.record_skipped(reason, fault)
            said = f"skipped pose again (try {skipped.tries} of {p.retry_skipped + 1})" if again else "skipped pose"
            packets = [self.status.packet(f"{said}: {skipped.reason}", pk.StatusReport(
                sweep=sweep_report(p, skipped=pk.Kept((skipped_pose(skipped),)))))]
            state: dict[str, str] = {}
            result = "skipped"
        else:
            seq, packets, state = self.captures.packets(cap)
            nxt.record_measured(cap.measured)
            self.state.pose = cap.measured  # the arm stands there, whether or not the commit fits
            result = "measured"
        if nxt.done:
            nxt.active = False
            packets.append(self._done_packet(p, nxt, seq if cap is not None else None))
        try:
            self.outbox.commit(packets, {**state, **self.sweeps.entry(nxt)}, reserve=self.reserve)
        except OutboxFull as exc:
            if cap is not None:
                self.pipeline.rollback(cap)
            # A full disk (the outbox told the runtime's disk watch) resumes when there is room.
            self.state.paused_reason, self.full_until_ack = str(exc), not isinstance(exc, DiskFull)
            return "paused"
        self.state.paused_reason = ""
        self.state.progress = nxt
        if cap is not None:
            self.captures.filed(cap, seq)
        self._said(p, nxt, index, again, cap, seq if cap is not None else None, reason, result)
        return result

    def _done_packet(self, p: SweepProgress, nxt: SweepProgress, seq: int | None) -> tuple[int, bytes]:
        """The STATUS that ends a sweep: how many poses were measured, and the ones missing with
        why; committed with the last pose's capture (`seq`), so it says the robot as it is after."""
        missing = tuple(skipped_pose(k) for k in nxt.skipped)
        return self.status.packet(
            "sweep done",
            pk.StatusReport(mode=Mode.IDLE.value,
                            sweep=sweep_report(p, active=False, measured=len(nxt.measured),
                                               skipped=pk.Kept((), len(nxt.skipped)), missing=pk.Kept(missing))),
            pk.RobotState.IDLE, seq)

    def _said(self, p: SweepProgress, nxt: SweepProgress, index: int | None, again: bool, cap: FittedView | None,
              seq: int | None, reason: str, result: str) -> None:
        """The pose's line in the log and the service status; the sweep's when it is done."""
        n = p.plan.count
        self.notifier.status(f"sweep {nxt.sweep_id}: {result} pose {(index or 0) + 1} of {n}"
                             + (" (again)" if again else ""))
        where = p.current()
        pose = (f"sweep {p.sweep_id} pose {(index or 0) + 1}/{n}{' again' if again else ''} at "
                f"{where.elevation:.1f}°/{where.azimuth:.1f}°")
        if cap is None:
            log.info("%s: %s%s", pose, "" if result == "measured" else "skipped: ", reason)
        else:
            log.info("%s: seq %d, measured %.1f°/%.1f°, %d models%s", pose, seq, cap.measured.elevation,
                     cap.measured.azimuth, len(cap.results), " (unchanged)" if cap.unchanged else "")
        if nxt.done:
            self.state.mode = Mode.IDLE
            done = f"sweep {nxt.sweep_id} done: {len(nxt.measured)} measured, {len(nxt.skipped)} missing"
            self.notifier.status(done)
            log.info("%s%s", done, "".join(f"; {k.commanded.elevation:.1f}°/{k.commanded.azimuth:.1f}°: {k.reason}"
                                           for k in nxt.skipped[:8]) + ("; ..." if len(nxt.skipped) > 8 else ""))
