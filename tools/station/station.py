"""The station: the one process that owns the radio (`btf-host station`; `listen` is it in the
foreground, and `cmd` without a station runs one for its command's length).

It holds the port for as long as it runs, stores every packet before its acknowledgement
leaves (the only owner of the `Receiver` and its `Store`), keeps the link's counters, and
serves everyone else who wants the link: `cmd` clients and status subscribers over the control
socket (`tools.station.control`), and, inside the same event loop, the operator's page.

One asyncio event loop runs it all. The link pump (`run`) turns a `radio.pump.LinkPump` with the
port on a thread of its own, so the loop never waits on the port: `LinkPump.transfer` (write
what is due, read what arrived) runs there; on the loop, what arrived is fed to the link and
every delivered packet is stored (`LinkPump.feed`), and only then is the next write taken
(`LinkPump.due`): an acknowledgement never leaves before its packet is on stable storage (the
turn's packets in one transaction, its commit fsync'd: synchronous=FULL, one fsync a turn). The
`Link`, the `Store`, the snapshot and the bus are touched on the loop only.

The interface for code inside the station (the control socket, the operator's page):

- `station.snapshot_json() -> dict`: `tools.station.snapshot.StationSnapshot.to_json`, every
  field named there: `station` (port, db, started, clients, subscribers, commands_pending),
  `link` (up, changed, last_heard, last_heard_s, and `radio.events.LinkStats`: frames_sent,
  frames_accepted, retransmissions, delivered, duplicates, rejected {reason: n}, ...;
  delivered_bytes, goodput_bps), `robot` (id, mode, state, pose, commanded, outbox, paused,
  torque, faults, errors, left_out (how many older faults and errors the robot's report left
  out), dead_letters (its messages this station refused: count, latest), failsafe, failsafe_s,
  failsafe_assumed, disk, disk_free, rejected, last_status), `sweep` (id, plan, next, poses,
  active, measured, skipped [{index, elevation, azimuth, reason}], grid:
  `tools.station.sweep_grid.grid_json`) and `captures` (stored, duplicates, masks, bad: the
  messages refused, latest [...]).
- `sub = station.bus.subscribe(maxsize)`, then `await sub.get()`: every event in order; a
  subscriber that falls behind loses the oldest and is told how many (`tools.station.bus`).
  `sub.close()` when done.
- `cid, answer = station.submit(name, args, command_id)`: the command goes to the robot at
  the next turn; `await answer` gives its ACK or NACK as a dict (`{"command_id", "ok",
  "type": "ACK"|"NACK", "text", "reason"?, "extras"?, "status"?}`), once, however often the robot
  says it.
  A command id the robot saw before is answered from its memory, never run twice, so a client
  that lost its station re-submits the same id to the next one.
- `station.stop()` ends `run` after the current turn; `station.failure` says why it ended on
  its own (`StationFailure`: a store that cannot be written, a port that failed; never a frame
  or a client: those are counted, said and refused). `station.wrong_key` is the one line
  saying the key is likely wrong, while it is.

Every event is a typed record, one declaration per kind (`tools.station.events`: capture,
unchanged, mask, status, failsafe, log, other, bad, command, answer, link, rejected, station,
lost), published on the bus, written by the log (`tools.station.log`) and rendered by `watch`
and the page from its declaration.

No packet ends the station: every field of a delivered packet is checked as it is decoded, and
one the station cannot use (undecodable, refused by the store, or one whose handling failed) is
kept raw in the database's rejected_packets, counted, logged as a `bad` event, and refused to
the robot with a NACK UNUSABLE naming the message, which the robot sets aside for good. No frame
ends it either (`tools.station.rejected_frames`): refused frames are `rejected` events with
their likely cause, a likely wrong key in one line of its own, and the robot's frames of its
session with the previous station, right after a start, the re-sync the first link-up says.
"""
from __future__ import annotations

import asyncio
import secrets
import sqlite3
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any, Callable, Iterator

from radio import packets as pk
from radio.link import Delivered, LinkDown, LinkUp, PeerStale, QueueFull
from radio.packets.base import clock_time
from radio.packets.commands import CommandName, check_args
from radio.pump import LinkPump
from tools.station import events as ev_
from tools.station.bus import EventBus
from tools.station.log import StationLog
from tools.station.receiver import Item, ItemKind, Receiver, StoreFailed, packet_json, refusal_body
from tools.station.rejected_frames import RejectedFrames
from tools.station.snapshot import StationSnapshot
from tools.store.database import disk_free

SENT_KEPT = 1024  # commands remembered until answered (for the snapshot)
POLLS_KEPT = 16  # the station's own STATUS requests it recognises the answers of


def empty(value: Any) -> bool:
    """An answer's value not worth a word: '', None, an empty list or mapping."""
    return value is None or (isinstance(value, (str, list, tuple, dict)) and not value)


class StationFailure(Exception):
    """The station cannot go on; `status` is the exit status its CLI gives (2: fix the setup)."""

    def __init__(self, text: str, status: int = 1) -> None:
        super().__init__(text)
        self.status = status


class Station:
    def __init__(self, pump: LinkPump, receiver: Receiver, log: StationLog, *, port: str, db: str,
                 status_every: float = 10.0, on_item: Callable[[Item], None] | None = None,
                 clock: Callable[[], float] = time.monotonic, wall: Callable[[], float] = time.time) -> None:
        self.pump, self.receiver, self.log = pump, receiver, log
        self.clock, self.wall = clock, wall
        self.status_every, self.on_item = status_every, on_item
        self.bus = EventBus()
        self.snapshot = StationSnapshot(port, db, wall())
        self.failure: StationFailure | None = None
        self.last_delivery = clock()
        self._stop = False
        self._waiting: dict[int, list[asyncio.Future]] = {}
        self._sent: dict[int, tuple[CommandName, dict]] = {}
        self._poll: tuple[int, float] | None = None  # the STATUS this station asked for, and when
        self._polls: deque[int] = deque(maxlen=POLLS_KEPT)  # its earlier ones: answered late, still its own
        self.rejected_frames = RejectedFrames(wall())  # what the link refused, said
        self._held: list[tuple[ev_.Event, bool]] | None = None  # events said once the turn's commit is done
        self._told_wrong_key = False
        self._accepted = 0
        self._polled_at = -1e9
        self.refused = 0  # the robot's messages this station refused (and told it so)
        self.faults = 0  # of them, those whose handling failed here (a fault of the station's own)

    # -- the interface -------------------------------------------------------------------------
    def snapshot_json(self) -> dict:
        s = self.snapshot
        s.commands_pending, s.subscribers = sum(map(len, self._waiting.values())), self.bus.subscribers
        return s.to_json(self.wall())

    def submit(self, name: CommandName, args: dict, command_id: int | None = None) -> tuple[int, asyncio.Future]:
        """Queue a command for the robot; (its id, a future of its answer). ValueError for
        arguments the robot would refuse to decode, or when the link holds too much already."""
        cid = secrets.randbits(31) if command_id is None else command_id
        try:
            check_args(name, args)
            body = pk.encode(pk.CommandPacket(cid, name, args))
        except Exception as exc:  # FrameError, or an id outside the packet's range
            raise ValueError(f"{name.name}: {exc}") from None
        fut = asyncio.get_running_loop().create_future()
        self.pump.send(body)  # QueueFull (a RuntimeError) when the link holds 1 MB unacknowledged
        self._waiting.setdefault(cid, []).append(fut)
        self._sent[cid] = (name, dict(args))
        while len(self._sent) > SENT_KEPT:
            del self._sent[next(iter(self._sent))]
        fut.add_done_callback(lambda f, cid=cid: self._forget(cid, f))
        said = " ".join(f"{k}={v}" for k, v in args.items())
        self.emit(ev_.CommandEvent(self.wall(), f"{name.name} {said}".strip() + f" sent (command {cid})",
                                   command_id=cid, name=name.name, args=packet_json_args(args)))
        return cid, fut

    def stop(self) -> None:
        self._stop = True

    def emit(self, ev: ev_.Event, logged: bool = True) -> None:
        """Log an event and publish it to every subscriber (inside a turn's commit: once it is done)."""
        if self._held is not None:
            self._held.append((ev, logged))
            return
        if logged:
            self.log.write(ev)
        self.bus.publish(ev)

    # -- the pump ------------------------------------------------------------------------------
    async def run(self) -> None:
        """Turn the link until `stop()`; StationFailure when it cannot go on (nothing unstored
        is ever acknowledged: a failed store ends the turn before its write)."""
        loop = asyncio.get_running_loop()
        io = ThreadPoolExecutor(1, thread_name_prefix="station-port")
        self.last_delivery = self.clock()  # idle from here: a slow start is not time without packets
        self.emit(ev_.StationEvent(self.wall(), f"started: port {self.snapshot.port}, database {self.snapshot.db}"))
        out = b""
        try:
            while not self._stop:
                try:
                    data, room = await loop.run_in_executor(io, self.pump.transfer, out)
                except Exception as exc:
                    raise StationFailure(f"port {self.snapshot.port}: {type(exc).__name__}: {exc}") from None
                try:
                    out = self._turn(data, room)
                except StationFailure:
                    raise
                except StoreFailed as exc:  # no room (1: run it again), or a damaged row (2)
                    raise StationFailure(f"{exc}; nothing unstored was acknowledged (the robot keeps it)",
                                         status=2 if exc.damaged else 1) from None
                except Exception as exc:  # the store: nothing of this turn is acknowledged
                    raise StationFailure(f"database {self.snapshot.db}: {type(exc).__name__}: {exc}") from None
            if out and self.failure is None:  # the acknowledgements of the last turn
                await loop.run_in_executor(io, self.pump.port.write, out)
        except StationFailure as exc:
            self.failure = exc
        finally:
            for futs in self._waiting.values():
                for f in futs:
                    f.cancel()
            await loop.run_in_executor(io, self.pump.close)
            io.shutdown()
            text = f"failed: {self.failure}" if self.failure else "stopped"
            self.emit(ev_.StationEvent(self.wall(), text, failed=self.failure is not None))

    def _turn(self, data: bytes, room: int) -> bytes:
        """Feed the link what arrived, store and route what it delivered; what to write next."""
        now, wall = self.clock(), self.wall()
        events = self.pump.feed(data, now)
        with self._one_commit(any(isinstance(ev, Delivered) for ev in events)):
            self._route(events, now, wall)
        self._watch_link(wall)
        self._ask_status(now)
        return self.pump.due(room, now)

    @contextmanager
    def _one_commit(self, storing: bool) -> Iterator[None]:
        """The turn's writes in one transaction: one commit, one fsync (synchronous=FULL), however
        many packets it delivered, before `due` lets their acknowledgements out; its events are said
        once the commit is on disk (none when it fails: StoreFailed, nothing of the turn kept)."""
        store = self.receiver.store
        if not storing or store is None:
            yield
            return
        self._held = []
        try:
            with store.batch():
                yield
        except sqlite3.Error as exc:  # the commit itself: no room for the WAL, an I/O error
            name = getattr(exc, "sqlite_errorname", "") or ""
            raise StoreFailed(f"database {store.path}: cannot commit this turn's packets: {exc} "
                              f"({disk_free(store.path)} free on its disk)",
                              damaged=name.startswith(("SQLITE_CORRUPT", "SQLITE_NOTADB"))) from None
        finally:
            held, self._held = self._held, None
        for ev, logged in held:
            self.emit(ev, logged)

    def _route(self, events: list, now: float, wall: float) -> None:
        """Each of the link's events of this turn: a delivery stored and routed, the link's state said."""
        for ev in events:
            if isinstance(ev, Delivered):
                self.last_delivery = now
                self.snapshot.note_delivered(len(ev.payload), wall)
                self._handle(ev, wall)
            elif isinstance(ev, (LinkUp, LinkDown)):
                up = isinstance(ev, LinkUp)
                self.snapshot.note_link(up, wall)
                resync = self.rejected_frames.link_up(self.pump.stats(), wall) if up else ""
                self.emit(ev_.LinkEvent(wall, f"up: the robot is heard{resync}" if up else
                                        f"down: nothing heard from the robot for {self.pump.link.link_timeout:g} s",
                                        up=up))
            elif isinstance(ev, PeerStale):  # the robot's counters are behind: said once, with the remedy
                self.emit(ev_.LinkEvent(wall, ev.text, up=self.pump.up, stale=True))
                if self.on_item is not None:
                    self.on_item(Item(ItemKind.LINK, ev.sender, None, False, ev.text))

    def _handle(self, ev: Delivered, wall: float) -> None:
        """Store and route one delivered message; one the station cannot use is refused (StoreFailed
        alone ends the turn: nothing of it is acknowledged)."""
        item = self.receiver.handle(ev.payload, ev.incarnation.hex(), ev.msg_id, ev.sender)
        try:
            self._delivered(item, wall)
        except (StoreFailed, StationFailure):
            raise
        except Exception as exc:  # a packet that passed every check still failed here: refuse it
            self.faults += 1
            item = self.receiver.refuse(ev.payload, ev.incarnation.hex(), ev.msg_id, ev.sender,
                                        f"the station could not handle {item.kind.value}: {type(exc).__name__}: {exc}")
            self._delivered(item, wall)

    def _delivered(self, item: Item, wall: float) -> None:
        if self.on_item is not None:
            self.on_item(item)
        if item.kind is ItemKind.ANSWER:
            self._answer(item.packet, wall)
            return
        s = self.snapshot
        if item.kind is ItemKind.BAD:
            s.counts["bad"] += 1
            self.emit(self._refuse(item, wall))
            return
        base = dict(robot=item.robot, seq=item.seq, stored=item.stored)
        if item.kind in (ItemKind.CAPTURE, ItemKind.UNCHANGED, ItemKind.MASK):
            # the models stay in the database: the event says what was filed where
            text = f"robot {item.robot} seq {item.seq}: {item.text}" + ("" if item.stored else " (already stored)")
            if item.kind is ItemKind.MASK:
                s.counts["masks"] += 1
                self.emit(ev_.MaskEvent(wall, text, **base))
                return
            s.note_capture(item, wall)
            kind = ev_.CaptureEvent if item.kind is ItemKind.CAPTURE else ev_.UnchangedEvent
            self.emit(kind(wall, text, **base, capture=s.latest[0]))
            return
        packet = None if item.packet is None else packet_json(item.packet)
        if item.kind is ItemKind.STATUS:
            s.note_status(item.packet, wall)
            failsafe = item.packet.report.failsafe is not None and item.packet.text.startswith("failsafe")
            self.emit((ev_.FailsafeReport if failsafe else ev_.StatusEvent)(wall, item.text, **base, packet=packet))
        else:
            self.emit((ev_.LogEvent if item.kind is ItemKind.LOG else ev_.OtherEvent)(
                wall, item.text, **base, packet=packet))

    def _refuse(self, item: Item, wall: float) -> ev_.RefusedEvent:
        """Tell the robot its message `item.msg_id` is refused (it sets it aside); the event saying so."""
        told = False
        self.refused += 1
        if item.msg_id is not None:
            try:
                self.pump.send(refusal_body(item))
                told = True
            except (QueueFull, ValueError):  # the link holds too much: the robot deletes it on the ACK alone
                pass
        said = f"message {item.msg_id} of robot {item.robot if item.robot is not None else '?'} refused: {item.text}"
        return ev_.RefusedEvent(wall, said + ("" if told else " (the robot was not told)"), robot=item.robot,
                                seq=item.seq, msg_id=item.msg_id, reason=item.refusal, size=item.size,
                                rejected=item.rejected, told=told)

    def _answer(self, p: Any, wall: float) -> None:
        cid, ok = p.command_id, isinstance(p, pk.AckPacket)
        answer = {"command_id": cid, "ok": ok, **packet_json(p)}
        name, args = self._sent.pop(cid, (None, {}))
        if ok and (name is None or p.name is name) and p.name is not None:
            # the answer's values are those the command table declares for the command it names
            self.snapshot.note_answer(p.name, dict(p.extras), args if name is not None else None)
            if p.name is CommandName.SWEEP:
                self.snapshot.note_sweep_started(packet_json_args(args), dict(p.extras))
            elif p.name is CommandName.STATUS and p.status is not None:
                self.snapshot.note_status_answer(p.status, wall)
        futures = self._waiting.pop(cid, [])
        for f in futures:
            if not f.done():
                f.set_result(answer)
        if cid in self._polls:
            if self._poll is not None and cid == self._poll[0]:
                self._poll = None
            self.emit(ev_.StatusEvent(wall, "the robot's report", packet=answer, poll=True), logged=False)
            return
        said = " ".join(f"{k}={_value(k, v)}" for k, v in p.extras.items()
                        if not empty(v))  # "paused=" says nothing: a field left empty is left out
        said = said if len(said) <= 160 else said[:157] + "..."
        verdict = f"ACK {said}".strip() if ok else f"NACK {p.reason.name}: {p.text}"
        named = name or (p.name if ok else None)
        label = named.name if named is not None else f"command {cid}"
        self.emit(ev_.AnswerEvent(wall, f"{label} (command {cid}): {verdict}"
                                  + ("" if futures else " (no client waits for it)"),
                                  command_id=cid, ok=ok, answer=answer))

    def _forget(self, cid: int, fut: asyncio.Future) -> None:
        futs = self._waiting.get(cid)
        if futs and fut in futs:
            futs.remove(fut)
            if not futs:
                del self._waiting[cid]

    @property
    def wrong_key(self) -> str:
        """The line saying the key is likely wrong, while frames fail authentication and none
        passed ('' otherwise). Never a reason to stop: anyone on the radio can send such frames."""
        return self.rejected_frames.wrong_key(self.pump.stats())

    def _watch_link(self, wall: float) -> None:
        """Quality counters from the link; refused frames with their likely cause (a wrong key
        in one line, the re-sync after a start as such): counted, said, never the end."""
        st = self.pump.stats()
        self.snapshot.link.stats = self.rejected_frames.view(st)
        if st.frames_accepted > self._accepted:
            self._accepted, self.snapshot.link.last_heard = st.frames_accepted, wall
        for text, fields in self.rejected_frames.update(st, wall):
            self.emit(ev_.RejectedEvent(wall, text, **fields))
            if fields.get("wrong_key") and not self._told_wrong_key and self.on_item is not None:
                self._told_wrong_key = True  # the foreground's reader is told once, the log each time
                self.on_item(Item(ItemKind.LINK, None, None, False, text))

    def _ask_status(self, now: float) -> None:
        """A STATUS every `status_every` seconds while the link is up, for the snapshot."""
        if not self.status_every or not self.pump.up:
            return
        if self._poll is not None and now - self._poll[1] < 3 * self.status_every:
            return
        if self._poll is None and now - self._polled_at < self.status_every:
            return
        cid = secrets.randbits(31)
        self.pump.send(pk.encode(pk.CommandPacket(cid, CommandName.STATUS, {})))
        self._poll, self._polled_at = (cid, now), now
        self._polls.append(cid)


def packet_json_args(args: dict) -> dict:
    """Command arguments as JSON (tuples as lists)."""
    return {k: list(v) if isinstance(v, tuple) else v for k, v in args.items()}


def _value(key: str, v: object) -> object:
    """An answer's value in the log: the robot's clock as a time, other floats short."""
    said = clock_time(v) if key == "time" else None
    return said if said is not None else f"{v:.6g}" if isinstance(v, float) else v
