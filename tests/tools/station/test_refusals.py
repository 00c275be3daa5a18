"""A packet the station cannot use never ends it: it is kept raw in rejected_packets, counted,
logged, and refused to the robot with a NACK UNUSABLE naming the message, which the robot sets
aside for good (the loop of "store, crash, restart, receive it again" is gone)."""
import asyncio
import time

import msgpack

from radio import packets as pk
from radio.auth import MemoryCounterStore
from radio.channel import ChannelConfig
from radio.channel_port import Cable
from radio.link import Link
from radio.pump import LinkPump
from tests.support.packets import models_body
from tests.support.robots import IDLE, SMALL, robot_toml
from tests.support.station_cable import KEY, drive, station_log, station_on_cable
from tools.station.log import StationLog
from tools.station.receiver import Receiver
from tools.station.station import Station
from tools.store.database import Store

ROBOT = robot_toml(SMALL, IDLE, {"link": {"heartbeat_s": 0.1}})


def old_status(extras: dict) -> bytes:
    """A STATUS in the schema-3 layout older robots sent: their state in free-form extras."""
    return msgpack.packb([3, int(pk.Kind.STATUS), 1, 1.7e9, 0, None, None, 0, 0, None, "boot", extras])


def nacks(robot) -> dict[int, pk.NackPacket]:
    return {p.msg_id: p for p in robot.commands if isinstance(p, pk.NackPacket)}


def test_an_old_status_whose_extras_say_sweep_abc_is_used_and_the_station_goes_on(tmp_path):
    station, robot, store = station_on_cable(tmp_path)
    mid = robot.pump.send(old_status({"sweep": "abc", "mode": "idle", "disk": 5}), msg_id=3)
    asyncio.run(drive(station, robot, lambda: mid in robot.acked))
    assert station.failure is None and mid in robot.acked and not nacks(robot)
    assert station.snapshot_json()["robot"]["mode"] == "idle"  # what it said well is read; the rest is not
    (status,) = [e for e in station_log(tmp_path) if e["kind"] == "status"]
    assert status["packet"]["extras"]["sweep"] == "abc"


def test_a_hostile_report_is_kept_raw_refused_by_its_id_and_the_station_goes_on(tmp_path):
    station, robot, store = station_on_cable(tmp_path)
    good = msgpack.unpackb(pk.encode(pk.StatusPacket(1, 1.7e9, pk.RobotState.IDLE, None, 0, 0, None, "boot")))
    hostile = msgpack.packb([*good[:-1], {11: {1: "abc"}}])  # the sweep's id a string
    huge_time = msgpack.unpackb(models_body(7)[0])
    huge_time[4] = 1e300
    bodies = {11: hostile, 12: msgpack.packb(huge_time), 13: models_body(8)[0]}
    for mid, body in bodies.items():
        robot.pump.send(body, msg_id=mid)
    asyncio.run(drive(station, robot, lambda: {11, 12} <= set(nacks(robot)) and 13 in robot.acked))
    assert station.failure is None and {11, 12, 13} <= robot.acked
    said = nacks(robot)
    assert said[11].reason is pk.Reason.UNUSABLE and "sweep id must be an integer" in said[11].text
    assert "time = 1e+300 outside" in said[12].text
    kept = {r.msg_id: r for r in store.rejected()}
    assert set(kept) == {11, 12} and kept[11].body == hostile and kept[12].sender == 1
    assert [c.sequence for c in store.captures()] == [8]  # the huge time was never stored
    bad = [e for e in station_log(tmp_path) if e["kind"] == "bad"]
    assert {e["msg_id"] for e in bad} == {11, 12} and all(e["told"] and e["tone"] == "bad" for e in bad)
    assert station.snapshot_json()["captures"]["bad"] == 2 and station.refused == 2


def test_a_value_the_store_refuses_is_refused_but_a_store_that_fails_still_ends_the_station(tmp_path):
    class Picky(Store):
        def add_capture(self, *a, **k):
            raise ValueError("levels 3: expected ...")

    from tools.store.schema import connect
    picky = Picky(connect(tmp_path / "host.db", True), tmp_path / "host.db")
    station, robot, _ = station_on_cable(tmp_path, store=picky)
    robot.pump.send(models_body(7)[0], msg_id=21)
    asyncio.run(drive(station, robot, lambda: 21 in nacks(robot)))
    assert station.failure is None and "MODELS not stored: levels 3" in nacks(robot)[21].text
    assert [r.msg_id for r in picky.rejected()] == [21]


def test_a_fault_handling_a_decoded_packet_refuses_it_and_is_counted(tmp_path, monkeypatch):
    station, robot, store = station_on_cable(tmp_path)
    monkeypatch.setattr(station.snapshot, "note_status", lambda *a: 1 / 0)
    robot.pump.send(pk.encode(pk.StatusPacket(1, 1.7e9, pk.RobotState.IDLE, None, 0, 0, None, "boot")), msg_id=31)
    robot.pump.send(models_body(9)[0], msg_id=32)
    asyncio.run(drive(station, robot, lambda: 31 in nacks(robot) and 32 in robot.acked))
    assert station.failure is None and station.faults == 1
    assert "could not handle status: ZeroDivisionError" in nacks(robot)[31].text
    assert [c.sequence for c in store.captures()] == [9]


def test_the_robot_sets_aside_the_status_the_station_refused_and_never_sends_it_again(tmp_path, fake_robot):
    cable = Cable(ChannelConfig(latency=0.0, bandwidth=1e7, buffer=1 << 20))
    rt, _ = fake_robot(ROBOT, transport=LinkPump(Link(1, 2, 1, KEY, MemoryCounterStore(), heartbeat=0.1,
                                                      link_timeout=5.0), cable.ends[0]))
    good = msgpack.unpackb(pk.encode(pk.StatusPacket(1, 1.7e9, pk.RobotState.IDLE, None, 0, 0, None, "boot")))
    hostile = msgpack.packb([*good[:-1], {11: {1: "abc"}}])
    mid = rt.outbox.put(int(pk.Kind.STATUS), hostile)  # as a robot of another build might have queued it
    store = Store.open(tmp_path / "host.db")

    def station():
        pump = LinkPump(Link(2, 1, 1, KEY, MemoryCounterStore(), heartbeat=0.1, link_timeout=5.0), cable.ends[1])
        return Station(pump, Receiver(store), StationLog(tmp_path / "host.db.log", echo=None), port="sim",
                       db=str(tmp_path / "host.db"), status_every=0)

    async def run(st, until, limit_s=20.0):
        task = asyncio.ensure_future(st.run())
        end = time.monotonic() + limit_s
        while not until() and time.monotonic() < end:
            rt.step()
            await asyncio.sleep(0.002)
        st.stop()
        await task

    first = station()
    asyncio.run(run(first, lambda: rt.outbox.dead_letters()[0] == 1))
    count, (letter,) = rt.outbox.dead_letters()
    assert first.failure is None and count == 1 and letter.msg_id == mid
    assert letter.body in (hostile, None)  # kept when the refusal came before the acknowledgement
    assert [r.body for r in store.rejected()] == [hostile]
    assert mid not in [m for m, _ in rt.outbox.pending(100)]
    second = station()  # a restart: the refused message is not sent again, nothing crashes
    asyncio.run(run(second, lambda: False, limit_s=1.5))
    assert second.failure is None and len(store.rejected()) == 1
