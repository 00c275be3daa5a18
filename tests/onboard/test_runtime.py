"""The robot runtime on the fake HAL through the in-memory link seam."""
import json
import subprocess
import sys
import tracemalloc

import numpy as np
import pytest

from hal.interfaces import ViewAngles
from onboard import config
from onboard.capture.pipeline import Pipeline
from onboard.link.transport import MemoryTransport
from onboard.runtime import Mode
from radio import packets as pk
from radio.link import Acked, LinkDown, LinkUp
from tests.support import ROOT
from tests.support.robots import IDLE, robot_toml
from tests.support.runtime import PLAN3, decoded, host_view, make, poses_by_seq, replies, runtime_toml, sweep


@pytest.mark.parametrize("scene", ["black", "white", "mixed"])
def test_sweep_of_each_plate_sends_every_pose_label_band_model(fake_robot, scene):
    rt, tr = make(fake_robot, scene)
    sweep(rt)
    models = [p for p in decoded(tr) if isinstance(p, pk.ModelsPacket)]
    assert [round(p.commanded[0]) for p in models] == [90, 80, 70, 60, 50, 40, 30]
    for p in models:
        assert abs(p.measured[0] - p.commanded[0]) < 3  # filed under the tracker's angle
        labels = {lab.label for lab in p.labels}
        assert labels == ({1, 2} if scene == "mixed" else {1 if scene == "black" else 2})
        assert set(p.models) == {(lab, b) for lab in labels for b in range(3)}
    assert len(rt.outbox) == 0 and rt.mode is Mode.IDLE


def test_faults_at_ten_percent_still_finish_and_report_every_skipped_pose(fake_robot):
    # A stalled servo moves on only at the settle timeout (real seconds): 2 s, not the default 10.
    # Skipped poses stay skipped here (retry_skipped = 0); tests/onboard/sweep/test_retry_skipped.py tries them again.
    rt, tr = make(fake_robot, "black", rate=0.1, extra={"sweep": {"settle_timeout_s": 2, "retry_skipped": 0}})
    sweep(rt)
    packets = decoded(tr)
    measured = [p for p in packets if isinstance(p, pk.ModelsPacket)]
    skipped = [p for p in packets if isinstance(p, pk.StatusPacket) and p.report.sweep and p.report.sweep.skipped]
    assert len(measured) + len(skipped) == 7
    assert sorted(p.report.sweep.skipped.items[0].index for p in skipped) == [s.index for s in rt.progress.skipped]
    # "<step> failed after N attempts" or "settle failed: servos ... still moving after 2.0 s"
    assert all(p.text.startswith("skipped pose: ") and "failed" in p.text for p in skipped)
    assert rt.pipeline.faults  # faults did happen and were retried


def test_interrupted_sweep_resumes_after_restart_without_repeating_poses(fake_robot):
    rt, tr = make(fake_robot, "black")
    rt.boot()
    for _ in range(3):
        rt.step()
    first = {p.seq: p.commanded[0] for p in decoded(tr) if isinstance(p, pk.ModelsPacket)}
    rt.outbox.close()
    rt2, tr2 = make(fake_robot, "black")  # same state directory: a restart
    sweep(rt2)
    # An unacknowledged packet is offered again after the restart; the seq identifies it.
    second = {p.seq: p.commanded[0] for p in decoded(tr2) if isinstance(p, pk.ModelsPacket)}
    both = {**first, **second}
    assert sorted(both.values(), reverse=True) == [90, 80, 70, 60, 50, 40, 30]
    assert first and all(first[s] == second[s] for s in set(first) & set(second))


def test_unacknowledged_packets_stay_in_the_outbox_within_the_window(fake_robot):
    rt, tr = make(fake_robot, "black", transport=MemoryTransport(auto_ack=False))
    rt.boot()
    for _ in range(10):
        rt.step()
    assert len(tr.sent) == rt.cfg.link.window
    assert len(rt.outbox) > rt.cfg.link.window


def command(tr, cid, name, **args):
    tr.receive(pk.encode(pk.CommandPacket(cid, name, args)))


def test_commands_are_answered_with_a_result_or_a_reason(fake_robot):
    rt, tr = make(fake_robot, "black", extra=IDLE)
    rt.boot()
    C = pk.CommandName
    command(tr, 1, C.PING)
    command(tr, 2, C.GOTO, elevation=60.0, azimuth=0.0)
    command(tr, 3, C.SET, key="skip.min_pixels", value=5)
    command(tr, 4, C.SET, key="hal.scene", value="white")
    command(tr, 5, C.CAPTURE)
    command(tr, 6, C.STATUS)
    command(tr, 7, C.SWEEP, elevations=[70.0, 50.0], azimuths=[0.0])
    command(tr, 8, C.REBOOT_SERVO, servo_id=1)
    command(tr, 9, C.SEND_MASK, seq=1)
    for _ in range(6):
        rt.step()
    r = replies(tr)
    assert isinstance(r[1], pk.AckPacket)
    assert isinstance(r[2], pk.AckPacket) and abs(r[2].extras["elevation"] - 60) < 3
    assert isinstance(r[3], pk.AckPacket) and rt.cfg.skip.min_pixels == 5
    assert isinstance(r[4], pk.NackPacket) and r[4].reason is pk.Reason.BAD_ARGUMENT
    assert "cannot be set" in r[4].text
    assert isinstance(r[5], pk.AckPacket) and r[5].extras["models"] == 3
    assert r[6].status.mode == "idle"
    assert r[7].extras["poses"] == 2
    assert isinstance(r[8], pk.AckPacket) and isinstance(r[9], pk.AckPacket)
    models = [p for p in decoded(tr) if isinstance(p, pk.ModelsPacket)]
    assert [p.commanded[0] for p in models][-2:] == [70.0, 50.0]
    command(tr, 10, C.TORQUE_OFF)
    command(tr, 11, C.ABORT)
    rt.step()
    r = replies(tr)
    assert isinstance(r[10], pk.AckPacket) and isinstance(r[11], pk.AckPacket)


def test_failsafe_holds_the_arm_and_is_reported_when_the_link_returns(fake_robot):
    rt, tr = make(fake_robot, "black")
    rt.boot()
    tr.deliver(LinkUp())
    rt.step()
    tr.deliver(LinkDown())  # heartbeats stopped for longer than failsafe_s
    rt.step()
    assert rt.mode is Mode.FAILSAFE
    bus = rt.hal.servo_bus
    held = bus.positions([1, 2])
    rt.sleep(0.05)
    rt.step()
    assert bus.positions([1, 2]) == pytest.approx(held, abs=0.5)  # held, no sweep move
    command(tr, 20, pk.CommandName.GOTO, elevation=40.0, azimuth=0.0)  # read before the link is up
    tr.deliver(LinkUp())
    before = len(tr.sent)
    rt.step()
    assert rt.mode is Mode.SWEEPING  # resumed
    r = replies(tr)
    assert isinstance(r[20], pk.NackPacket) and r[20].reason is pk.Reason.BUSY
    statuses = [pk.decode(b) for _, b in tr.sent[before - 1:]]
    assert any(isinstance(p, pk.StatusPacket) and "failsafe" in p.text for p in statuses)


def test_goto_during_failsafe_is_refused_with_a_reason(fake_robot):
    rt, tr = make(fake_robot, "black", extra=IDLE)
    rt.boot()
    tr.deliver(LinkUp())
    rt.step()
    tr.deliver(LinkDown())
    rt.step()
    rt.dispatch.on_body(pk.encode(pk.CommandPacket(5, pk.CommandName.GOTO, {"elevation": 40.0, "azimuth": 0.0})))
    rt.service()
    r = replies(tr)
    assert isinstance(r[5], pk.NackPacket) and r[5].reason is pk.Reason.BUSY


def test_skip_rules_unchanged_marker_and_small_labels(fake_robot):
    rt, tr = make(fake_robot, "black", extra=IDLE)
    rt.dispatch.set_keys({"skip.unchanged_tolerance": 50.0})
    rt.boot()
    for cid in (1, 2):
        command(tr, cid, pk.CommandName.CAPTURE)
        rt.step()
    kinds = [type(p).__name__ for p in decoded(tr)]
    assert kinds.count("ModelsPacket") == 1 and kinds.count("UnchangedPacket") == 1


def test_garbage_from_the_base_never_ends_the_runtime(fake_robot):
    rt, tr = make(fake_robot, "black", extra=IDLE)
    rt.boot()
    for junk in (b"", b"\x00", b"\x93\x01\x04\x00", bytes(range(256))):
        tr.receive(junk)
    rt.step()
    assert len(rt.errors) == 4


def test_memory_growth_with_frame_size_is_only_the_frame_buffers(tmp_path):
    path = tmp_path / "robot.toml"
    path.write_text(robot_toml())
    cfg = config.load(path)

    def peak(n):
        rng = np.random.default_rng(0)
        frame = rng.integers(0, 256, (n, n, 3), dtype=np.uint8)
        labels = np.zeros((n, n), np.uint8)
        labels[:, n // 2:] = 1
        pipe = Pipeline(cfg, None, lambda f, fr, m: (labels[:f.data.shape[0], :f.data.shape[1]], False))
        pipe.process(frame[:8, :8], ViewAngles(90), ViewAngles(90))  # allocate the fitter first
        tracemalloc.start()
        pipe.process(frame, ViewAngles(90), ViewAngles(90))
        _, top = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        return top

    small, large = peak(500), peak(2000)
    # Feature bands (3 bytes/pixel) are the only frame-sized buffer the pipeline makes; what else
    # differs between the two calls does not grow with the frame (a cache entry, a log record).
    frame_buffers = (2000 * 2000 - 500 * 500) * 3
    assert large - small <= frame_buffers + 64 * 1024


def test_runtime_imports_nothing_from_the_host_and_stays_under_150_mb(tmp_path):
    path = tmp_path / "robot.toml"
    path.write_text(runtime_toml())
    code = f"""
import json, resource, sys
from onboard import config
from onboard.runtime import Runtime
from onboard.capture.segmentation import Segmentation
from onboard.link.transport import MemoryTransport
from hal.factory import build_hal
cfg = config.load({str(path)!r})
hal = build_hal(cfg.hal)
hal.camera.open(80, 60)
rt = Runtime(cfg, hal, MemoryTransport(), Segmentation(cfg, hal))
rt.run(lambda r: r.progress is not None and r.idle())
bad = [m for m in sys.modules if m.split('.')[0] in ('scipy', 'matplotlib', 'tools', 'skimage', 'cv2')]
# VmHWM, not ru_maxrss: Linux carries ru_maxrss across exec from the (large) test process.
hwm = next(int(l.split()[1]) for l in open("/proc/self/status") if l.startswith("VmHWM:"))
print(json.dumps({{"rss_kb": hwm, "bad": bad}}))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         cwd=ROOT, check=True)
    info = json.loads(out.stdout.strip().splitlines()[-1])
    assert info["bad"] == []
    assert info["rss_kb"] < 150 * 1024


# -- exactly once across restarts --------------------------------------------------------


class Crash(BaseException):
    """The process dies here (not an Exception: the loop's guard does not catch it)."""


def counting_commits(rt, kill_at=None, after=False):
    """Wrap the outbox's commit: count calls, and die at call `kill_at` (before or after it)."""
    real, calls = rt.outbox.commit, []

    def commit(*a, **kw):
        calls.append(1)
        if len(calls) == kill_at and not after:
            raise Crash()
        out = real(*a, **kw)
        if len(calls) == kill_at:
            raise Crash()
        return out

    rt.outbox.commit = commit
    return calls


@pytest.mark.parametrize("after", [False, True], ids=["kill-before-commit", "kill-after-commit"])
def test_a_kill_at_any_commit_delivers_every_pose_exactly_once(fake_robot, tmp_path, after):
    (tmp_path / "count").mkdir()
    rt, _ = make(fake_robot, "mixed", extra=PLAN3, where=tmp_path / "count")
    commits = counting_commits(rt)
    sweep(rt)
    assert len(commits) >= 4  # the sweep's start and its three poses at least
    for k in range(1, len(commits) + 1):
        state = tmp_path / f"kill{k}"
        state.mkdir()
        rt, tr = make(fake_robot, "mixed", extra=PLAN3, where=state)
        counting_commits(rt, kill_at=k, after=after)
        with pytest.raises(Crash):
            sweep(rt)
        rt.outbox.close()
        rt2, tr2 = make(fake_robot, "mixed", extra=PLAN3, where=state)  # restarted on the same state
        sweep(rt2)
        kept = host_view(tr, tr2)
        got = poses_by_seq(kept)
        assert [e for e, _ in got] == [70, 80, 90], (k, got)  # every pose, once
        assert len({s for _, s in got}) == 3
        masks = {seq for kind, seq in kept if kind == "MaskPacket"}
        assert masks and masks <= {s for _, s in got}  # no mask of a pose measured twice


def test_a_full_outbox_pauses_the_pose_and_measures_it_once_after_the_ack(fake_robot):
    tr = MemoryTransport(auto_ack=False)
    rt, _ = make(fake_robot, "black", extra=PLAN3, transport=tr, quota=600)
    box = rt.outbox
    rt.boot()
    for _ in range(6):
        rt.step()
    assert "outbox full" in rt.paused_reason and rt.progress.next_index < 3
    stuck = rt.progress.next_index
    for _ in range(3):
        rt.step()
    assert rt.progress.next_index == stuck  # nothing measured while the outbox is full
    while not rt.idle():
        for msg_id, _ in list(tr.sent):
            tr.deliver(Acked(msg_id))
        rt.step()
    got = poses_by_seq(host_view(tr))
    assert [e for e, _ in got] == [70, 80, 90] and len({s for _, s in got}) == 3
    assert not rt.progress.skipped and rt.paused_reason == ""
    assert box.bytes_used <= 600


def test_a_restart_after_a_finished_sweep_does_not_sweep_again(fake_robot):
    rt, tr = make(fake_robot, "black", extra=PLAN3)
    sweep(rt)
    assert rt.progress.done and len(poses_by_seq(host_view(tr))) == 3
    rt.outbox.close()
    rt2, tr2 = make(fake_robot, "black", extra=PLAN3)
    rt2.run(lambda r: r.idle())
    assert rt2.mode is Mode.IDLE and not poses_by_seq(host_view(tr2))
    boot = [p for p in decoded(tr2) if isinstance(p, pk.StatusPacket) and p.text == "boot"]
    assert boot[0].report.sweep.boot == "finished"
    rt2.outbox.close()
    # Asked for explicitly (btf-robot run --new-sweep) a new sweep runs, with new sequences.
    rt3, tr3 = make(fake_robot, "black", extra=PLAN3)
    rt3.sweep.new_sweep = True
    sweep(rt3)
    again = poses_by_seq(host_view(tr3))
    assert [e for e, _ in again] == [70, 80, 90]
    assert min(s for _, s in again) > max(s for _, s in poses_by_seq(host_view(tr)))
    assert rt3.progress.sweep_id == rt.progress.sweep_id + 1


def test_a_sweep_paused_by_a_full_outbox_rests_between_turns_instead_of_spinning(fake_robot):
    rests = []
    rt, _ = make(fake_robot, "black", extra=PLAN3, transport=MemoryTransport(auto_ack=False), quota=600,
                 sleep=lambda s: rests.append(s))
    turns = []
    rt.run(lambda r: turns.append(1) or len(turns) > 20, tick_s=0.01)
    assert rt.mode is Mode.SWEEPING and "outbox full" in rt.paused_reason
    assert rests.count(0.01) >= 15  # every paused turn rests a tick


def test_commands_are_still_answered_when_captures_have_filled_the_outbox(fake_robot):
    rt, tr = make(fake_robot, "mixed", extra={"sweep": {"start": 90, "stop": 0, "step": 2}},
                  transport=MemoryTransport(auto_ack=False), quota=8192)
    box = rt.outbox
    rt.boot()
    while not rt.paused_reason:
        rt.step()
    assert rt.sweep.step() == "paused"
    for cid in (1, 2, 3):
        command(tr, cid, pk.CommandName.PING if cid < 3 else pk.CommandName.STATUS)
    rt.service()
    answered = {p.command_id for _, body in box.pending(limit=1000)
                if isinstance(p := pk.decode(body), (pk.AckPacket, pk.NackPacket))}
    assert answered == {1, 2, 3} and box.bytes_used <= 8192


def test_per_pose_memory_is_bounded_over_a_long_mission(fake_robot):
    from onboard.capture.pipeline import MAX_POSES_REMEMBERED, remember

    table = {}
    for k in range(3 * MAX_POSES_REMEMBERED):
        remember(table, (k, 0), k)
    remember(table, (2 * MAX_POSES_REMEMBERED, 0), "again")  # re-set: now the newest
    assert len(table) == MAX_POSES_REMEMBERED
    assert list(table)[-1] == (2 * MAX_POSES_REMEMBERED, 0) and (0, 0) not in table
    rt, tr = make(fake_robot, "black", extra=IDLE)
    rt.boot()
    for cid, el in enumerate((90.0, 80.0, 70.0)):
        command(tr, 2 * cid, pk.CommandName.GOTO, elevation=el, azimuth=0.0)
        command(tr, 2 * cid + 1, pk.CommandName.CAPTURE)
        rt.step()
    assert len(rt.pipeline._previous) == len(rt.captures.last_models) == 3
