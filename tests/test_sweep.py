"""Sweep plans and persisted progress: resume after a restart, skip poses already measured."""
import json

import pytest
from hypothesis import given, strategies as st

from hal.interfaces import ViewAngles
from onboard.sweep import SweepPlan, SweepProgress, SweepStore, angular_distance


def test_plan_90_to_30_step_10_has_seven_poses_per_azimuth():
    plan = SweepPlan(90, 30, 10, (0.0, 90.0))
    poses = plan.poses()
    assert [p.elevation for p in poses[:7]] == [90, 80, 70, 60, 50, 40, 30]
    assert len(poses) == 14 and poses[7] == ViewAngles(90, 90.0)


def test_plan_runs_upward_too_and_rejects_bad_steps():
    assert [p.elevation for p in SweepPlan(30, 50, 10).poses()] == [30, 40, 50]
    with pytest.raises(ValueError, match="positive"):
        SweepPlan(90, 30, 0)


@given(st.floats(0, 90), st.floats(0, 90), st.floats(0.5, 45))
def test_plan_never_leaves_the_start_stop_interval(start, stop, step):
    poses = SweepPlan(start, stop, step).poses()
    lo, hi = min(start, stop), max(start, stop)
    assert poses[0].elevation == pytest.approx(start)
    assert all(lo - 1e-6 <= p.elevation <= hi + 1e-6 for p in poses)


def test_interrupted_sweep_resumes_where_it_stopped(tmp_path):
    plan = SweepPlan(90, 30, 10)
    store = SweepStore(tmp_path)
    prog = store.resume_or_start(plan)
    prog.record_measured(ViewAngles(89.6, 0.2))
    prog.record_skipped("servo timeout")
    store.save(prog)
    # A new process: the same plan resumes at pose 2 with its history.
    again = SweepStore(tmp_path).resume_or_start(plan)
    assert again.sweep_id == prog.sweep_id and again.next_index == 2
    assert again.current() == ViewAngles(70.0, 0.0)
    assert again.skipped[0].reason == "servo timeout"
    assert again.measured == [(0, ViewAngles(89.6, 0.2))]


def test_finished_or_changed_plan_starts_a_new_sweep(tmp_path):
    store = SweepStore(tmp_path)
    prog = store.start(SweepPlan(90, 80, 10))
    prog.record_measured(ViewAngles(90, 0))
    prog.record_measured(ViewAngles(80, 0))
    store.save(prog)
    assert prog.done
    fresh = store.resume_or_start(SweepPlan(90, 80, 10))
    assert fresh.sweep_id == prog.sweep_id + 1 and fresh.next_index == 0
    other = store.resume_or_start(SweepPlan(90, 30, 10))
    assert other.sweep_id == fresh.sweep_id + 1


def test_torn_or_garbage_progress_file_starts_over_instead_of_crashing(tmp_path):
    store = SweepStore(tmp_path)
    store.path.write_text('{"sweep_id": 3, "plan": ')
    assert store.load() is None
    prog = store.resume_or_start(SweepPlan(90, 30, 10))
    assert prog.next_index == 0
    assert json.loads(store.path.read_text())["sweep_id"] == 1
    assert not store.path.with_suffix(".tmp").exists()


def test_already_measured_within_tolerance():
    prog = SweepProgress(1, SweepPlan(90, 30, 10))
    prog.record_measured(ViewAngles(70.4, 10.0))
    assert prog.already_measured(ViewAngles(70.0, 10.5), 1.0)
    assert not prog.already_measured(ViewAngles(68.0, 10.0), 1.0)
    assert not prog.already_measured(ViewAngles(70.0, 20.0), 1.0)


def test_azimuth_wraps_and_is_ignored_straight_down():
    assert angular_distance(ViewAngles(50, 359.5), ViewAngles(50, 0.5)) == pytest.approx(1.0)
    assert angular_distance(ViewAngles(90, 0), ViewAngles(89.5, 180)) == pytest.approx(0.5)
