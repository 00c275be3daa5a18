"""Fake robot runtimes over the in-memory link, and what a test reads of what they sent."""
from __future__ import annotations

from radio import packets as pk
from tests.support.robots import robot_toml


def runtime_toml(scene: str = "mixed", rate: float = 0.0, *changes: dict) -> str:
    """A fake robot on `scene` at 60 x 80 with fault rate `rate` (seeded), and `changes`."""
    return robot_toml({"hal": {"scene": scene, "size": [60, 80], "fault_rate": rate, "fault_seed": 3}}, *changes)


def make(fake_robot, scene="mixed", rate=0.0, extra: dict | tuple = (), **kw):
    """A fake robot on `scene` (fault rate `rate`, more config in `extra`: one change or several)."""
    changes = (extra,) if isinstance(extra, dict) else tuple(extra)
    return fake_robot(runtime_toml(scene, rate, *changes), **kw)


def sweep(rt):
    return rt.run(lambda r: r.progress is not None and r.idle())


def decoded(tr):
    return [pk.decode(body) for _, body in tr.sent]


def replies(tr):
    return {p.command_id: p for p in decoded(tr) if isinstance(p, (pk.AckPacket, pk.NackPacket))}


def host_view(*transports):
    """What a host keeps: packets by (kind, seq), each stored once whatever was re-sent."""
    kept = {}
    for tr in transports:
        for p in decoded(tr):
            if isinstance(p, (pk.ModelsPacket, pk.UnchangedPacket, pk.MaskPacket)):
                kept[(type(p).__name__, p.seq)] = p
    return kept


def poses_by_seq(kept):
    return sorted((round(p.commanded[0]), p.seq) for (kind, _), p in kept.items() if kind == "ModelsPacket")


PLAN3 = {"sweep": {"start": 90, "stop": 70, "step": 10}}  # three poses
