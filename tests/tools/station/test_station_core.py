"""The station's parts in one process, over a simulated cable: the event bus, the store before
the acknowledgement, a wrong key and another key's frames (said, never the end), the snapshot,
and a command answered once."""
import asyncio
import time

import pytest

from radio import packets as pk
from radio.auth import MemoryCounterStore
from radio.link import Link
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


def test_a_wrong_key_is_said_in_one_line_and_the_station_goes_on_listening(tmp_path):
    station, robot, _ = station_on_cable(tmp_path, robot_key=bytes(32))
    asyncio.run(drive(station, robot, lambda: station.pump.stats().rejected.get("tag", 0) >= 40, limit_s=20.0))
    assert station.failure is None and station.pump.stats().rejected["tag"] >= 40  # stopped by the test
    assert station.wrong_key.startswith("wrong key?") and "--key must hold" in station.wrong_key
    rejected = [e for e in station_log(tmp_path) if e["kind"] == "rejected"]
    assert rejected and all(e["reason"] == "tag" for e in rejected)
    said = [e for e in rejected if e.get("wrong_key")]
    assert said and said[0]["text"].startswith("wrong key?") and "still listening" in said[0]["text"]


class Forger:
    """A transmitter with another key on the robot's side of the cable: it only writes."""

    def __init__(self, end):
        self.link, self.end = Link(1, 2, 1, bytes(32), MemoryCounterStore(), heartbeat=0.01), end

    def turn(self):
        self.end.write(self.link.poll(time.monotonic()))


def test_the_station_survives_frames_of_another_key_before_and_after_hearing_its_robot(tmp_path):
    station, robot, store = station_on_cable(tmp_path)
    forger = Forger(robot.pump.port)
    tags = lambda: station.pump.stats().rejected.get("tag", 0)  # noqa: E731

    async def go():
        task = asyncio.ensure_future(station.run())

        async def until(done, *ends):
            end = time.monotonic() + 20.0
            while not done() and not task.done() and time.monotonic() < end:
                for e in ends:
                    e.turn()
                await asyncio.sleep(0.002)

        await until(lambda: station.wrong_key, forger)  # before the robot is heard
        first = robot.pump.send(models_body(7)[0], msg_id=41)
        await until(lambda: first in robot.acked, robot, forger)
        before = tags()
        said = lambda: any("another transmitter" in e["text"] for e in station_log(tmp_path))  # noqa: E731
        await until(lambda: tags() >= before + 40 and said(), robot, forger)  # after
        second = robot.pump.send(models_body(8)[0], msg_id=42)
        await until(lambda: second in robot.acked, robot, forger)
        station.stop()
        await task
        return first, second, before

    first, second, before = asyncio.run(go())
    assert station.failure is None and {first, second} <= robot.acked
    assert [c.sequence for c in store.captures()] == [7, 8] and tags() >= before + 40 >= 48
    texts = [e["text"] for e in station_log(tmp_path) if e["kind"] == "rejected"]
    assert any(t.startswith("wrong key?") for t in texts) and any("another transmitter" in t for t in texts)


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
