"""What the station knows, as one record: `StationSnapshot` (its JSON form is `to_json`).

The link's state and quality counters come from the link itself (`radio.link.LinkStats`); the
robot's mode, pose, outbox, faults, failsafe and sweep come from what it sends (STATUS packets,
the answers to STATUS commands, captures), so they are as fresh as its last word, whose time is
given. Times are wall-clock seconds inside, ISO 8601 (UTC) and seconds-ago in the JSON form.
The sweep's plan becomes the grid of poses the operator's page draws (`tools.station.sweep_grid`).
"""
from __future__ import annotations

from collections import deque
from dataclasses import asdict, dataclass, field
from typing import Any

from onboard.sweep.plan import SweepPlan
from radio import packets as pk
from radio.events import LinkStats
from radio.packets.base import iso_time
from tools.station import sweep_grid

LATEST = 10  # captures the snapshot lists
GOODPUT_S = 10.0  # the window of the goodput figure
DEFAULT_FAILSAFE_S = 5.0  # the robot's [link] failsafe_s, until it reports its own
SKIPPED_KEPT = 64
FAILSAFE_KEPT = 8


def ago(t: float | None, now: float) -> float | None:
    return None if t is None else round(max(0.0, now - t), 1)


@dataclass
class LinkView:
    up: bool = False
    changed: float | None = None  # when it last went up or down
    last_heard: float | None = None  # the last frame that passed authentication (heartbeats too)
    stats: LinkStats = field(default_factory=lambda: LinkStats(0, 0, 0, 0, 0, 0, 0, 0))
    delivered_bytes: int = 0
    recent: deque = field(default_factory=lambda: deque(maxlen=4096))  # (wall, payload bytes) delivered

    def goodput(self, now: float) -> float:
        """Payload bytes a second delivered over the last GOODPUT_S seconds."""
        return sum(n for t, n in self.recent if now - t <= GOODPUT_S) / GOODPUT_S


@dataclass
class RobotView:
    robot_id: int | None = None
    mode: str | None = None  # idle | sweeping | failsafe, from the robot's own report
    state: str | None = None  # the STATUS packet's state
    pose: tuple[float, float] | None = None  # the last measured (elevation, azimuth)
    commanded: tuple[float, float] | None = None  # where it was last sent (a capture's pose, a GOTO)
    outbox: int | None = None  # packets waiting on the robot for our acknowledgement
    paused: str = ""
    torque: bool | None = None
    faults: list[str] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    failsafe: list[str] = field(default_factory=list)
    last_status: float | None = None  # when the robot last told us its state
    last_status_text: str = ""
    disk: str | None = None  # ok | low | full, when the robot reports its disk
    disk_free: int | None = None  # bytes
    rejected: dict[str, int] = field(default_factory=dict)  # frames the robot's link refused, by reason
    failsafe_s: float | None = None  # silence from the base after which the robot holds the arm
    left_out: dict[str, int] = field(default_factory=lambda: {"faults": 0, "errors": 0})  # older ones it cut
    dead_letters: dict | None = None  # its messages this station refused: {"count", "latest"}


@dataclass
class SweepView:
    sweep_id: int | None = None
    plan: dict | None = None  # the SWEEP command's arguments, when this station sent it
    next_index: int | None = None
    poses: int | None = None
    active: bool | None = None
    measured: int = 0
    skipped: list[dict] = field(default_factory=list)  # {"index", "elevation", "azimuth", "reason", "tries"}
    missing: list[dict] | None = None  # the poses the robot could not measure, once the sweep ended
    missing_left_out: int = 0  # more missing poses than its report lists
    layout: SweepPlan | None = None  # the poses, from the robot's STATUS or this station's SWEEP
    done: set[int] = field(default_factory=set)  # poses whose capture arrived before the robot's next report


@dataclass
class StationSnapshot:
    port: str
    db: str
    started: float
    link: LinkView = field(default_factory=LinkView)
    robot: RobotView = field(default_factory=RobotView)
    sweep: SweepView = field(default_factory=SweepView)
    latest: deque = field(default_factory=lambda: deque(maxlen=LATEST))
    counts: dict[str, int] = field(default_factory=lambda: {"stored": 0, "duplicates": 0, "masks": 0, "bad": 0})
    commands_pending: int = 0
    clients: int = 0
    subscribers: int = 0

    # -- updates, from the station's loop ----------------------------------------------------
    def note_capture(self, item: Any, wall: float) -> None:
        p = item.packet
        self.robot.robot_id, self.robot.pose = p.robot_id, (float(p.measured[0]), float(p.measured[1]))
        if p.commanded[0] is not None:
            self.robot.commanded = (float(p.commanded[0]), float(p.commanded[1]))
        self.counts["stored" if item.stored else "duplicates"] += 1
        self.latest.appendleft({
            "robot": p.robot_id, "seq": p.seq, "kind": item.kind.value, "stored": item.stored,
            "time": iso_time(p.time), "received": iso_time(wall), "elevation": round(float(p.measured[0]), 2),
            "azimuth": round(float(p.measured[1]), 2), "commanded": [float(a) for a in p.commanded],
            "regions": len(p.labels) if isinstance(p, pk.ModelsPacket) else None, "text": item.text})
        s = self.sweep
        if item.stored and s.active:  # captures stored since the sweep began
            s.measured += 1
            if s.layout is not None and p.commanded[0] is not None:
                at = (float(p.commanded[0]), float(p.commanded[1]))
                i = sweep_grid.index_of(s.layout, at, s.done | {k["index"] for k in s.skipped}, s.next_index or 0)
                if i is None:  # a skipped pose measured again, after the plan
                    i = next((k["index"] for k in s.skipped if k["index"] < s.layout.count
                              and sweep_grid.same_pose(s.layout.pose(k["index"]), at)), None)
                    s.skipped = [k for k in s.skipped if k["index"] != i]
                if i is not None:
                    s.done.add(i)

    def note_status(self, p: pk.StatusPacket, wall: float) -> None:
        """A STATUS: what its report says (`pk.StatusReport`, every field checked by the decoder)."""
        r = self.robot
        r.robot_id, r.state, r.outbox = p.robot_id, p.state.name.lower(), p.outbox_pending
        if r.pose is None and p.pose is not None:  # its last capture's: captures and GOTO say it first
            r.pose = (p.pose[0], p.pose[1])
        r.last_status, r.last_status_text = wall, p.text
        self._report(p.report, whole=False)

    def note_status_answer(self, report: pk.StatusReport, wall: float) -> None:
        """The answer to a STATUS command: the robot's whole report."""
        self._report(report, whole=True)
        self.robot.last_status, self.robot.last_status_text = wall, "status"

    def _report(self, x: pk.StatusReport, whole: bool) -> None:
        """What a report says; `whole`: the answer to STATUS (its lists replace ours; a STATUS's
        failsafe is one more hold)."""
        r = self.robot
        for name in ("mode", "outbox", "paused", "torque", "failsafe_s"):
            if getattr(x, name) is not None:
                setattr(r, name, getattr(x, name))
        for name in ("faults", "errors"):
            kept = getattr(x, name)
            if kept is not None:
                setattr(r, name, list(kept.items))
                r.left_out[name] = kept.left_out
        if x.failsafe is not None:
            held = [_held(e) for e in x.failsafe.items]
            r.failsafe = held if whole else (r.failsafe + held)[-FAILSAFE_KEPT:]
        if x.disk is not None:
            r.disk, r.disk_free = x.disk.state, x.disk.free
        if x.rejected is not None:
            r.rejected = {k.reason: k.count for k in x.rejected.items}
        if x.dead_letters is not None:
            d = x.dead_letters
            r.dead_letters = {"count": d.count, "latest": [
                {"msg_id": k.msg_id, "kind": None if k.kind is None else k.kind.name, "reason": k.reason,
                 "time": iso_time(k.time)} for k in d.latest.items]}
        if x.sweep is not None:
            self._sweep(x.sweep, whole)

    def _sweep(self, w: pk.SweepReport, whole: bool = False) -> None:
        self._sweep_id(w.id)
        s = self.sweep
        if w.poses is not None:
            s.poses = w.poses
        if w.next is not None:
            s.next_index = w.next
            s.done = {i for i in s.done if i >= w.next}
        if w.plan is not None:
            s.layout = sweep_grid.plan_of(w.plan.to_record()) or s.layout
        if w.active is not None:
            s.active = w.active
        if whole and w.skipped is not None and not w.skipped.left_out:  # every pose skipped now
            s.skipped = []
        for k in w.skipped or ():
            self._skip(k)
        if w.missing is not None:  # the sweep ended: these are the poses it could not measure
            s.missing, s.missing_left_out = [_pose_dict(k) for k in w.missing.items], w.missing.left_out
            s.skipped = []
            for k in w.missing.items:
                self._skip(k)
        if w.measured is not None:  # the sweep is done
            s.measured, s.next_index = w.measured, s.poses

    def note_sweep_started(self, plan: dict, answer: dict) -> None:
        """The robot ACKed a SWEEP this station sent: a new sweep with a known plan."""
        self.sweep = SweepView(answer["sweep"], plan, 0, answer["poses"], True,
                               layout=sweep_grid.plan_of_command(plan))
        self.robot.mode = "sweeping"

    def note_answer(self, name: pk.CommandName, answer: dict, args: dict | None = None) -> None:
        """The robot ACKed `name` (sent with `args`, when this station sent it): `answer` holds the
        values the command table declares for it, checked by the decoder."""
        C = pk.CommandName
        if name is C.GOTO:
            self.robot.pose = (answer["elevation"], answer["azimuth"])
            if args and "elevation" in args:
                self.robot.commanded = (float(args["elevation"]), float(args.get("azimuth", 0.0)))
        if name in (C.ABORT, C.TORQUE_OFF):
            self.sweep.active = False
            self.robot.mode = "idle"
        if name in (C.TORQUE_OFF, C.TORQUE_ON):
            self.robot.torque = name is C.TORQUE_ON

    def note_link(self, up: bool, wall: float) -> None:
        self.link.up, self.link.changed = up, wall

    def note_delivered(self, size: int, wall: float) -> None:
        self.link.delivered_bytes += size
        self.link.recent.append((wall, size))

    def failsafe_assumed(self, now: float) -> bool:
        """The link has been silent longer than the robot's failsafe_s: it holds the arm now (it
        reports the failsafe itself only once the link returns)."""
        ln = self.link
        silent = None if ln.last_heard is None else now - ln.last_heard
        return (not ln.up and silent is not None
                and silent >= (self.robot.failsafe_s or DEFAULT_FAILSAFE_S))

    def _sweep_id(self, sweep_id: int) -> None:
        if sweep_id != self.sweep.sweep_id:
            self.sweep = SweepView(sweep_id)

    def _skip(self, k: pk.SkippedPose) -> None:
        """A pose skipped (again: its newest reason and tries replace the older)."""
        kept = [x for x in self.sweep.skipped if x["index"] != k.index]
        self.sweep.skipped = (kept + [_pose_dict(k)])[-SKIPPED_KEPT:]

    # -- the JSON form -----------------------------------------------------------------------
    def to_json(self, now: float) -> dict:
        ln, r, s = self.link, self.robot, self.sweep
        stats = asdict(ln.stats)
        return {
            "station": {"port": self.port, "db": self.db, "started": iso_time(self.started),
                        "clients": self.clients, "subscribers": self.subscribers,
                        "commands_pending": self.commands_pending},
            "link": {"up": ln.up, "changed": iso_time(ln.changed), "last_heard": iso_time(ln.last_heard),
                     "last_heard_s": ago(ln.last_heard, now), **stats, "delivered_bytes": ln.delivered_bytes,
                     "goodput_bps": round(ln.goodput(now), 1)},
            "robot": {"id": r.robot_id, "mode": r.mode, "state": r.state, "pose": _pose(r.pose),
                      "commanded": _pose(r.commanded),
                      "outbox": r.outbox, "paused": r.paused, "torque": r.torque, "faults": r.faults,
                      "errors": r.errors, "left_out": r.left_out, "dead_letters": r.dead_letters,
                      "failsafe": r.failsafe, "failsafe_s": r.failsafe_s,
                      "failsafe_assumed": self.failsafe_assumed(now), "disk": r.disk, "disk_free": r.disk_free,
                      "rejected": r.rejected, "last_status": iso_time(r.last_status),
                      "last_status_s": ago(r.last_status, now), "last_status_text": r.last_status_text},
            "sweep": {"id": s.sweep_id, "plan": s.plan, "next": s.next_index, "poses": s.poses,
                      "active": s.active, "measured": s.measured, "skipped": s.skipped, "missing": s.missing,
                      "missing_left_out": s.missing_left_out,
                      "grid": sweep_grid.grid_json(s.layout, s.next_index, s.done, s.skipped, s.active)},
            "captures": {**self.counts, "latest": list(self.latest)},
        }


def _pose_dict(k: pk.SkippedPose) -> dict:
    """A skipped or missing pose in the snapshot's JSON."""
    return {"index": k.index, "elevation": k.elevation, "azimuth": k.azimuth, "reason": k.reason,
            "tries": k.tries or 1}


def _pose(pose: tuple[float, float] | None) -> dict | None:
    return None if pose is None else {"elevation": pose[0], "azimuth": pose[1]}


def _held(e: pk.FailsafeEvent) -> str:
    """A failsafe hold, for a person."""
    return (f"{iso_time(e.since)} for {e.until - e.since:.1f} s" if e.until is not None
            else f"{iso_time(e.since)}, ongoing")
