"""`kill -9` the station at random instants during a sweep, again and again, restarting it each
time: the host ends with every capture of the sweep exactly once, and a `cmd`
client that lost its station mid-command gets one answer from the next.

A kill lands anywhere: between storing a packet and acknowledging it (the robot sends it
again and the database keeps it once), in the middle of a write, while a command is on its
way. BTF_KILL_SEED picks other kill instants (to hunt for a failing schedule by hand)."""
import os
import random
import threading
import time
from collections import Counter

import pytest

from tests.support.station_rig import AUTONOMOUS, POSES, Rig, kill9

OUTBOX = 4096  # bytes: the robot runs at most a few poses ahead of the station


def kill_during_sweep(tmp_path, kills: int, radio: str = "", clients: int = 1) -> None:
    rig = Rig(tmp_path, {"hal": {"size": [80, 100]}}, AUTONOMOUS, outbox_quota_bytes=OUTBOX)
    rng = random.Random(int(os.environ.get("BTF_KILL_SEED", "15")))
    answers: list = []
    stop = threading.Event()

    def client() -> None:  # status commands across the kills: each answered once, by some station
        while not stop.is_set():
            answers.append(rig.cmd("status", timeout=120))

    try:
        robot = rig.robot()
        threads = [threading.Thread(target=client) for _ in range(clients)]
        killed_mid_sweep = 0
        for i in range(kills):
            station = rig.station(*(("--port", f"btfsim://?port={rig.cable.paths[1]}&{radio}") if radio else ()))
            rig.wait_up(station)
            if i == 0:
                for t in threads:
                    t.start()
            time.sleep(rng.uniform(0.0, 0.6))
            killed_mid_sweep += robot.poll() is None and len(rig.captures()) < len(POSES)
            kill9(station)
        station = rig.station()
        rig.wait_up(station)
        rig.wait_for_poses(POSES, robot=robot)
        stop.set()  # the commands still on their way are answered by this last station
        for t in threads:
            t.join()
        assert rig.stop(station) == 0 and rig.stop(robot) == 0
        captures = rig.captures()
        log = rig.log()
    finally:
        stop.set()
        rig.close()
    assert killed_mid_sweep >= kills // 2, killed_mid_sweep
    by_pose = Counter((c.commanded[0], c.commanded[1]) for c in captures)
    assert sorted(by_pose) == POSES and set(by_pose.values()) == {1}, {p: n for p, n in by_pose.items() if n > 1}
    # each capture stored by exactly one delivery; a re-sent one was recognised, not stored again
    stored = Counter((e["robot"], e["seq"]) for e in log if e["kind"] == "capture" and e["stored"])
    assert set(stored.values()) == {1} and len(stored) <= len(captures)
    assert len({c.sequence for c in captures}) == len(captures) == len(POSES)
    # every status command got exactly one answer, whichever station carried it
    assert answers and all(code == 0 and len(lines) == 1 for code, lines, _ in answers), answers


def test_a_station_killed_ten_times_during_a_sweep_loses_and_duplicates_nothing(tmp_path):
    kill_during_sweep(tmp_path, kills=10)


@pytest.mark.slow
@pytest.mark.skipif(not os.environ.get("BTF_STRESS"), reason="stress run only (make stress)")
def test_a_station_killed_thirty_times_over_a_lossy_radio_loses_and_duplicates_nothing(tmp_path):
    kill_during_sweep(tmp_path, kills=30, radio="loss=0.1&ber=1e-4&seed=3", clients=3)
