"""Sweep plans and persisted progress: resume after a restart, skip poses already measured."""
import json

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hal.interfaces import ViewAngles
from onboard.link.outbox import Outbox, OutboxFull
from onboard.sweep.plan import Boot, SweepPlan, SweepProgress, SweepStore, angular_distance


def test_plan_90_to_30_step_10_has_seven_poses_per_azimuth():
    plan = SweepPlan(90, 30, 10, (0.0, 90.0))
    poses = plan.poses()
    assert [p.elevation for p in poses[:7]] == [90, 80, 70, 60, 50, 40, 30]
    assert len(poses) == 14 and poses[7] == ViewAngles(90, 90.0)


def test_plan_runs_upward_too_and_rejects_bad_steps():
    assert [p.elevation for p in SweepPlan(30, 50, 10).poses()] == [30, 40, 50]
    with pytest.raises(ValueError, match="positive"):
        SweepPlan(90, 30, 0)


def test_plan_size_is_bounded_before_any_pose_is_listed():
    with pytest.raises(ValueError, match="exceeds 4096"):
        SweepPlan(90, 0, 1e-12)  # 9e13 poses: refused by arithmetic, not by building them
    with pytest.raises(ValueError, match=r"\[0, 90\]"):
        SweepPlan(0, 0, 1, elevations=(30.0, 120.0))
    with pytest.raises(ValueError, match="finite"):
        SweepPlan(90, 30, 10, (float("nan"),))
    plan = SweepPlan(90, 30, 10, (0.0, 90.0))
    assert plan.count == 14 and [plan.pose(i) for i in range(14)] == plan.poses()
    with pytest.raises(IndexError):
        plan.pose(14)


@given(st.floats(0, 90), st.floats(0, 90), st.floats(0.5, 45))
def test_plan_never_leaves_the_start_stop_interval(start, stop, step):
    poses = SweepPlan(start, stop, step).poses()
    lo, hi = min(start, stop), max(start, stop)
    assert poses[0].elevation == pytest.approx(start)
    assert all(lo - 1e-6 <= p.elevation <= hi + 1e-6 for p in poses)


def store_at(path):
    return SweepStore(Outbox(path / "outbox.sqlite"), legacy_dir=path)


def test_interrupted_sweep_resumes_where_it_stopped(tmp_path):
    plan = SweepPlan(90, 30, 10)
    store = store_at(tmp_path)
    prog, boot = store.autostart(plan)
    assert boot is Boot.STARTED
    prog.record_measured(ViewAngles(89.6, 0.2))
    prog.record_skipped("servo timeout")
    store.save(prog)
    store.db.close()
    # A new process: the same plan resumes at pose 2 with its history.
    again, boot = store_at(tmp_path).autostart(plan)
    assert boot is Boot.RESUMED
    assert again.sweep_id == prog.sweep_id and again.next_index == 2
    assert again.current() == ViewAngles(70.0, 0.0)
    assert again.skipped[0].reason == "servo timeout"
    assert again.measured == [(0, ViewAngles(89.6, 0.2))]


def test_progress_and_packets_are_one_commit(tmp_path):
    store = store_at(tmp_path)
    prog = store.start(SweepPlan(90, 80, 10))
    prog.record_measured(ViewAngles(90, 0))
    ids = store.save(prog, [(1, b"models of pose 0"), (2, b"its mask")])
    assert store.db.pending(10) == [(ids[0], b"models of pose 0"), (ids[1], b"its mask")]
    assert store.load().next_index == 1
    full = SweepStore(Outbox(tmp_path / "small.sqlite", quota_bytes=200))
    first = full.start(SweepPlan(90, 80, 10))
    first.record_measured(ViewAngles(90, 0))
    with pytest.raises(OutboxFull):
        full.save(first, [(1, b"x" * 300)])
    # Neither the packet nor the progress past the pose was stored.
    assert len(full.db) == 0 and full.load().next_index == 0


def test_finished_sweep_of_the_same_plan_is_not_started_again(tmp_path):
    store = store_at(tmp_path)
    prog = store.start(SweepPlan(90, 80, 10), autostart=True)
    prog.record_measured(ViewAngles(90, 0))
    prog.record_measured(ViewAngles(80, 0))
    prog.active = False
    store.save(prog)
    assert prog.done
    again, boot = store.autostart(SweepPlan(90, 80, 10))
    assert boot is Boot.FINISHED and again.sweep_id == prog.sweep_id and again.done
    # Asked for explicitly, or with a changed plan, a new sweep starts.
    fresh, boot = store.autostart(SweepPlan(90, 80, 10), new=True)
    assert boot is Boot.STARTED and fresh.sweep_id == prog.sweep_id + 1 and fresh.next_index == 0
    other, boot = store.autostart(SweepPlan(90, 30, 10))
    assert boot is Boot.STARTED and other.sweep_id == fresh.sweep_id + 1
    assert store.autostart(SweepPlan(90, 30, 10))[1] is Boot.RESUMED


def test_sweep_from_a_command_resumes_then_rests_without_reverting_to_the_config_plan(tmp_path):
    config_plan, commanded = SweepPlan(90, 30, 10), SweepPlan(80, 60, 10)
    store = store_at(tmp_path)
    store.autostart(config_plan)
    cmd = store.start(commanded)  # a SWEEP command replaces the autostarted sweep
    cmd.record_measured(ViewAngles(80, 0))
    store.save(cmd)
    resumed, boot = store.autostart(config_plan)
    assert boot is Boot.RESUMED and resumed.plan == commanded and resumed.next_index == 1
    resumed.record_measured(ViewAngles(70, 0))
    resumed.record_measured(ViewAngles(60, 0))
    store.save(resumed)
    assert store.autostart(config_plan)[1] is Boot.FINISHED


def test_aborted_sweep_is_not_restarted_at_boot(tmp_path):
    store = store_at(tmp_path)
    prog, _ = store.autostart(SweepPlan(90, 30, 10))
    prog.active = False
    store.save(prog)
    again, boot = store.autostart(SweepPlan(90, 30, 10))
    assert boot is Boot.STOPPED and again.sweep_id == prog.sweep_id


def test_garbage_progress_starts_over_instead_of_crashing(tmp_path):
    store = store_at(tmp_path)
    store.db.commit((), {SweepStore.KEY: '{"sweep_id": 3, "plan": ', SweepStore.AUTOSTART_KEY: "[1, 2"})
    assert store.load() is None
    prog, boot = store.autostart(SweepPlan(90, 30, 10))
    assert boot is Boot.STARTED and prog.next_index == 0 and prog.sweep_id == 1
    assert json.loads(store.db.state(SweepStore.KEY))["sweep_id"] == 1


def test_progress_from_the_old_sweep_file_is_read_once(tmp_path):
    old = SweepProgress(4, SweepPlan(90, 30, 10))
    old.record_measured(ViewAngles(90, 0))
    (tmp_path / "sweep.json").write_text(json.dumps(old.to_record()))
    prog, boot = store_at(tmp_path).autostart(SweepPlan(90, 30, 10))
    assert boot is Boot.RESUMED and prog.sweep_id == 4 and prog.next_index == 1
    (tmp_path / "sweep.json").write_text("{torn")
    assert SweepStore(Outbox(tmp_path / "other.sqlite"), legacy_dir=tmp_path).load() is None


def test_already_measured_within_tolerance():
    prog = SweepProgress(1, SweepPlan(90, 30, 10))
    prog.record_measured(ViewAngles(70.4, 10.0))
    assert prog.already_measured(ViewAngles(70.0, 10.5), 1.0)
    assert not prog.already_measured(ViewAngles(68.0, 10.0), 1.0)
    assert not prog.already_measured(ViewAngles(70.0, 20.0), 1.0)


def test_azimuth_wraps_and_is_ignored_straight_down():
    assert angular_distance(ViewAngles(50, 359.5), ViewAngles(50, 0.5)) == pytest.approx(1.0)
    assert angular_distance(ViewAngles(90, 0), ViewAngles(89.5, 180)) == pytest.approx(0.5)
