"""A sweep's plan as the grid the operator's page draws: elevations down, azimuths across,
each pose done, skipped (with the robot's reason), being measured, or pending.

The plan is the robot's (`onboard.sweep.plan.SweepPlan`, its record in the STATUS answer) or the
arguments of the SWEEP this station sent; progress is the robot's `next` index from its
STATUS, advanced between reports by the captures that arrive at the plan's poses.
"""
from __future__ import annotations

from typing import Any

from onboard.sweep.plan import SweepPlan

GRID_POSES = 4096  # onboard.sweep.plan.MAX_POSES: a plan is never larger
MATCH_DEG = 0.01  # a capture's commanded angles are the pose's, to the wire's centidegree


class Cell:
    DONE, SKIPPED, MEASURING, PENDING = "d", "s", "m", "p"


def plan_of(record: Any) -> SweepPlan | None:
    """A plan from its record (`SweepPlan.to_record`), or None when it is not a valid one."""
    try:
        return SweepPlan.from_record(record)
    except (KeyError, TypeError, ValueError):
        return None


def plan_of_command(args: dict) -> SweepPlan | None:
    """The plan a SWEEP command's arguments name, as the robot builds it (`onboard.dispatch`);
    None when it leaves the azimuths to the robot's config."""
    if "azimuths" not in args:
        return None
    azs = [float(a) for a in args["azimuths"]]
    if "elevations" in args:
        els = [float(e) for e in args["elevations"]]
        return plan_of({"start": els[0], "stop": els[-1], "step": 1.0, "azimuths": azs, "elevations": els})
    return plan_of({"start": args["start"], "stop": args["stop"], "step": args["step"], "azimuths": azs})


def index_of(plan: SweepPlan, commanded: tuple[float, float], taken: set[int], after: int) -> int | None:
    """The first pose of the plan from `after` on, not in `taken`, at the commanded angles."""
    for i in range(max(0, after), plan.count):
        if i not in taken and same_pose(plan.pose(i), commanded):
            return i
    return None


def same_pose(pose: Any, commanded: tuple[float, float]) -> bool:
    """Whether a plan's pose is at the commanded (elevation, azimuth), to the wire's centidegree."""
    el, az = commanded
    return abs(pose.elevation - el) <= MATCH_DEG and abs((pose.azimuth - az + 180.0) % 360.0 - 180.0) <= MATCH_DEG


def grid_json(plan: SweepPlan | None, next_index: int | None, done: set[int], skipped: list[dict],
              active: bool | None) -> dict | None:
    """`{"elevations": [rows], "azimuths": [columns], "cells": "dsmp..." (row by row),
    "reasons": {"row,col": reason}}`; None without a plan."""
    if plan is None or plan.count > GRID_POSES:
        return None
    poses = plan.poses()
    els = list(dict.fromkeys(p.elevation for p in poses))
    azs = list(dict.fromkeys(p.azimuth for p in poses))
    reasons = {int(k["index"]): str(k["reason"]) for k in skipped}
    state: dict[tuple[int, int], str] = {}
    reason_at: dict[str, str] = {}
    measuring = None
    for i, p in enumerate(poses):
        at = (els.index(p.elevation), azs.index(p.azimuth))
        if i in reasons:
            state[at] = Cell.SKIPPED
            reason_at[f"{at[0]},{at[1]}"] = reasons[i]
        elif i in done or (next_index is not None and i < next_index):
            state[at] = Cell.DONE
        else:
            if measuring is None and active:
                measuring = at
            state[at] = Cell.PENDING
    if measuring is not None:
        state[measuring] = Cell.MEASURING
    cells = "".join(state.get((r, c), " ") for r in range(len(els)) for c in range(len(azs)))
    return {"elevations": els, "azimuths": azs, "cells": cells, "reasons": reason_at}
