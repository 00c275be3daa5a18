"""Sweep control: start, resume, stop, and measure the next pose of the sweep.

Exactly once: a pose's packets, the sweep progress that marks it done and the next capture
sequence are one outbox transaction (`Outbox.commit`), so a kill at any instant leaves the
pose queued and done, or neither; the host drops re-sent rows by (robot, incarnation, seq).
Faults become retries, then a skipped pose with its reason; the sweep goes on. A full outbox
or a disk short of room pauses it; the pose is measured again when there is room.
"""
from __future__ import annotations

import copy
import logging

from onboard.capture.filing import Captures
from onboard.capture.pipeline import FittedView, Pipeline, PoseSkipped
from onboard.link.outbox import DiskFull, Outbox, OutboxFull
from onboard.link.status import Status, skipped_pose, sweep_report
from onboard.state import Interrupted, Mode, RuntimeState
from onboard.sweep.plan import Boot, SweepPlan, SweepProgress, SweepStore
from onboard.watchdog import Notifier
from radio import packets as pk

log = logging.getLogger("btf.robot")


class SweepControl:
    def __init__(self, state: RuntimeState, outbox: Outbox, pipeline: Pipeline, captures: Captures,
                 status: Status, notifier: Notifier, reserve: int, new_sweep: bool = False) -> None:
        self.state, self.outbox, self.pipeline, self.captures = state, outbox, pipeline, captures
        self.status, self.notifier = status, notifier
        self.sweeps = SweepStore(outbox, legacy_dir=state.cfg.state_dir)
        self.reserve = reserve  # outbox bytes kept free for replies and STATUS
        self.new_sweep = new_sweep
        self.full_until_ack = False  # a commit hit the quota: measure again after an ACK

    def plan(self) -> SweepPlan:
        s = self.state.cfg.sweep
        return SweepPlan(s.start, s.stop, s.step, s.azimuths)

    def start(self, plan: SweepPlan | None = None) -> SweepProgress:
        """A new sweep (of the config's plan unless one is given), saved before it begins."""
        self.state.progress = self.sweeps.start(self.plan() if plan is None else plan)
        self.state.mode = Mode.SWEEPING
        return self.state.progress

    def begin(self, progress: SweepProgress) -> None:
        """`progress` (a new sweep already committed) is the sweep now."""
        self.state.progress, self.state.mode = progress, Mode.SWEEPING

    def autostart(self) -> Boot:
        """At boot: resume an interrupted sweep; never restart a finished one on its own."""
        self.state.progress, boot = self.sweeps.autostart(self.plan(), new=self.new_sweep)
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
        if p is None or p.done:
            return "done"
        if self.outbox.full_for(self.reserve) or self.full_until_ack:
            self.state.paused_reason = "outbox full: acquisition paused until the host acknowledges"
            return "paused"
        if self.state.disk != "ok":  # the disk is short of room: nothing more is measured until it is not
            self.state.paused_reason = (f"disk {self.state.disk}: {self.state.disk_free} bytes free under "
                                        f"{self.state.cfg.state_dir}; acquisition paused until there is room")
            return "paused"
        nxt = copy.deepcopy(p)
        try:
            with self.state.arm_work():
                cap = self._measure(p)
        except Interrupted:  # the command or failsafe that interrupted has set the state
            return "interrupted"
        except Exception as exc:
            # A fault the pipeline did not foresee skips the pose with its reason
            # instead of failing the same pose forever.
            reason = exc.reason if isinstance(exc, PoseSkipped) else f"internal: {type(exc).__name__}: {exc}"
            return self._file(p, nxt, None, reason)
        return self._file(p, nxt, cap, "")

    def _measure(self, p: SweepProgress) -> FittedView:
        commanded = p.current()
        self.pipeline.move(commanded)
        measured = self.pipeline.measure_view()
        cfg = self.state.cfg
        if cfg.skip.skip_measured_pose and p.already_measured(measured, cfg.sweep.pose_tolerance_deg):
            raise PoseSkipped(f"already measured in this sweep (measured {measured.elevation:.1f}°, "
                              f"{measured.azimuth:.1f}°)")
        return self.pipeline.shoot(commanded, measured)

    def _file(self, p: SweepProgress, nxt: SweepProgress, cap: FittedView | None, reason: str) -> str:
        """Commit the pose's packets (or its skip) with the progress past it."""
        if cap is None:
            skipped = nxt.record_skipped(reason)
            packets = [self.status.packet(f"skipped pose: {skipped.reason}", pk.StatusReport(
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
            packets.append(self.status.packet("sweep done", pk.StatusReport(sweep=sweep_report(
                p, active=False, measured=len(nxt.measured), skipped=pk.Kept((), len(nxt.skipped)))),
                pk.RobotState.IDLE))
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
        self.notifier.status(f"sweep {nxt.sweep_id}: {result} pose {nxt.next_index} of {nxt.plan.count}")
        where = p.current()
        pose = f"sweep {p.sweep_id} pose {nxt.next_index}/{nxt.plan.count} at {where.elevation:.1f}°/{where.azimuth:.1f}°"
        if cap is None:
            log.info("%s: skipped: %s", pose, reason)
        else:
            log.info("%s: seq %d, measured %.1f°/%.1f°, %d models%s", pose, seq, cap.measured.elevation,
                     cap.measured.azimuth, len(cap.results), " (unchanged)" if cap.unchanged else "")
        if nxt.done:
            self.state.mode = Mode.IDLE
            done = f"sweep {nxt.sweep_id} done: {len(nxt.measured)} measured, {len(nxt.skipped)} skipped"
            self.notifier.status(done)
            log.info("%s", done)
        return result
