"""The station's parts in one process, over a simulated cable: the event bus, the store before
the acknowledgement, the wrong key, the snapshot, and a command answered once."""
import asyncio

import pytest

from radio import packets as pk
from tests.support.packets import models_body
from tests.support.station_cable import drive, station_log, station_on_cable
from tools.station.bus import EventBus
from tools.store.database import Store


def test_a_slow_subscriber_loses_the_oldest_events_and_is_told_how_many():
    async def go():
        bus = EventBus()
        fast, slow = bus.subscribe(100), bus.subscribe(3)
        for i in range(10):
            bus.publish({"kind": "x", "i": i})
        got_fast = [(await fast.get())["i"] for _ in range(10)]
        lost = await slow.get()
        got_slow = [(await slow.get())["i"] for _ in range(3)]
        slow.close()
        with pytest.raises(EOFError):
            await slow.get()
        bus.publish({"kind": "x", "i": 10})
        return got_fast, lost, got_slow, bus.subscribers, await fast.get()

    got_fast, lost, got_slow, subscribers, last = asyncio.run(go())
    assert got_fast == list(range(10)) and last["i"] == 10
    assert lost.KIND == "lost" and lost.count == 7 and got_slow == [7, 8, 9]
    assert subscribers == 1


def test_a_packet_is_acknowledged_only_once_it_is_stored(tmp_path):
    station, robot, store = station_on_cable(tmp_path)
    mid = robot.pump.send(models_body(7)[0], msg_id=41)
    asyncio.run(drive(station, robot, lambda: mid in robot.acked))
    assert mid in robot.acked and [c.sequence for c in store.captures()] == [7]
    events = [e for e in station_log(tmp_path) if e["kind"] == "capture"]
    assert events[0]["stored"] and events[0]["seq"] == 7 and events[0]["capture"]["regions"] == 2


def test_a_store_that_fails_ends_the_station_and_nothing_is_acknowledged(tmp_path):
    class BrokenStore(Store):
        def add_capture(self, *a, **k):
            raise OSError("disk full")

    from tools.store.schema import connect
    broken = BrokenStore(connect(tmp_path / "host.db", True), tmp_path / "host.db")
    station, robot, _ = station_on_cable(tmp_path, store=broken)
    mid = robot.pump.send(models_body(7)[0], msg_id=41)
    asyncio.run(drive(station, robot, lambda: False, limit_s=3.0))
    assert station.failure is not None and station.failure.status == 1 and "disk full" in str(station.failure)
    for _ in range(50):  # whatever the station wrote before it failed has arrived by now
        robot.turn()
    assert mid not in robot.acked and robot.pump.link.queued_bytes > 0  # still the robot's to send


def test_a_wrong_key_ends_the_station_saying_so(tmp_path):
    station, robot, _ = station_on_cable(tmp_path, robot_key=bytes(32))
    asyncio.run(drive(station, robot, lambda: False, limit_s=20.0))
    assert station.failure is not None and station.failure.status == 2
    assert "wrong key?" in str(station.failure)
    rejected = [e for e in station_log(tmp_path) if e["kind"] == "rejected"]
    assert rejected and rejected[0]["reason"] == "tag" and "tag mismatch: wrong key?" in rejected[0]["cause"]


def test_a_command_is_answered_once_and_the_snapshot_follows_the_robot(tmp_path):
    station, robot, _ = station_on_cable(tmp_path)
    status = pk.StatusPacket(1, 1_700_000_000.0, pk.RobotState.SWEEPING, (60.0, 0.0), 3, 900, 6,
                             "skipped pose: settle failed", report=pk.StatusReport(sweep=pk.SweepReport(
                                 2, skipped=pk.Kept((pk.SkippedPose(4, 50.0, 0.0, "settle failed"),)))))
    robot.pump.send(pk.encode(status))
    answers = []

    async def go():
        sub = station.bus.subscribe()
        _, fut = station.submit(pk.CommandName.PING, {}, command_id=77)
        _, again = station.submit(pk.CommandName.PING, {}, command_id=77)  # the same id, twice
        drive_task = asyncio.ensure_future(drive(station, robot, lambda: fut.done() and again.done()))
        answers.extend([await fut, await again])
        await drive_task
        kinds = []
        while (e := sub.get_nowait()) is not None:
            kinds.append(e.KIND)
        return kinds

    kinds = asyncio.run(go())
    assert [a["command_id"] for a in answers] == [77, 77] and all(a["ok"] and a["type"] == "ACK" for a in answers)
    assert len(robot.commands) == 2 and answers[0] == answers[1]  # both waiters, one answer
    assert kinds.count("answer") == 1 and "status" in kinds and "link" in kinds
    snap = station.snapshot_json()
    assert set(snap) == {"station", "link", "robot", "sweep", "captures"}
    assert snap["link"]["up"] and snap["link"]["frames_accepted"] > 0 and snap["link"]["last_heard"]
    assert snap["robot"]["state"] == "sweeping" and snap["robot"]["pose"] == {"elevation": 60.0, "azimuth": 0.0}
    assert snap["sweep"]["id"] == 2 and snap["sweep"]["skipped"] == [
        {"index": 4, "elevation": 50.0, "azimuth": 0.0, "reason": "settle failed", "tries": 1}]


def test_an_answer_is_logged_without_the_fields_the_robot_left_empty(tmp_path):
    station, robot, _ = station_on_cable(tmp_path)
    robot.extras = {"set": "skip.min_pixels", "camera": ""}

    async def go():
        _, fut = station.submit(pk.CommandName.SET, {"key": "skip.min_pixels", "value": 50}, command_id=78)
        await drive(station, robot, fut.done)
        return await fut

    assert asyncio.run(go())["extras"]["camera"] == ""  # the answer itself as the robot sent it
    said = [e["text"] for e in station_log(tmp_path) if e["kind"] == "answer"]
    assert said == ["SET (command 78): ACK set=skip.min_pixels"], said
