"""A station in this process and a robot's link over a simulated cable: the robot's end sends
packets, answers the station's commands once each, and keeps what the station sent it."""
from __future__ import annotations

import asyncio
import json
import time

from radio import packets as pk
from radio.auth import MemoryCounterStore
from radio.channel import ChannelConfig
from radio.channel_port import Cable
from radio.link import Acked, Link
from radio.pump import LinkPump
from tools.station.log import StationLog
from tools.station.receiver import Receiver
from tools.station.station import Station
from tools.store.database import Store

KEY = bytes(range(32))


class Robot:
    """The robot's end of the cable: a link that sends packets and answers each command once, with
    a PING's answer (its clock)."""

    def __init__(self, end, key=KEY):
        self.pump = LinkPump(Link(1, 2, 1, key, MemoryCounterStore(), heartbeat=0.1, link_timeout=5.0), end)
        self.acked: set[int] = set()
        self.commands: list[pk.CommandPacket] = []
        self.extras: dict | None = None  # what its answers carry (default: a PING's answer, its clock)

    def turn(self):
        for ev in self.pump.step():
            if isinstance(ev, Acked):
                self.acked.add(ev.msg_id)
            elif hasattr(ev, "payload"):
                cmd = pk.decode(ev.payload)
                self.commands.append(cmd)
                if not isinstance(cmd, pk.CommandPacket):
                    continue  # the station's refusal of a message (a NACK): kept in `commands` for the tests
                if [c.command_id for c in self.commands].count(cmd.command_id) == 1:  # as the robot: once
                    extras = {"time": 1.7e9 + len(self.commands)} if self.extras is None else self.extras
                    self.pump.send(pk.encode(pk.AckPacket(cmd.command_id, cmd.name.name, extras)))


def station_on_cable(tmp_path, store=None, host_key=KEY, robot_key=KEY):
    cable = Cable(ChannelConfig(latency=0.0, bandwidth=1e7, buffer=1 << 20))
    store = store or Store.open(tmp_path / "host.db")
    pump = LinkPump(Link(2, 1, 1, host_key, MemoryCounterStore(), heartbeat=0.1, link_timeout=5.0), cable.ends[1])
    station = Station(pump, Receiver(store), StationLog(tmp_path / "host.db.log", echo=None),
                      port="sim", db=str(tmp_path / "host.db"), status_every=0)
    return station, Robot(cable.ends[0], robot_key), store


async def drive(station, robot, until, limit_s=20.0):
    """Run the station, turning the robot beside it, until `until()`."""
    task = asyncio.ensure_future(station.run())
    end = time.monotonic() + limit_s
    while not until() and not task.done() and time.monotonic() < end:
        robot.turn()
        await asyncio.sleep(0.002)
    station.stop()
    await task


def station_log(tmp_path):
    """The station's log file, its events as dicts."""
    return [json.loads(line) for line in (tmp_path / "host.db.log").read_text().splitlines()]
