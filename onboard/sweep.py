"""The sweep plan and its progress, persisted atomically so a restarted robot resumes.

A plan is the list of commanded poses (elevation start..stop by step, for each
azimuth). Progress records, per sweep, which poses are done, the measured view each
capture was filed under, and the poses skipped with their reason. The file is
written to a temporary name, fsynced and renamed, so a kill at any instant leaves
either the old or the new state, never a torn one.
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path

from hal.interfaces import ViewAngles


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

    def poses(self) -> list[ViewAngles]:
        """Elevations from start toward stop (inclusive, either direction), per azimuth."""
        if self.elevations:
            return [ViewAngles(float(e), float(a)) for a in self.azimuths for e in self.elevations]
        direction = -1.0 if self.stop < self.start else 1.0
        n = int(math.floor(abs(self.stop - self.start) / self.step + 1e-9)) + 1
        elevations = [self.start + direction * i * self.step for i in range(n)]
        return [ViewAngles(e, float(a)) for a in self.azimuths for e in elevations]


@dataclass(frozen=True, slots=True)
class SkippedPose:
    index: int
    commanded: ViewAngles
    reason: str


@dataclass
class SweepProgress:
    """Mutable progress of one sweep; `save` persists it atomically."""

    sweep_id: int
    plan: SweepPlan
    next_index: int = 0
    measured: list[tuple[int, ViewAngles]] = field(default_factory=list)
    skipped: list[SkippedPose] = field(default_factory=list)
    active: bool = True

    @property
    def poses(self) -> list[ViewAngles]:
        return self.plan.poses()

    @property
    def done(self) -> bool:
        return self.next_index >= len(self.poses)

    def current(self) -> ViewAngles | None:
        poses = self.poses
        return poses[self.next_index] if self.next_index < len(poses) else None

    def already_measured(self, view: ViewAngles, tolerance_deg: float) -> bool:
        """Whether a capture of this sweep was filed within tolerance of `view`."""
        return any(angular_distance(view, m) <= tolerance_deg for _, m in self.measured)

    def record_measured(self, view: ViewAngles) -> None:
        self.measured.append((self.next_index, view))
        self.next_index += 1

    def record_skipped(self, reason: str) -> SkippedPose:
        pose = self.current()
        if pose is None:
            raise ValueError("the sweep is already complete")
        skipped = SkippedPose(self.next_index, pose, reason)
        self.skipped.append(skipped)
        self.next_index += 1
        return skipped

    def to_record(self) -> dict:
        return {
            "sweep_id": self.sweep_id,
            "plan": {**asdict(self.plan), "azimuths": list(self.plan.azimuths),
                     "elevations": list(self.plan.elevations)},
            "next_index": self.next_index,
            "measured": [[i, v.elevation, v.azimuth] for i, v in self.measured],
            "skipped": [[s.index, s.commanded.elevation, s.commanded.azimuth, s.reason]
                        for s in self.skipped],
            "active": self.active,
        }

    @classmethod
    def from_record(cls, rec: dict) -> "SweepProgress":
        plan = rec["plan"]
        return cls(
            sweep_id=int(rec["sweep_id"]),
            plan=SweepPlan(float(plan["start"]), float(plan["stop"]), float(plan["step"]),
                           tuple(float(a) for a in plan["azimuths"]),
                           tuple(float(e) for e in plan.get("elevations", ()))),
            next_index=int(rec["next_index"]),
            measured=[(int(i), ViewAngles(float(e), float(a))) for i, e, a in rec["measured"]],
            skipped=[SkippedPose(int(i), ViewAngles(float(e), float(a)), str(r))
                     for i, e, a, r in rec["skipped"]],
            active=bool(rec["active"]),
        )


def angular_distance(a: ViewAngles, b: ViewAngles) -> float:
    """Largest of the elevation and (wrapped) azimuth differences, degrees.

    At elevation 90 the azimuth does not change the view, so it is ignored there.
    """
    d_el = abs(a.elevation - b.elevation)
    d_az = abs((a.azimuth - b.azimuth + 180.0) % 360.0 - 180.0)
    if min(a.elevation, b.elevation) >= 89.0:
        d_az = 0.0
    return max(d_el, d_az)


class SweepStore:
    """The sweep progress file under the state directory."""

    def __init__(self, state_dir: Path) -> None:
        self.path = Path(state_dir) / "sweep.json"

    def load(self) -> SweepProgress | None:
        """The saved progress, or None when there is none (or it is unreadable: start over)."""
        try:
            rec = json.loads(self.path.read_text(encoding="utf-8"))
            return SweepProgress.from_record(rec)
        except FileNotFoundError:
            return None
        except (OSError, ValueError, KeyError, TypeError):
            return None

    def save(self, progress: SweepProgress) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_suffix(".tmp")
        data = json.dumps(progress.to_record()).encode()
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            os.write(fd, data)
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, self.path)
        dir_fd = os.open(self.path.parent, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)

    def start(self, plan: SweepPlan) -> SweepProgress:
        """A new sweep (the id follows the saved one), saved before it begins."""
        old = self.load()
        progress = SweepProgress(sweep_id=(old.sweep_id + 1) if old else 1, plan=plan)
        self.save(progress)
        return progress

    def resume_or_start(self, plan: SweepPlan) -> SweepProgress:
        """Resume an unfinished sweep of the same plan; otherwise start a new one."""
        old = self.load()
        if old is not None and old.active and not old.done and old.plan == plan:
            return old
        return self.start(plan)
