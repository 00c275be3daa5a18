"""Hostile packets that mostly still decode: each field of a kind is drawn from its declaration
(`radio.packets.schema`), most often a value its type accepts (its bounds included), sometimes
one it must refuse (a wrong type, a bound crossed, NaN, a huge time, nested junk); nested STATUS
records and command answers the same way, and extras full of the keys older stations read.
MODELS and MASK start from valid bodies (their blobs), their header fields drawn the same way.
`rng` is a random.Random: seeded for the long loops, hypothesis's own for property tests."""
from __future__ import annotations

import random
import string
from typing import Any

import msgpack
import numpy as np

from btf.fit.fitter import fit_histogram
from radio import packets as pk
from radio.packets import schema as sc
from radio.packets.command import Arguments
from radio.packets.commands import COMMANDS

VALID_P = 0.9  # a field drawn inside its type
NESTED_VALID_P = 0.98  # a nested record's field
JUNK = (None, True, False, 0, -1, 2**31, 2**63 - 1, 2**64 - 1, -2**63, 1e308, -1e308, float("nan"), float("inf"),
        float("-inf"), -0.0, 1e18, 2.0**40, "", "abc", "x" * 511, "bell\x07", "\u2028", b"", b"\x00" * 9,
        [], [1, 2], [[1], "x"], {}, {1: 2}, {"a": [1, {"b": None}]}, {"sweep": "abc"})
# What older stations and robots named in STATUS extras: the keys a careless reader trusts.
LEGACY_KEYS = ("mode", "sweep", "skipped_index", "skipped_elevation", "skipped_azimuth", "measured", "skipped",
               "disk", "disk_free", "camera", "sweep_state", "failsafe_since", "failsafe_s", "plan", "next",
               "poses", "rejected", "faults", "errors", "time", "elevation", "azimuth", "seq", "torque")
TEXT = string.ascii_letters + string.digits + " .:/-_@°äé€中"


def _text(rng: random.Random, most: int) -> str:
    n = rng.choice((0, 1, most, rng.randint(0, min(most, 40))))
    return "".join(rng.choice(TEXT) for _ in range(n))


def valid(t: sc.FieldType, rng: random.Random, depth: int = 0) -> Any:
    """A wire value `t` accepts (edges included)."""
    if isinstance(t, sc.Int):
        return rng.choice((t.lo, t.hi, rng.randint(t.lo, t.hi), min(t.hi, max(t.lo, rng.randint(0, 9)))))
    if isinstance(t, sc.Float):
        return rng.choice((float(t.lo), float(t.hi), rng.uniform(t.lo, t.hi), min(t.hi, max(t.lo, 0.0))))
    if isinstance(t, sc.Text):
        text = t.fit(_text(rng, t.most))  # within its characters and the unpacker's bytes
        return text or ("x" if not t.empty else "")
    if isinstance(t, sc.Word):
        return rng.choice(t.words)
    if isinstance(t, sc.Flag):
        return rng.random() < 0.5
    if isinstance(t, sc.Choice):
        return int(rng.choice(list(t.enum_type)))
    if isinstance(t, sc.Bin):
        return bytes(rng.randrange(256) for _ in range(rng.randint(0, 24)))
    if isinstance(t, sc.Angles):
        if t.optional and rng.random() < 0.3:
            return [None, None]
        return [rng.choice((-9000, 9000, rng.randint(-9000, 9000))), rng.choice((0, 35999, rng.randint(0, 35999)))]
    if isinstance(t, sc.Maybe):
        return None if rng.random() < 0.3 else valid(t.inner, rng, depth)
    if isinstance(t, sc.ListOf):
        return [valid(t.item, rng, depth + 1) for _ in range(rng.randint(t.least, min(t.most, t.least + 4)))]
    if isinstance(t, sc.Latest):
        n = rng.choice((0, 1, t.most, rng.randint(0, t.most)))
        return [[valid(t.item, rng, depth + 1) for _ in range(n)], rng.choice((0, 1, 2**32 - 1))]
    if isinstance(t, sc.Record):
        return record(t.cls, rng, depth)
    if isinstance(t, Arguments):
        return {}
    raise TypeError(f"no draw for {t!r}")


def hostile(t: sc.FieldType, rng: random.Random) -> Any:
    """A wire value `t` should refuse, most often (a bound crossed, a wrong type, junk)."""
    crossed = []
    if isinstance(t, (sc.Int, sc.Float)):
        crossed = [t.lo - 1, t.hi + 1, t.hi * 10 + 7, -t.hi - 1]
    elif isinstance(t, sc.Text):
        crossed = ["y" * (t.most + 1)]
    elif isinstance(t, sc.Latest):
        crossed = [[[None] * (t.most + 1), 0], [[], -1]]
    return rng.choice(crossed + list(JUNK)) if crossed and rng.random() < 0.5 else rng.choice(JUNK)


def draw(t: sc.FieldType, rng: random.Random, depth: int = 0) -> Any:
    """Mostly valid (nested fields more so, or few nested records would decode), else hostile."""
    p = VALID_P if depth == 0 else NESTED_VALID_P
    return valid(t, rng, depth) if rng.random() < p or depth > 4 else hostile(t, rng)


def record(cls: type, rng: random.Random, depth: int = 0) -> dict:
    """A record's tagged map: its required fields and some of the others, now and then a stray tag."""
    out = {}
    for f in sc.layout(cls):
        if not isinstance(f.type, sc.Maybe) or rng.random() < 0.6:
            out[f.tag] = draw(f.type, rng, depth + 1)
    if rng.random() < 0.03:
        out[rng.choice((99, -1, "mode", 0))] = rng.choice(JUNK)
    return out


def extras(rng: random.Random) -> dict:
    keys = rng.sample(LEGACY_KEYS, rng.randint(0, 6))
    return {k: rng.choice(JUNK + (1, 2.5, "idle", "ok", "low", "finished", 3, 80.0)) for k in keys}


def answer(name: pk.CommandName, rng: random.Random) -> dict:
    """The extras of an ACK of `name`: its declared answer, drawn."""
    return {f.name: draw(f.type, rng) for f in COMMANDS[name].answer
            if not isinstance(f.type, sc.Maybe) or rng.random() < 0.5}


def _seeds() -> dict[pk.Kind, list[list]]:
    rng = np.random.default_rng(3)
    fits = {(lab, b): fit_histogram(np.bincount(np.clip(rng.gamma(2 + lab, 8, 3000), 0, 255).astype(np.int64),
                                                minlength=256)) for lab in (1, 4) for b in range(3)}
    labels = np.zeros((30, 40), np.uint8)
    labels[10:, 20:] = 4
    models = [pk.encode_models(fits, robot_id=1, seq=s, time=1.7e9 + s, commanded=(80.0, 0.0), measured=(79.9, 0.1),
                               feature_space="rgb", bands=("R", "G", "B")) for s in (1, 2, 7)]
    masks = [pk.encode_mask(labels, robot_id=1, seq=7)]
    unchanged = [pk.encode(pk.UnchangedPacket(1, s, 1.7e9, (80.0, 0.0), (80.0, 0.0), r)) for s, r in ((8, 7), (9, 1))]
    out: dict[pk.Kind, list[list]] = {}
    for body in models + masks + unchanged:
        items = msgpack.unpackb(body)
        out.setdefault(pk.Kind(items[1]), []).append(items)
    return out


SEEDS = _seeds()


def body(rng: random.Random) -> bytes:
    """One hostile packet body of any kind, at any schema version it has."""
    kind = rng.choice(list(pk.KINDS))
    cls = pk.KINDS[kind]
    version = rng.choice(range(pk.SCHEMA_VERSION, sc.newest(cls) + 1))
    fields = sc.layout(cls, version)
    if kind in SEEDS:
        items = list(rng.choice(SEEDS[kind]))
        at = 2
        for f in fields:
            if rng.random() < 0.2:
                items[at:at + f.type.width] = _spread(f, draw(f.type, rng))
            at += f.type.width
    else:
        items = [version, int(kind)]
        for f in fields:
            items.extend(_spread(f, draw(f.type, rng)))
        _tailor(kind, items, rng)
    if rng.random() < 0.3:
        items.append(extras(rng) if rng.random() < 0.9 else rng.choice(JUNK))
    if rng.random() < 0.02:
        items.insert(rng.randrange(len(items) + 1), rng.choice(JUNK))
    try:
        return msgpack.packb(items, use_bin_type=True)
    except (OverflowError, ValueError, TypeError):
        return msgpack.packb([version, int(kind)])


def _spread(f: sc.Field, v: Any) -> list:
    """A drawn value as the wire items the field takes (a hostile pair is two junk items)."""
    if f.type.width == 1:
        return [v]
    return list(v) if isinstance(v, list) and len(v) == f.type.width else [v] * f.type.width


def _tailor(kind: pk.Kind, items: list, rng: random.Random) -> None:
    """Make a declared-but-generic draw likelier to pass: an ACK names a command and carries its
    answer; a command carries arguments of its own."""
    if kind is pk.Kind.ACK and rng.random() < 0.8:
        name = rng.choice(list(pk.CommandName))
        items[3] = name.name
        if rng.random() < 0.9:
            items.append(answer(name, rng))
        if name is not pk.CommandName.STATUS and items[0] >= 4:
            items[4] = None
    elif kind is pk.Kind.COMMAND:
        name = items[3] if type(items[3]) is int else None
        spec = COMMANDS[pk.CommandName(name)] if name in pk.CommandName._value2member_map_ else None
        if spec is not None and spec.args:
            items[4] = {a.key: rng.choice((1.0, 45.0, [80.0, 60.0], "x", 2, -1)) for a in spec.args if rng.random() < 0.6}
