"""What the robot says about itself: the STATUS packet (boot, skipped poses, sweep done, the
failsafe, the disk) and the answer to the STATUS command, both typed (`radio.packets.StatusReport`),
and the systemd status line. Every STATUS says the mode, the disk and the last pose's compute
time besides what it is about; the answer says everything: the sweep with its plan and skipped
poses, the failsafe and its `failsafe_s` (so the station draws the grid and knows when the arm is
held), the link's rejections, faults, errors and the messages the base refused. Bounded lists say how many older
items they left out. A STATUS the outbox cannot take (a full disk) goes straight to the link."""
from __future__ import annotations

import dataclasses
from typing import Callable

from onboard.capture.filing import Captures
from onboard.capture.pipeline import Pipeline
from onboard.failsafe import Failsafe
from onboard.link import bodies as wire
from onboard.link.outbox import Outbox
from onboard.link.service import LinkService
from onboard.state import Mode, RuntimeState
from onboard.sweep.plan import SweepProgress
from onboard.watchdog import Notifier
from radio import packets as pk
from radio.packets.schema import Record, Recent
from radio.packets.status import PLAN_ANGLES

DEAD_LETTERS_SHOWN = 4


class Status:
    def __init__(self, state: RuntimeState, outbox: Outbox, captures: Captures, pipeline: Pipeline,
                 failsafe: Failsafe, link: LinkService, notifier: Notifier,
                 wall: Callable[[], float]) -> None:
        self.state, self.outbox, self.captures, self.pipeline = state, outbox, captures, pipeline
        self.failsafe, self.link, self.notifier, self.wall = failsafe, link, notifier, wall

    def report(self) -> pk.StatusReport:
        """The robot's whole state, as the answer to STATUS carries it."""
        s, p = self.state, self.state.progress
        rejected = sorted(dict(getattr(self.link.stats(), "rejected", {}) or {}).items())
        count, letters = self.outbox.dead_letters(DEAD_LETTERS_SHOWN)
        return fit(dataclasses.replace(
            self.said(), outbox=len(self.outbox), paused=s.paused_reason or s.device_gone,
            rejected=pk.Kept(tuple(pk.Rejection(str(k), int(n)) for k, n in rejected)),
            failsafe=_events(self.failsafe.events),
            failsafe_s=float(s.cfg.link.failsafe_s), torque=bool(s.torque), faults=_kept(self.pipeline.faults),
            errors=_kept(s.errors), sweep=None if p is None else sweep_report(p, whole=True),
            dead_letters=pk.DeadLetters(count, pk.Kept(
                tuple(pk.DeadLetter(d.msg_id, _kind(d.kind), d.reason, d.refused) for d in letters),
                max(0, count - len(letters))))))

    def said(self) -> pk.StatusReport:
        """What every STATUS says: the mode, the disk and the last pose's compute time."""
        s, timing = self.state, self.captures.last_timing
        return pk.StatusReport(mode=s.mode.value, disk=pk.Disk(s.disk, s.disk_free),
                               pose_ms=None if timing is None else round(timing.total * 1e3, 1))

    def robot_state(self) -> pk.RobotState:
        s = self.state
        if s.mode is Mode.FAILSAFE or s.paused_reason or s.device_gone or s.disk != "ok":
            return pk.RobotState.PAUSED
        return pk.RobotState.SWEEPING if self.state.mode is Mode.SWEEPING else pk.RobotState.IDLE

    def packet(self, text: str, report: pk.StatusReport | None = None,
               state: pk.RobotState | None = None, last_seq: int | None = None) -> tuple[int, bytes]:
        """A STATUS packet (outbox kind, body), for the caller to queue or commit: `report`'s
        fields, with the mode and the disk; `state` and `last_seq` where the caller knows them
        ahead of the robot (a packet committed with the capture it follows)."""
        said = self.said()
        if report is not None:
            said = dataclasses.replace(report, mode=report.mode or said.mode, disk=report.disk or said.disk,
                                       pose_ms=said.pose_ms if report.pose_ms is None else report.pose_ms)
        return wire.status_body(self.state.cfg.robot_id, self.wall(), self.robot_state() if state is None else state,
                                self.state.pose, len(self.outbox), self.outbox.bytes_used,
                                self.captures.last_seq if last_seq is None else last_seq, text, fit(said))

    def send(self, text: str, report: pk.StatusReport | None = None) -> None:
        """Queue a STATUS now (straight on the link if the outbox cannot take it), and show its
        text as the service status."""
        kind, body = self.packet(text, report)
        if self.link.queue(kind, body) is None:
            self.link.send_direct(kind, body)
        self.notifier.status(text)


def sweep_report(p: SweepProgress, whole: bool = False, **said) -> pk.SweepReport:
    """A sweep as STATUS says it: its number and what `said` names; `whole`: its progress, plan
    and skipped poses too, and once it is done the poses missing."""
    if not whole:
        return pk.SweepReport(p.sweep_id, **said)
    plan = p.plan
    fits = len(plan.azimuths) <= PLAN_ANGLES and len(plan.elevations) <= PLAN_ANGLES
    return pk.SweepReport(
        p.sweep_id, next=p.next_index, poses=plan.count, active=p.active,
        plan=pk.Plan(plan.start, plan.stop, plan.step, plan.azimuths, plan.elevations) if fits else None,
        plan_left_out=not fits, skipped=pk.Kept(tuple(skipped_pose(k) for k in p.skipped)),
        **({"missing": pk.Kept(tuple(skipped_pose(k) for k in p.skipped)), "measured": len(p.measured)}
           if p.done else {}), **said)


def skipped_pose(k) -> pk.SkippedPose:
    return pk.SkippedPose(k.index, float(k.commanded.elevation), float(k.commanded.azimuth) % 360.0, k.reason,
                          k.tries if k.tries > 1 else None)


def fit(report: pk.StatusReport) -> pk.StatusReport:
    """`report` within the schema's bounds, what was cut counted (as `encode` would send it)."""
    return Record(pk.StatusReport).fit(report)


def _kept(items) -> pk.Kept:
    return items.kept() if isinstance(items, Recent) else pk.Kept(tuple(items))


def _events(events) -> pk.Kept:
    kept = _kept(events)
    return pk.Kept(tuple(pk.FailsafeEvent(e["since"], e["until"]) for e in kept.items), kept.left_out)


def _kind(kind: int | None) -> pk.Kind | None:
    return pk.Kind(kind) if kind in pk.Kind._value2member_map_ else None
