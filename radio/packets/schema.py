"""The packet schema as data: every field of every packet kind and of every nested record is
declared once, on its dataclass, with `wire(type, doc)`: its name, its type with the bounds,
what it means, and (for a record) its tag. Encode, decode and the schema's document
(`python -m radio.packets`, docs/packets.md) all read these declarations.

A packet is a msgpack array: its declared fields in order, then the optional extras map. A field
added to a kind later carries `since=` the schema version that added it: older bodies of that
kind decode without it (its default), and the kind is encoded at its newest version.

A nested record (`Record`) travels as a map from small integer tags to values; a field that is
None is left out, so a record says only what it knows. Bounded lists (`Latest`) keep the newest
items and carry how many older ones were left out: a sender cuts visibly (`fit`), a receiver
refuses anything past the bounds. Texts are cut to their bound with a visible "…".
"""
from __future__ import annotations

import dataclasses
import enum
import operator
from collections import deque
from dataclasses import dataclass
from typing import Any, Callable, ClassVar, Iterable

from radio import FrameError
from radio.packets.base import (
    MAX_STR,
    SCHEMA_VERSION,
    UINT32,
    angles_from_wire,
    angles_to_wire,
    want_bin,
    want_enum,
    want_float,
    want_int,
    want_str,
)

CUT = "…"  # ends a text the sender had to shorten


class FieldType:
    """How one field travels: `check` an untrusted wire value (FrameError naming the field),
    `to_wire` a value, `fit` a value into the bounds the way a sender may (cutting visibly)."""

    width: ClassVar[int] = 1  # wire items the field takes in a packet's array

    def check(self, v: Any, name: str) -> Any:
        raise NotImplementedError

    def to_wire(self, v: Any, name: str) -> Any:
        return v

    def fit(self, v: Any) -> Any:
        return v

    def describe(self) -> str:
        raise NotImplementedError


@dataclass(frozen=True)
class Int(FieldType):
    lo: int
    hi: int

    def check(self, v: Any, name: str) -> int:
        return want_int(v, name, self.lo, self.hi)

    def to_wire(self, v: Any, name: str) -> int:
        return operator.index(v)

    def fit(self, v: Any) -> Any:
        return v if isinstance(v, bool) else operator.index(v)

    def describe(self) -> str:
        return f"int {self.lo}..{_big(self.hi)}"


@dataclass(frozen=True)
class Float(FieldType):
    lo: float
    hi: float
    allow_int: bool = False

    def check(self, v: Any, name: str) -> float:
        return want_float(v, name, self.lo, self.hi, self.allow_int)

    def to_wire(self, v: Any, name: str) -> float:
        return float(v)

    def fit(self, v: Any) -> Any:
        return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else v

    def describe(self) -> str:
        hi = f"2^{int(self.hi).bit_length() - 1}" if self.hi > 1e6 and float(self.hi).is_integer() and \
            int(self.hi) & (int(self.hi) - 1) == 0 else f"{self.hi:g}"
        return f"float {self.lo:g}..{hi}"


@dataclass(frozen=True)
class Text(FieldType):
    most: int = MAX_STR
    empty: bool = True

    def check(self, v: Any, name: str) -> str:
        return want_str(v, name, self.most, self.empty)

    def fit(self, v: Any) -> str:
        """Printable, at most `most` characters and the unpacker's MAX_STR bytes of UTF-8."""
        text = "".join(c if c.isprintable() else " " for c in str(v))
        if len(text) <= self.most and len(text.encode()) <= MAX_STR:
            return text
        room = MAX_STR - len(CUT.encode())
        return text[:self.most - 1].encode()[:room].decode("utf-8", "ignore") + CUT

    def describe(self) -> str:
        return f"text ≤ {self.most} characters" + ("" if self.empty else ", not empty")


@dataclass(frozen=True)
class Word(FieldType):
    """One of a few fixed strings."""

    words: tuple[str, ...]

    def check(self, v: Any, name: str) -> str:
        if type(v) is not str or v not in self.words:
            raise FrameError(f"{name} {v!r} is not one of {', '.join(self.words)}")
        return v

    def to_wire(self, v: Any, name: str) -> str:
        return str(v)

    def describe(self) -> str:
        return " \\| ".join(f'"{w}"' for w in self.words)


class Flag(FieldType):
    def check(self, v: Any, name: str) -> bool:
        if type(v) is not bool:
            raise FrameError(f"{name} must be true or false, got {type(v).__name__}")
        return v

    def to_wire(self, v: Any, name: str) -> bool:
        return bool(v)

    def describe(self) -> str:
        return "bool"


@dataclass(frozen=True)
class Choice(FieldType):
    """An IntEnum, by value."""

    enum_type: type[enum.IntEnum]

    def check(self, v: Any, name: str) -> Any:
        return want_enum(v, self.enum_type, name)

    def to_wire(self, v: Any, name: str) -> int:
        return int(v)

    def describe(self) -> str:
        return f"{self.enum_type.__name__} ({', '.join(f'{m.value} {m.name}' for m in self.enum_type)})"


@dataclass(frozen=True)
class Bin(FieldType):
    def check(self, v: Any, name: str) -> bytes:
        return want_bin(v, name)

    def describe(self) -> str:
        return "bytes"


@dataclass(frozen=True)
class Angles(FieldType):
    """(elevation, azimuth) in degrees as two integer centidegrees; `optional`: [nil, nil] for None."""

    optional: bool = False
    width: ClassVar[int] = 2

    def check(self, v: Any, name: str) -> tuple[float, float] | None:
        el, az = v
        if self.optional and el is None and az is None:
            return None
        return angles_from_wire(el, az, name)

    def to_wire(self, v: Any, name: str) -> list:
        return [None, None] if v is None and self.optional else angles_to_wire(v, name)

    def describe(self) -> str:
        return "elevation -9000..9000, azimuth 0..35999 (centidegrees)" + (", both nil: unknown" if self.optional else "")


@dataclass(frozen=True)
class Maybe(FieldType):
    """The inner type, or nil (None: not said)."""

    inner: FieldType

    def check(self, v: Any, name: str) -> Any:
        return None if v is None else self.inner.check(v, name)

    def to_wire(self, v: Any, name: str) -> Any:
        return None if v is None else self.inner.to_wire(v, name)

    def fit(self, v: Any) -> Any:
        return None if v is None else self.inner.fit(v)

    def describe(self) -> str:
        return f"{self.inner.describe()}, or nil"


@dataclass(frozen=True)
class ListOf(FieldType):
    """A whole list of `least`..`most` items (a list that cannot be cut, such as a plan's angles)."""

    item: FieldType
    most: int
    least: int = 0

    def check(self, v: Any, name: str) -> tuple:
        if type(v) is not list or not self.least <= len(v) <= self.most:
            raise FrameError(f"{name} must be a list of {self.least}..{self.most} items")
        return tuple(self.item.check(x, name) for x in v)

    def to_wire(self, v: Any, name: str) -> list:
        return [self.item.to_wire(x, name) for x in v]

    def fit(self, v: Any) -> tuple:
        return tuple(self.item.fit(x) for x in v)

    def describe(self) -> str:
        return f"list of {self.least}..{self.most} × ({self.item.describe()})"


@dataclass(frozen=True, slots=True)
class Kept:
    """The newest items of a bounded list, and how many older ones were left out."""

    items: tuple = ()
    left_out: int = 0

    def __iter__(self):
        return iter(self.items)

    def __len__(self) -> int:
        return len(self.items)

    @property
    def total(self) -> int:
        return len(self.items) + self.left_out


class Recent(deque):
    """The sender's side of a `Latest` field: the newest `maxlen` items appended, and a count of
    the older ones let go, so what a report leaves out is said (`kept`)."""

    def __init__(self, maxlen: int, items: Iterable = ()) -> None:
        super().__init__(maxlen=maxlen)
        self.dropped = 0
        for x in items:
            self.append(x)

    def append(self, x: Any) -> None:
        if len(self) == self.maxlen:
            self.dropped += 1
        super().append(x)

    def kept(self) -> Kept:
        return Kept(tuple(self), self.dropped)


@dataclass(frozen=True)
class Latest(FieldType):
    """At most `most` items, the newest, as [[item, ...], left_out]: what was cut is counted."""

    item: FieldType
    most: int

    def check(self, v: Any, name: str) -> Kept:
        if type(v) is not list or len(v) != 2 or type(v[0]) is not list:
            raise FrameError(f"{name} must be [[item, ...], left out]")
        if len(v[0]) > self.most:
            raise FrameError(f"{name} holds {len(v[0])} items, at most {self.most}")
        return Kept(tuple(self.item.check(x, name) for x in v[0]), want_int(v[1], f"{name} left out", 0, UINT32))

    def to_wire(self, v: Any, name: str) -> list:
        return [[self.item.to_wire(x, name) for x in v.items], v.left_out]

    def fit(self, v: Any) -> Kept:
        items, before = (tuple(v.items), v.left_out) if isinstance(v, Kept) else (tuple(v), 0)
        cut = max(0, len(items) - self.most)
        return Kept(tuple(self.item.fit(x) for x in items[cut:]), min(UINT32, before + cut))

    def describe(self) -> str:
        return f"the newest ≤ {self.most} × ({self.item.describe()}), and how many were left out"


@dataclass(frozen=True)
class Record(FieldType):
    """A nested record: a map {tag: value} of its declared fields, nil ones left out."""

    cls: type

    def check(self, v: Any, name: str) -> Any:
        if type(v) is not dict:
            raise FrameError(f"{name} must be a map of tagged fields")
        by_tag = {f.tag: f for f in layout(self.cls)}
        values = {}
        for tag, value in v.items():
            f = by_tag.get(tag) if type(tag) is int else None
            if f is None:
                raise FrameError(f"{name} has no field tagged {tag!r}")
            values[f.name] = f.type.check(value, f"{name} {f.label}")
        for f in by_tag.values():
            if f.name not in values and not isinstance(f.type, Maybe):
                raise FrameError(f"{name} lacks its {f.label}")
        record = self.cls(**values)
        problem = record.problem() if hasattr(record, "problem") else ""
        if problem:
            raise FrameError(f"{name}: {problem}")
        return record

    def to_wire(self, v: Any, name: str) -> dict:
        if not isinstance(v, self.cls):
            raise TypeError(f"{name} must be a {self.cls.__name__}, got {type(v).__name__}")
        out = {}
        for f in layout(self.cls):
            value = getattr(v, f.name)
            if value is not None:
                out[f.tag] = f.type.to_wire(value, f"{name} {f.label}")
        return out

    def fit(self, v: Any) -> Any:
        return dataclasses.replace(v, **{f.name: f.type.fit(getattr(v, f.name)) for f in layout(self.cls)})

    def describe(self) -> str:
        return f"record {self.cls.__name__}"


def _big(n: int) -> str:
    return f"2^{n.bit_length()}-1" if n > 10**6 and (n + 1) & n == 0 else str(n)


# -- declaring fields ----------------------------------------------------------------------


@dataclass(frozen=True)
class Field:
    name: str
    type: FieldType
    doc: str
    tag: int | None = None  # a record's fields: the key it travels under
    since: int = SCHEMA_VERSION  # the schema version that added it
    label: str = ""  # how messages name it ("" : the name, spaced)

    def __post_init__(self) -> None:
        if not self.label:
            object.__setattr__(self, "label", self.name.replace("_", " "))


def wire(kind: FieldType, doc: str, *, tag: int | None = None, since: int = SCHEMA_VERSION, label: str = "",
         default: Any = dataclasses.MISSING, factory: Callable[[], Any] | None = None) -> Any:
    """A dataclass field that travels: its type, meaning, tag (records) and the version that added it."""
    meta = {"wire": (kind, doc, tag, since, label)}
    if factory is not None:
        return dataclasses.field(default_factory=factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


_LAYOUTS: dict[type, tuple[Field, ...]] = {}


def layout(cls: type, version: int | None = None) -> tuple[Field, ...]:
    """The declared wire fields of a packet kind (at `version`: those it had then) or a record.
    A kind whose dataclass is not its wire form lists them itself, as `WIRE`."""
    if cls not in _LAYOUTS:
        explicit = cls.__dict__.get("WIRE")
        _LAYOUTS[cls] = tuple(explicit) if explicit is not None else tuple(
            Field(f.name, *f.metadata["wire"]) for f in dataclasses.fields(cls) if "wire" in f.metadata)
        tags = [f.tag for f in _LAYOUTS[cls] if f.tag is not None]
        if len(tags) != len(set(tags)):
            raise TypeError(f"{cls.__name__}: two fields share a tag")
    fields = _LAYOUTS[cls]
    return fields if version is None else tuple(f for f in fields if f.since <= version)


def newest(cls: type) -> int:
    """The schema version a kind is encoded at: the newest of its fields' and of the bytes inside
    one (`BYTES_SINCE`: a kind whose packed field grew, e.g. the MODELS blob)."""
    return max([f.since for f in layout(cls)] + [getattr(cls, "BYTES_SINCE", SCHEMA_VERSION)])


def width(cls: type, version: int) -> int:
    return sum(f.type.width for f in layout(cls, version))


def values_to_wire(fields: Iterable[Field], values: dict[str, Any]) -> list:
    out: list = []
    for f in fields:
        v = f.type.to_wire(values[f.name], f.label)
        out.extend(v if f.type.width > 1 else [v])
    return out


def values_from_wire(fields: Iterable[Field], items: list) -> dict[str, Any]:
    """The declared fields' values from a packet's wire items, each checked."""
    out, i = {}, 0
    for f in fields:
        n = f.type.width
        out[f.name] = f.type.check(items[i] if n == 1 else items[i:i + n], f.label)
        i += n
    return out


def fitted(obj: Any) -> Any:
    """`obj` (a record or a packet) with every declared field fitted into its bounds."""
    return dataclasses.replace(obj, **{f.name: f.type.fit(getattr(obj, f.name)) for f in layout(type(obj))})


class Declared:
    """A packet kind whose dataclass declares its wire fields with `wire`: encoded and decoded
    from the declarations; `problem` states what no single field shows (one field against another)."""

    __slots__ = ()

    def wire_values(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in layout(type(self))}

    @classmethod
    def from_values(cls, values: dict[str, Any], extras: dict, version: int, compute: bool = True) -> Any:
        packet = cls(**values, extras=extras)
        problem = packet.problem()
        if problem:
            raise FrameError(problem)
        return packet

    def problem(self) -> str:
        return ""
