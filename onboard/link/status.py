"""What the robot says about itself: the STATUS packet (boot, skipped poses, sweep done, the
failsafe, the disk, answers to the STATUS command) and the systemd status line. The answer
to STATUS carries the sweep's plan (as JSON, `onboard.sweep.plan.SweepPlan.to_record`) and the
robot's `failsafe_s`, so the station can draw the sweep's grid and knows when the arm is held.
A STATUS the outbox cannot take (a full disk) goes straight to the link."""
from __future__ import annotations

import json
from typing import Callable

from onboard.capture.filing import Captures
from onboard.capture.pipeline import Pipeline
from onboard.failsafe import Failsafe
from onboard.link import bodies as wire
from onboard.link.outbox import Outbox
from onboard.link.service import LinkService
from onboard.state import Mode, RuntimeState
from onboard.watchdog import Notifier
from radio import packets as pk

PLAN_TEXT = 500  # characters of the plan's JSON a STATUS carries (a packet string holds 512)


class Status:
    def __init__(self, state: RuntimeState, outbox: Outbox, captures: Captures, pipeline: Pipeline,
                 failsafe: Failsafe, link: LinkService, notifier: Notifier,
                 wall: Callable[[], float]) -> None:
        self.state, self.outbox, self.captures, self.pipeline = state, outbox, captures, pipeline
        self.failsafe, self.link, self.notifier, self.wall = failsafe, link, notifier, wall

    def report(self) -> dict:
        """The robot's state as a record (`flat` turns it into STATUS extras)."""
        s, p = self.state, self.state.progress
        return {
            "mode": s.mode.value,
            "sweep": None if p is None else {
                "id": p.sweep_id, "next": p.next_index, "poses": p.plan.count, "active": p.active,
                "plan": p.plan.to_record(),
                "skipped": [[k.index, k.commanded.elevation, k.commanded.azimuth, k.reason]
                            for k in p.skipped[-16:]],
            },
            "outbox": len(self.outbox),
            "paused": s.paused_reason,
            "disk": s.disk,
            "disk_free": s.disk_free,
            "rejected": dict(getattr(self.link.stats(), "rejected", {})),
            "failsafe": self.failsafe.events[-4:],
            "failsafe_s": s.cfg.link.failsafe_s,
            "torque": s.torque,
            "faults": self.pipeline.faults[-8:],
            "errors": list(s.errors)[-8:],
        }

    def robot_state(self) -> pk.RobotState:
        if self.state.mode is Mode.FAILSAFE or self.state.paused_reason or self.state.disk != "ok":
            return pk.RobotState.PAUSED
        return pk.RobotState.SWEEPING if self.state.mode is Mode.SWEEPING else pk.RobotState.IDLE

    def packet(self, text: str, extras: dict | None = None,
               state: pk.RobotState | None = None) -> tuple[int, bytes]:
        """A STATUS packet (outbox kind, body), for the caller to queue or commit."""
        if self.state.disk != "ok":  # every STATUS says when the disk is short of room
            extras = {**(extras or {}), "disk": self.state.disk, "disk_free": self.state.disk_free}
        return wire.status_body(self.state.cfg.robot_id, self.wall(), state or self.robot_state(),
                                self.state.pose, len(self.outbox), self.outbox.bytes_used,
                                self.captures.last_seq, text, extras)

    def send(self, text: str, extras: dict | None = None) -> None:
        """Queue a STATUS now (straight on the link if the outbox cannot take it), and show its
        text as the service status."""
        kind, body = self.packet(text, extras)
        if self.link.queue(kind, body) is None:
            self.link.send_direct(kind, body)
        self.notifier.status(text)


def flat(st: dict) -> dict:
    """A status record as packet extras: scalars and short lists only."""
    sweep = st.get("sweep") or {}
    out = {"mode": st["mode"], "outbox": st["outbox"], "paused": st["paused"], "disk": st["disk"],
           "disk_free": st["disk_free"], "rejected": [f"{k}:{n}" for k, n in sorted(st["rejected"].items())]}
    if sweep:
        out.update(sweep_id=sweep["id"], next=sweep["next"], poses=sweep["poses"])
        plan = json.dumps(sweep["plan"], separators=(",", ":")) if "plan" in sweep else ""
        if plan and len(plan) <= PLAN_TEXT:  # a plan of many listed angles goes without
            out["plan"] = plan
        out["skipped"] = [f"{i}@{e:.1f}/{a:.1f}: {r}" for i, e, a, r in sweep["skipped"]]
    out["failsafe"] = [f"{wire.iso_time(e['since'])} for {e['until'] - e['since']:.1f} s" if e["until"]
                       else f"{wire.iso_time(e['since'])}, ongoing" for e in st["failsafe"]]
    if "failsafe_s" in st:
        out["failsafe_s"] = float(st["failsafe_s"])
    if st.get("torque") is not None:
        out["torque"] = bool(st["torque"])
    out["faults"] = list(st["faults"])
    out["errors"] = list(st["errors"])
    return out
