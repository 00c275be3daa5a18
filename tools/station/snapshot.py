"""What the station knows, as one record: `StationSnapshot` (its JSON form is `to_json`).

The link's state and quality counters come from the link itself (`radio.link.LinkStats`); the
robot's mode, pose, outbox, faults, failsafe and sweep come from what it sends (STATUS packets,
the answers to STATUS commands, captures), so they are as fresh as its last word, whose time is
given. Times are wall-clock seconds inside, ISO 8601 (UTC) and seconds-ago in the JSON form.
The sweep's plan becomes the grid of poses the operator's page draws (`tools.station.sweep_grid`).
"""
from __future__ import annotations

import json
import re
from collections import deque
from dataclasses import asdict, dataclass, field
from datetime import datetime, timezone
from typing import Any

from onboard.sweep.plan import SweepPlan
from radio import packets as pk
from radio.events import LinkStats
from tools.station import sweep_grid

LATEST = 10  # captures the snapshot lists
GOODPUT_S = 10.0  # the window of the goodput figure
DEFAULT_FAILSAFE_S = 5.0  # the robot's [link] failsafe_s, until it reports its own
SKIPPED_KEPT = 64
_SKIPPED = re.compile(r"^(\d+)@(-?[\d.]+)/(-?[\d.]+): (.*)$")  # the robot's STATUS form of a skipped pose


def iso(t: float | None) -> str | None:
    return None if t is None else datetime.fromtimestamp(t, timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


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


@dataclass
class SweepView:
    sweep_id: int | None = None
    plan: dict | None = None  # the SWEEP command's arguments, when this station sent it
    next_index: int | None = None
    poses: int | None = None
    active: bool | None = None
    measured: int = 0
    skipped: list[dict] = field(default_factory=list)  # {"index", "elevation", "azimuth", "reason"}
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
            "time": iso(p.time), "received": iso(wall), "elevation": round(float(p.measured[0]), 2),
            "azimuth": round(float(p.measured[1]), 2), "commanded": [float(a) for a in p.commanded],
            "regions": len(p.labels) if isinstance(p, pk.ModelsPacket) else None, "text": item.text})
        s = self.sweep
        if item.stored and s.active:  # captures stored since the sweep began
            s.measured += 1
            if s.layout is not None and p.commanded[0] is not None:
                i = sweep_grid.index_of(s.layout, (float(p.commanded[0]), float(p.commanded[1])),
                                        s.done | {k["index"] for k in s.skipped}, s.next_index or 0)
                if i is not None:
                    s.done.add(i)

    def note_status(self, p: pk.StatusPacket, wall: float) -> None:
        r = self.robot
        r.robot_id, r.state, r.outbox = p.robot_id, p.state.name.lower(), p.outbox_pending
        if r.pose is None and p.pose is not None:  # its last capture's: captures and GOTO say it first
            r.pose = (float(p.pose[0]), float(p.pose[1]))
        r.last_status, r.last_status_text = wall, p.text
        x, s = dict(p.extras), self.sweep
        if "mode" in x:
            r.mode = str(x["mode"])
        if "sweep" in x:
            self._sweep_id(int(x["sweep"]))
        if "skipped_index" in x:
            self._skip(int(x["skipped_index"]), x.get("skipped_elevation"), x.get("skipped_azimuth"),
                       p.text.removeprefix("skipped pose: "))
        if p.text == "sweep done":
            r.mode, s.active, s.next_index = "idle", False, s.poses
            s.measured = int(x.get("measured", s.measured))
        if "failsafe_since" in x:
            r.failsafe = (r.failsafe + [f"{x['failsafe_since']} for {x.get('failsafe_s', '?')} s"])[-4:]
        self._disk(x)

    def note_status_answer(self, extras: dict, wall: float) -> None:
        """The ACK of a STATUS command: the robot's whole report (`onboard.link.status.flat`)."""
        r, s = self.robot, self.sweep
        r.mode, r.outbox, r.paused = extras.get("mode", r.mode), extras.get("outbox", r.outbox), extras.get("paused", "")
        r.faults, r.errors = list(extras.get("faults", ())), list(extras.get("errors", ()))
        r.failsafe = list(extras.get("failsafe", ()))
        if "torque" in extras:
            r.torque = bool(extras["torque"])
        if "failsafe_s" in extras:
            r.failsafe_s = float(extras["failsafe_s"])
        self._disk(extras)
        r.rejected = dict(_counts(extras.get("rejected", ())))
        r.last_status, r.last_status_text = wall, "status"
        if "sweep_id" in extras:
            self._sweep_id(int(extras["sweep_id"]))
            s = self.sweep
            s.next_index, s.poses = int(extras["next"]), int(extras["poses"])
            s.done = {i for i in s.done if i >= s.next_index}
            if "plan" in extras:
                s.layout = sweep_grid.plan_of(_json(extras["plan"])) or s.layout
            s.active = r.mode == "sweeping" or (s.next_index < s.poses and r.mode == "failsafe")
            for text in extras.get("skipped", ()):
                m = _SKIPPED.match(str(text))
                if m:
                    self._skip(int(m[1]), float(m[2]), float(m[3]), m[4])

    def note_sweep_started(self, plan: dict, extras: dict) -> None:
        """The robot ACKed a SWEEP this station sent: a new sweep with a known plan."""
        self.sweep = SweepView(int(extras["sweep"]), plan, 0, int(extras["poses"]), True,
                               layout=sweep_grid.plan_of_command(plan))
        self.robot.mode = "sweeping"

    def note_answer(self, name: pk.CommandName, extras: dict, args: dict | None = None) -> None:
        """The robot ACKed `name` (sent with `args`, when this station sent it)."""
        C = pk.CommandName
        if name is C.GOTO and "elevation" in extras:
            self.robot.pose = (float(extras["elevation"]), float(extras.get("azimuth", 0.0)))
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

    def _disk(self, extras: dict) -> None:
        r = self.robot
        if "disk" in extras:
            r.disk = str(extras["disk"])
        if isinstance(extras.get("disk_free"), int):
            r.disk_free = extras["disk_free"]

    def _skip(self, index: int, elevation: Any, azimuth: Any, reason: str) -> None:
        if any(k["index"] == index for k in self.sweep.skipped):
            return
        self.sweep.skipped = (self.sweep.skipped + [{
            "index": index, "elevation": None if elevation is None else float(elevation),
            "azimuth": None if azimuth is None else float(azimuth), "reason": reason}])[-SKIPPED_KEPT:]

    # -- the JSON form -----------------------------------------------------------------------
    def to_json(self, now: float) -> dict:
        ln, r, s = self.link, self.robot, self.sweep
        stats = asdict(ln.stats)
        return {
            "station": {"port": self.port, "db": self.db, "started": iso(self.started),
                        "clients": self.clients, "subscribers": self.subscribers,
                        "commands_pending": self.commands_pending},
            "link": {"up": ln.up, "changed": iso(ln.changed), "last_heard": iso(ln.last_heard),
                     "last_heard_s": ago(ln.last_heard, now), **stats, "delivered_bytes": ln.delivered_bytes,
                     "goodput_bps": round(ln.goodput(now), 1)},
            "robot": {"id": r.robot_id, "mode": r.mode, "state": r.state, "pose": _pose(r.pose),
                      "commanded": _pose(r.commanded),
                      "outbox": r.outbox, "paused": r.paused, "torque": r.torque, "faults": r.faults,
                      "errors": r.errors, "failsafe": r.failsafe, "failsafe_s": r.failsafe_s,
                      "failsafe_assumed": self.failsafe_assumed(now), "disk": r.disk, "disk_free": r.disk_free,
                      "rejected": r.rejected, "last_status": iso(r.last_status),
                      "last_status_s": ago(r.last_status, now), "last_status_text": r.last_status_text},
            "sweep": {"id": s.sweep_id, "plan": s.plan, "next": s.next_index, "poses": s.poses,
                      "active": s.active, "measured": s.measured, "skipped": s.skipped,
                      "grid": sweep_grid.grid_json(s.layout, s.next_index, s.done, s.skipped, s.active)},
            "captures": {**self.counts, "latest": list(self.latest)},
        }


def _pose(pose: tuple[float, float] | None) -> dict | None:
    return None if pose is None else {"elevation": pose[0], "azimuth": pose[1]}


def _json(text: Any) -> Any:
    try:
        return json.loads(text)
    except (TypeError, ValueError):
        return None


def _counts(items: Any) -> list[tuple[str, int]]:
    """The robot's `reason:n` strings (its link's rejections) as pairs; others are left out."""
    out = []
    for item in items if isinstance(items, (list, tuple)) else ():
        reason, _, n = str(item).rpartition(":")
        if reason and n.isdigit():
            out.append((reason, int(n)))
    return out
