"""The sweep plan and its progress, persisted atomically so a restarted robot resumes.

A plan is the list of commanded poses (elevation start..stop by step, for each
azimuth). Progress records, per sweep, which poses are done, the measured view each
capture was filed under, and the poses skipped with their reason. After the plan's last
pose, each pose skipped for a device fault is measured again, up to `retry_skipped` more
times (`[sweep] retry_skipped`), the oldest first; the sweep is done when every pose is
measured or out of tries, and the poses still skipped are the ones missing, each with why.

Progress lives in the outbox database's state table, so the runtime commits a pose's
packets and the progress that marks it done in one transaction: a kill at any instant
leaves the pose either queued and done, or neither (then it is measured again).

At boot an interrupted sweep resumes; a finished (or aborted) sweep of the plan the
config names is not started again on its own. A new sweep comes from a SWEEP command,
a changed plan in the config, or an explicit request (`btf-robot run --new-sweep`).
"""
from __future__ import annotations

import enum
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Iterable, Protocol

from hal.interfaces import ViewAngles

MAX_POSES = 4096  # a plan is listed and persisted whole: bound it before building it


@dataclass(frozen=True, slots=True)
class SweepPlan:
    start: float
    stop: float
    step: float
    azimuths: tuple[float, ...] = (0.0,)
    elevations: tuple[float, ...] = ()  # an explicit list (from a SWEEP command) overrides start..stop

    def __post_init__(self) -> None:
        if not (math.isfinite(self.start) and math.isfinite(self.stop) and math.isfinite(self.step)):
            raise ValueError("sweep start, stop and step must be finite")
        if self.step <= 0:
            raise ValueError(f"sweep step must be positive, got {self.step}")
        if not self.azimuths:
            raise ValueError("a sweep needs at least one azimuth")
        if not all(math.isfinite(v) for v in self.azimuths):
            raise ValueError("sweep azimuths must be finite")
        if not all(0.0 <= e <= 90.0 for e in (self.start, self.stop, *self.elevations)):
            raise ValueError("sweep elevations must lie in [0, 90] degrees")
        if self.count > MAX_POSES:
            raise ValueError(f"a sweep of {self.count} poses exceeds {MAX_POSES}")

    @property
    def _per_azimuth(self) -> int:
        if self.elevations:
            return len(self.elevations)
        return int(math.floor(abs(self.stop - self.start) / self.step + 1e-9)) + 1

    @property
    def count(self) -> int:
        """How many poses `poses()` lists, computed without listing them."""
        return self._per_azimuth * len(self.azimuths)

    def pose(self, index: int) -> ViewAngles:
        """The index-th pose of `poses()`."""
        a, i = divmod(index, self._per_azimuth)
        if not 0 <= index < self.count:
            raise IndexError(f"pose {index} outside a plan of {self.count}")
        if self.elevations:
            return ViewAngles(float(self.elevations[i]), float(self.azimuths[a]))
        direction = -1.0 if self.stop < self.start else 1.0
        return ViewAngles(self.start + direction * i * self.step, float(self.azimuths[a]))

    def poses(self) -> list[ViewAngles]:
        """Elevations from start toward stop (inclusive, either direction), per azimuth."""
        return [self.pose(i) for i in range(self.count)]

    def to_record(self) -> dict:
        return {**asdict(self), "azimuths": list(self.azimuths), "elevations": list(self.elevations)}

    @classmethod
    def from_record(cls, plan: dict) -> "SweepPlan":
        return cls(float(plan["start"]), float(plan["stop"]), float(plan["step"]),
                   tuple(float(a) for a in plan["azimuths"]),
                   tuple(float(e) for e in plan.get("elevations", ())))


@dataclass(frozen=True, slots=True)
class SkippedPose:
    index: int
    commanded: ViewAngles
    reason: str  # why its last try failed
    fault: bool = False  # a device failed (it may work when tried again), not the pose itself
    tries: int = 1


@dataclass
class SweepProgress:
    """Mutable progress of one sweep; `save` persists it atomically."""

    sweep_id: int
    plan: SweepPlan
    next_index: int = 0
    measured: list[tuple[int, ViewAngles]] = field(default_factory=list)
    skipped: list[SkippedPose] = field(default_factory=list)  # oldest first; measured again: removed
    active: bool = True
    retry_skipped: int = 0  # more tries, after the plan, of a pose skipped for a device fault

    @property
    def poses(self) -> list[ViewAngles]:
        return self.plan.poses()

    def _retry(self) -> SkippedPose | None:
        """The skipped pose to try again, once the plan is through (None: none left to try)."""
        if self.next_index < self.plan.count:
            return None
        return next((k for k in self.skipped if k.fault and k.tries <= self.retry_skipped), None)

    @property
    def retrying(self) -> bool:
        """The plan is through and a skipped pose is being measured again."""
        return self._retry() is not None

    @property
    def done(self) -> bool:
        return self.next_index >= self.plan.count and self._retry() is None

    def current(self) -> ViewAngles | None:
        if self.next_index < self.plan.count:
            return self.plan.pose(self.next_index)
        again = self._retry()
        return None if again is None else again.commanded

    def current_index(self) -> int | None:
        """The plan index of `current()`."""
        if self.next_index < self.plan.count:
            return self.next_index
        again = self._retry()
        return None if again is None else again.index

    def already_measured(self, view: ViewAngles, tolerance_deg: float) -> bool:
        """Whether a capture of this sweep was filed within tolerance of `view`."""
        return any(angular_distance(view, m) <= tolerance_deg for _, m in self.measured)

    def record_measured(self, view: ViewAngles) -> None:
        again = self._retry()
        if again is None:
            self.measured.append((self.next_index, view))
            self.next_index += 1
        else:
            self.measured.append((again.index, view))
            self.skipped.remove(again)

    def record_skipped(self, reason: str, fault: bool = False) -> SkippedPose:
        """The current pose failed for `reason` (`fault`: a device's, worth another try later)."""
        again = self._retry()
        if again is not None:  # one more try failed: it goes behind the others still to try
            self.skipped.remove(again)
            skipped = SkippedPose(again.index, again.commanded, reason, fault, again.tries + 1)
            self.skipped.append(skipped)
            return skipped
        pose = self.current()
        if pose is None:
            raise ValueError("the sweep is already complete")
        skipped = SkippedPose(self.next_index, pose, reason, fault)
        self.skipped.append(skipped)
        self.next_index += 1
        return skipped

    def to_record(self) -> dict:
        return {
            "sweep_id": self.sweep_id,
            "plan": self.plan.to_record(),
            "next_index": self.next_index,
            "measured": [[i, v.elevation, v.azimuth] for i, v in self.measured],
            "skipped": [[s.index, s.commanded.elevation, s.commanded.azimuth, s.reason, s.fault, s.tries]
                        for s in self.skipped],
            "active": self.active,
            "retry_skipped": self.retry_skipped,
        }

    @classmethod
    def from_record(cls, rec: dict) -> "SweepProgress":
        return cls(
            sweep_id=int(rec["sweep_id"]),
            plan=SweepPlan.from_record(rec["plan"]),
            next_index=int(rec["next_index"]),
            measured=[(int(i), ViewAngles(float(e), float(a))) for i, e, a in rec["measured"]],
            # A sweep saved before retries held [index, elevation, azimuth, reason].
            skipped=[SkippedPose(int(i), ViewAngles(float(e), float(a)), str(r), *_tried(more))
                     for i, e, a, r, *more in rec["skipped"]],
            active=bool(rec["active"]),
            retry_skipped=int(rec.get("retry_skipped", 0)),
        )


def _tried(more: list) -> tuple[bool, int]:
    fault, tries = (more + [False, 1])[:2]
    return bool(fault), int(tries)


def angular_distance(a: ViewAngles, b: ViewAngles) -> float:
    """Largest of the elevation and (wrapped) azimuth differences, degrees.

    At elevation 90 the azimuth does not change the view, so it is ignored there.
    """
    d_el = abs(a.elevation - b.elevation)
    d_az = abs((a.azimuth - b.azimuth + 180.0) % 360.0 - 180.0)
    if min(a.elevation, b.elevation) >= 89.0:
        d_az = 0.0
    return max(d_el, d_az)


class StateDb(Protocol):
    """The outbox's side of the store: state entries committed together with packets."""

    def state(self, key: str) -> str | None: ...
    def commit(self, packets: Iterable[tuple[int, bytes]] = (),
               state: dict[str, str] | None = None) -> list[int]: ...


class Boot(enum.StrEnum):
    """What `SweepStore.autostart` decided."""

    STARTED = "started"    # no sweep yet, a changed plan, or a new sweep asked for
    RESUMED = "resumed"    # an interrupted sweep goes on
    FINISHED = "finished"  # the plan's sweep is complete: nothing to do until asked
    STOPPED = "stopped"    # the sweep was aborted: nothing to do until asked


class SweepStore:
    """Sweep progress in the outbox database (`sweep`), with the plan autostart last used."""

    KEY = "sweep"
    AUTOSTART_KEY = "autostart_plan"

    def __init__(self, db: StateDb, legacy_dir: Path | None = None) -> None:
        self.db = db
        # Before progress moved into the outbox it was a file; read once, never written.
        self.legacy = None if legacy_dir is None else Path(legacy_dir) / "sweep.json"

    def load(self) -> SweepProgress | None:
        """The saved progress, or None when there is none (or it is unreadable: start over)."""
        text = self.db.state(self.KEY)
        if text is None and self.legacy is not None:
            try:
                text = self.legacy.read_text(encoding="utf-8")
            except OSError:
                return None
        return _parse(text, SweepProgress.from_record)

    def entry(self, progress: SweepProgress) -> dict[str, str]:
        """The state entry to commit with the packets of the step that made `progress`."""
        return {self.KEY: json.dumps(progress.to_record())}

    def save(self, progress: SweepProgress, packets: Iterable[tuple[int, bytes]] = ()) -> list[int]:
        """Store progress, with the packets it accounts for, in one transaction."""
        return self.db.commit(packets, self.entry(progress))

    def next_sweep(self, plan: SweepPlan) -> SweepProgress:
        """A new sweep whose id follows the saved one, not yet saved (commit `entry` of it)."""
        old = self.load()
        return SweepProgress(sweep_id=(old.sweep_id + 1) if old else 1, plan=plan)

    def start(self, plan: SweepPlan, autostart: bool = False) -> SweepProgress:
        """A new sweep, saved before it begins."""
        progress = self.next_sweep(plan)
        state = self.entry(progress)
        if autostart:
            state[self.AUTOSTART_KEY] = json.dumps(plan.to_record())
        self.db.commit((), state)
        return progress

    def autostart(self, plan: SweepPlan, new: bool = False) -> tuple[SweepProgress, Boot]:
        """At boot: resume an interrupted sweep, start one if needed, else leave it be.

        The plan counts as changed when it differs from the one autostart last started
        (or, with no record of that, from the saved sweep's plan)."""
        old = self.load()
        seen = _parse(self.db.state(self.AUTOSTART_KEY), SweepPlan.from_record)
        changed = seen != plan if seen is not None else old is not None and old.plan != plan
        if new or old is None or changed:
            return self.start(plan, autostart=True), Boot.STARTED
        if old.active and not old.done:
            return old, Boot.RESUMED
        return old, Boot.FINISHED if old.done else Boot.STOPPED


def _parse(text: str | None, build):
    if text is None:
        return None
    try:
        return build(json.loads(text))
    except (ValueError, KeyError, TypeError, AttributeError):
        return None
