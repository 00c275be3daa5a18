"""The packet schema's document, written from the declarations (`radio.packets.schema`): every
kind's fields in wire order, the schema version each appeared in, and every nested record by
tag. docs/packets.md is this text (`python -m radio.packets > docs/packets.md`; a test keeps
them equal)."""
from __future__ import annotations

from radio.packets import KINDS
from radio.packets.base import SCHEMA_VERSION, Kind
from radio.packets.commands import COMMANDS
from radio.packets.schema import Field, Latest, ListOf, Maybe, Record, layout, newest

HEAD = """# Packets on the wire

Written from the declarations in `radio/packets/` by `python -m radio.packets`: do not edit by hand.

A body is the msgpack array `[version, kind, field, ...]`, then an optional map of extras (at most
16 short keys to scalars or short lists). A kind is encoded at its newest version and decodes at
every version from {oldest}; a field marked *since N* is absent from older bodies. A record travels
as a map from tag to value, its nil fields left out; a bounded list as `[[item, ...], left out]`.
Texts are printable, at most the characters given and 512 bytes of UTF-8; a sender cuts a longer
one visibly (ending in "…").
"""


def _row(f: Field, since_base: int = SCHEMA_VERSION) -> str:
    since = f" *(since {f.since})*" if f.since > since_base else ""
    tag = f"{f.tag} | " if f.tag is not None else ""
    return f"| {tag}`{f.name}` | {f.type.describe()} | {f.doc}{since} |"


def _records(types) -> list[type]:
    """Every record reachable from the declared fields, in the order first met."""
    found: list[type] = []

    def walk(t) -> None:
        if isinstance(t, (Maybe, ListOf, Latest)):
            walk(t.inner if isinstance(t, Maybe) else t.item)
        elif isinstance(t, Record) and t.cls not in found:
            found.append(t.cls)
            for f in layout(t.cls):
                walk(f.type)

    for t in types:
        walk(t)
    return found


def document() -> str:
    out = [HEAD.format(oldest=SCHEMA_VERSION)]
    for kind in Kind:
        cls = KINDS[kind]
        out += [f"## {kind.name} ({int(kind)}), schema {newest(cls)}", "", _doc(cls), "",
                "| field | type | meaning |", "|---|---|---|", *(_row(f) for f in layout(cls)), ""]
    out += ["## Command answers", "", "An ACK's extras: the values the command table declares for its command.", "",
            "| command | field | type | meaning |", "|---|---|---|---|"]
    out += [f"| {c.name.name} | `{f.name}` | {f.type.describe()} | {f.doc} |" for c in COMMANDS.values() for f in c.answer]
    out.append("")
    for rec in _records(f.type for cls in KINDS.values() for f in layout(cls)):
        out += [f"## Record {rec.__name__}", "", _doc(rec), "", "| tag | field | type | meaning |", "|---|---|---|---|",
                *(_row(f) for f in layout(rec)), ""]
    return "\n".join(line for i, line in enumerate(out) if line or (i and out[i - 1])).rstrip() + "\n"


def _doc(cls: type) -> str:
    """The first paragraph of a class's own docstring, on one line ("" for a dataclass's generated one)."""
    doc = cls.__doc__ or ""
    return "" if doc.startswith(cls.__name__ + "(") else " ".join(doc.split("\n\n")[0].split())
