"""The base station's receiving half: link events in, packets decoded and stored, answers out.

`Receiver` turns one delivered payload into a stored capture, mask or a line to show.
Storing happens before the link's next `poll`, so a packet is acknowledged only once it
is in the database; a crash in between makes the robot send it again, and the database
keeps it once because captures are unique by (robot, incarnation, sequence): the
incarnation is the robot state's id its link session named, so a robot whose state was
wiped numbers from 1 again without its new captures being taken for old ones. A store that
fails (a full disk, a damaged row) raises `StoreFailed` before anything is acknowledged.

A packet the station cannot use (it does not decode: some field is out of the schema; or the
store refuses a value) is refused: its raw bytes are kept in the database's rejected_packets for
a person, and the Item says so (`refusal`); whoever owns the link then tells the robot with a
NACK UNUSABLE naming the message (`refusal_body`), and the robot sets it aside.

`HostSession` turns the link (`radio.pump.LinkPump` over any pyserial URL, a pty fd or the
simulated radio): received payloads go to the Receiver, commands go out, and the robot's
ACK/NACK answers are collected by command id.
"""
from __future__ import annotations

import dataclasses
import enum
import os
import secrets
import sqlite3
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from btf.fit import space_choice
from btf.fit.features import PcaBasis
from radio import FrameError
from radio import packets as pk
from radio.link import Delivered, LinkDown, LinkStats, LinkUp, PeerStale
from radio.pump import LinkPump
from tools.analysis.radiometry import settings_json
from tools.store.database import CorruptDatabase, Store

HOST_NODE, ROBOT_NODE, LINK_ID = 2, 1, 1


class ItemKind(enum.StrEnum):
    CAPTURE = "capture"
    UNCHANGED = "unchanged"
    MASK = "mask"
    STATUS = "status"
    LOG = "log"
    ANSWER = "answer"
    BAD = "bad"
    LINK = "link"  # the link itself: its peer's frames all refused as stale
    OTHER = "other"


class StoreFailed(Exception):
    """A delivered packet could not be stored (a full disk, a damaged database): nothing of
    this turn is acknowledged; the robot keeps it and sends it again. One line."""

    def __init__(self, text: str, damaged: bool) -> None:
        super().__init__(text)
        self.damaged = damaged  # the database needs a person (exit 2), not just room (exit 1)


@dataclass(frozen=True, slots=True)
class Item:
    """What one delivered payload became."""

    kind: ItemKind
    robot: int | None
    seq: int | None
    stored: bool
    text: str
    packet: Any = field(default=None, compare=False, repr=False)
    incarnation: str = ""  # the robot state that sent it ("" when its session named none)
    msg_id: int | None = None  # the robot's message id (its outbox row)
    refusal: str = ""  # why the station refuses it ("" when it does not)
    size: int = 0  # bytes of the payload
    rejected: int | None = None  # its row in rejected_packets, when refused and kept

    def to_json(self) -> dict:
        d: dict[str, Any] = {"kind": self.kind.value, "robot": self.robot, "seq": self.seq,
                             "incarnation": self.incarnation, "stored": self.stored, "text": self.text}
        if self.packet is not None:
            d["packet"] = packet_json(self.packet)
        return d


def mask_key(seq: int, incarnation: str = "") -> str:
    """The key a capture's mask is stored under."""
    return f"capture-{seq}@{incarnation}" if incarnation else f"capture-{seq}"


def _free(path: Any) -> str:
    try:
        st = os.statvfs(os.path.dirname(os.path.abspath(path)))
    except OSError:
        return "unknown bytes"
    return f"{st.f_bavail * st.f_frsize} bytes"


def _jsonable(v: Any) -> Any:
    if isinstance(v, (bytes, bytearray)):
        return v.hex()
    if isinstance(v, enum.Enum):
        return v.name
    if isinstance(v, pk.Kept):
        return {"items": _jsonable(v.items), "left_out": v.left_out}
    if dataclasses.is_dataclass(v) and not isinstance(v, type):  # a typed record (a STATUS report)
        return {f.name: _jsonable(getattr(v, f.name)) for f in dataclasses.fields(v) if getattr(v, f.name) is not None}
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, (np.integer, np.floating)):
        return v.item()
    return v


def packet_json(p: Any) -> dict:
    """A decoded packet as a JSON-ready dict (documented in the README under `decode`)."""
    out: dict[str, Any] = {"type": p.KIND.name}
    if isinstance(p, pk.ModelsPacket):
        out.update(robot=p.robot_id, seq=p.seq, time=p.time, commanded=list(p.commanded),
                   measured=list(p.measured), space=p.feature_space, bands=list(p.bands),
                   levels=p.levels, models=[
                       {"label": lab, "band": b, "family": m.family.value, "gamma": m.gamma,
                        "delta": m.delta, "xi": m.xi, "lam": m.lam}
                       for (lab, b), m in sorted(p.models.items())],
                   counts={str(r.label): r.count for r in p.labels}, camera=settings_json(p.camera))
    elif isinstance(p, pk.MaskPacket):
        out.update(robot=p.robot_id, seq=p.seq, frame_shape=list(p.frame_shape), shape=list(p.shape),
                   labels=sorted(int(v) for v in set(p.values)))
    else:
        for name in p.__slots__:
            if name != "extras":
                out[name] = _jsonable(getattr(p, name))
    if getattr(p, "extras", None):
        out["extras"] = _jsonable(dict(p.extras))
    return out


class Receiver:
    """Decodes delivered payloads and files them in `store` (None: show only); counts what it saw."""

    def __init__(self, store: Store | None, scene: str = "") -> None:
        self.store, self.scene = store, scene
        self.counts: dict[str, int] = {k.value: 0 for k in ItemKind}
        self.duplicates = 0
        # A malformed PCA basis in the extras: the capture is stored without it. (Dependence is
        # part of the MODELS blob: a bad record makes the whole packet undecodable.)
        self.rejected_extras = 0
        self.refused = 0  # messages refused (and kept in rejected_packets)

    def handle(self, payload: bytes, incarnation: str = "", msg_id: int | None = None,
               sender: int | None = None) -> Item:
        """What `payload` (message `msg_id` of node `sender`) became, stored under `incarnation`
        (the sending robot state's id, hex). StoreFailed when the database cannot take it (the
        caller must not acknowledge it)."""
        try:
            p = pk.decode(payload)
        except FrameError as exc:
            return self.refuse(payload, incarnation, msg_id, sender, f"undecodable packet: {exc}")
        try:
            item = self._stored(lambda: self._file(p, incarnation), f"{p.KIND.name} of robot {getattr(p, 'robot_id', '?')}")
        except (ValueError, TypeError, OverflowError, ArithmeticError) as exc:  # a value the store refuses
            return self.refuse(payload, incarnation, msg_id, sender, f"{p.KIND.name} not stored: {exc}", p)
        return self._count(dataclasses.replace(item, incarnation=incarnation, msg_id=msg_id, size=len(payload)))

    def refuse(self, payload: bytes, incarnation: str, msg_id: int | None, sender: int | None, reason: str,
               packet: Any = None) -> Item:
        """A message the station cannot use: its raw bytes kept for a person (when there is a
        database), counted, and an Item whose `refusal` says why."""
        row = None
        if self.store is not None:
            row = self._stored(lambda: self.store.add_rejected(time.time(), sender, incarnation, msg_id, reason,
                                                               bytes(payload)), "a refused packet")
        self.refused += 1
        robot = getattr(packet, "robot_id", None)
        return self._count(Item(ItemKind.BAD, robot, getattr(packet, "seq", None), False, reason, packet, incarnation,
                                msg_id=msg_id, refusal=reason, size=len(payload), rejected=row))

    def _stored(self, write: Any, what: str) -> Any:
        """write(), or StoreFailed when the database cannot take it."""
        try:
            return write()
        except CorruptDatabase as exc:
            raise StoreFailed(f"{exc}: repair it or receive into another database", damaged=True) from None
        except sqlite3.Error as exc:
            name = getattr(exc, "sqlite_errorname", "") or ""
            raise StoreFailed(f"database {self.store.path}: cannot store {what}: {exc} "
                              f"({_free(self.store.path)} free on its disk)",
                              damaged=name.startswith(("SQLITE_CORRUPT", "SQLITE_NOTADB"))) from None

    def _file(self, p: Any, incarnation: str) -> Item:
        if self.store is None and isinstance(p, (pk.ModelsPacket, pk.UnchangedPacket, pk.MaskPacket)):
            return Item(ItemKind.OTHER, getattr(p, "robot_id", None), getattr(p, "seq", None), False,
                        f"{p.KIND.name} not stored (no database)", p)
        if isinstance(p, pk.ModelsPacket):
            return self._models(p, incarnation)
        if isinstance(p, pk.UnchangedPacket):
            return self._unchanged(p, incarnation)
        if isinstance(p, pk.MaskPacket):
            labels = p.full_size()
            new = self.store.add_mask(mask_key(p.seq, incarnation), labels, str(p.robot_id))
            return Item(ItemKind.MASK, p.robot_id, p.seq, new,
                        f"mask {p.frame_shape[1]}x{p.frame_shape[0]} labels "
                        f"{sorted(int(v) for v in set(p.values))}", p)
        if isinstance(p, pk.StatusPacket):
            pose = "?" if p.pose is None else f"{p.pose[0]:.1f}/{p.pose[1]:.1f}"
            return Item(ItemKind.STATUS, p.robot_id, p.last_seq, False,
                        f"{p.state.name.lower()} pose {pose} outbox {p.outbox_pending}: {p.text}", p)
        if isinstance(p, pk.LogPacket):
            return Item(ItemKind.LOG, p.robot_id, None, False, f"{p.level.name}: {p.text}", p)
        if isinstance(p, (pk.AckPacket, pk.NackPacket)):
            verdict = "ACK" if isinstance(p, pk.AckPacket) else f"NACK {p.reason.name}"
            return Item(ItemKind.ANSWER, None, p.command_id, False, f"{verdict}: {p.text}", p)
        return Item(ItemKind.OTHER, None, None, False, type(p).__name__, p)

    def _count(self, item: Item) -> Item:
        self.counts[item.kind.value] += 1
        if item.kind in (ItemKind.CAPTURE, ItemKind.UNCHANGED, ItemKind.MASK) and not item.stored:
            self.duplicates += 1
        return item

    def _models(self, p: pk.ModelsPacket, incarnation: str) -> Item:
        fits = dict(p.fits)  # the records as decoded: nothing re-derived here
        notes = []
        dependence = dict(p.dependence)
        pca = None
        try:
            pca = PcaBasis.from_extras(dict(p.extras))
        except ValueError as exc:
            self.rejected_extras += 1
            notes.append(f"PCA basis rejected: {exc}")
        new = self.store.add_capture(str(p.robot_id), p.seq, p.time, p.commanded, p.measured,
                                     p.feature_space, p.bands, fits, scene=self.scene,
                                     dependence=dependence, pca=pca, levels=p.levels, camera=p.camera,
                                     incarnation=incarnation)
        if p.camera is not None and p.camera.unlocked:
            notes.append("taken with the camera NOT locked")
        chosen = p.extras.get(space_choice.EXTRA_KEY)
        if new and isinstance(chosen, str) and chosen:
            self.store.add_space_choice(str(p.robot_id), p.seq, chosen, incarnation)
            notes.append(f"feature space {p.feature_space} chosen automatically")
        extra = "".join(f"; {n}" for n in notes)
        return Item(ItemKind.CAPTURE, p.robot_id, p.seq, new,
                    f"capture at {p.measured[0]:.1f}° ({len(p.labels)} regions, {len(p.bands)} bands"
                    f"{', dependence' if dependence else ''}{', PCA basis' if pca else ''}){extra}", p)

    def _unchanged(self, p: pk.UnchangedPacket, incarnation: str) -> Item:
        ref = self.store.capture_by_seq(str(p.robot_id), p.ref_seq, incarnation)
        if ref is None:
            return Item(ItemKind.UNCHANGED, p.robot_id, p.seq, False,
                        f"unchanged marker refers to capture {p.ref_seq}, which is not stored", p)
        fits = self.store.models(ref.id)
        # The marker stands for the reference's whole model: its dependence and basis too.
        basis = self.store.pca_basis(ref.id)
        new = self.store.add_capture(str(p.robot_id), p.seq, p.time, p.commanded, p.measured,
                                     ref.space, ref.band_names, fits, scene=ref.scene,
                                     dependence=self.store.dependence(ref.id), pca=basis, levels=ref.levels,
                                     camera=ref.camera, incarnation=incarnation)
        return Item(ItemKind.UNCHANGED, p.robot_id, p.seq, new,
                    f"unchanged at {p.measured[0]:.1f}°: models of capture {p.ref_seq}", p)


def refusal_body(item: Item) -> bytes:
    """The NACK that tells the robot its message `item.msg_id` is refused: it sets it aside."""
    return pk.encode(pk.NackPacket(0, pk.Reason.UNUSABLE, item.refusal, msg_id=item.msg_id))


class HostSession:
    """The host's end of the link: a `LinkPump` feeding a Receiver; commands go out and the
    robot's ACK/NACK answers are collected by command id. A packet the Receiver cannot store
    raises StoreFailed out of `step` before the link writes: nothing unstored is acknowledged,
    and the session must not be stepped again (its link counts the packet delivered)."""

    def __init__(self, pump: LinkPump, receiver: Receiver) -> None:
        self.pump, self.receiver = pump, receiver
        self.answers: dict[int, Item] = {}
        self.last_delivery = pump.clock()
        self.up = False

    def step(self) -> list[Item]:
        """One turn: what arrived is stored, then the link writes (so the ACK of a packet
        leaves only once it is in the database)."""
        items = []
        for ev in self.pump.read():
            if isinstance(ev, Delivered):
                item = self.receiver.handle(ev.payload, ev.incarnation.hex(), ev.msg_id, ev.sender)
                if item.refusal and item.msg_id is not None:
                    self.pump.send(refusal_body(item))
                self.last_delivery = self.pump.clock()
                if item.kind is ItemKind.ANSWER and item.seq is not None:
                    self.answers[item.seq] = item
                items.append(item)
            elif isinstance(ev, (LinkUp, LinkDown)):
                self.up = isinstance(ev, LinkUp)
            elif isinstance(ev, PeerStale):
                items.append(Item(ItemKind.LINK, ev.sender, None, False, ev.text))
        self.pump.write()
        return items

    def command(self, name: pk.CommandName, args: dict | None = None) -> int:
        """Queue one command; returns its id (the robot's ACK/NACK lands in `answers`)."""
        cid = secrets.randbits(31)
        self.pump.send(pk.encode(pk.CommandPacket(cid, name, dict(args or {}))))
        return cid

    def stats(self) -> LinkStats:
        return self.pump.stats()

    def close(self) -> None:
        self.pump.close()
