"""Shared pieces of the packet schema: kinds, bounds, strict field checks, extras.

Every check raises `radio.FrameError` naming the field, so a decoder is a sequence of
checks over the unpacked msgpack values and never trusts a type or a range it did not test.
"""
from __future__ import annotations

import enum
import math
from datetime import datetime, timezone
from collections.abc import Mapping
from typing import Any

import msgpack

from radio import FrameError
from radio.fragment import MAX_MESSAGE

# The schema version every kind has a layout at; a kind whose layout grew since is encoded at its
# own newer version (`radio.packets.schema.newest`), and its older layouts still decode.
# 2: MODELS packs angles, labels, codes and records into one blob; 3: the read records;
# 4: STATUS and the ACK of STATUS carry the typed report, a NACK may refuse a robot's message;
# 5: the MODELS camera section's flags are a varint and may carry the frame's source file.
SCHEMA_VERSION = 3
NEWEST_VERSION = 5
# A body is one link message: a longer one could not be sent (`radio.fragment.MAX_MESSAGE`).
MAX_BODY = MAX_MESSAGE
MAX_STR = 512
MAX_ARRAY = 256
MAX_EXTRAS = 16
MAX_MAP = 64  # a nested record's fields
MAX_EXTRA_KEY = 32
MAX_EXTRA_LIST = 64
UINT32 = 2**32 - 1
UINT64 = 2**64 - 1
INT64 = 2**63 - 1
# A wall-clock time in seconds since 1970: no robot's clock reads past 2106, and a time that
# cannot be shown as a date is refused with the packet, before anything is stored.
MAX_TIME = float(2**32)


def iso_time(t: float | None) -> str | None:
    """A wall-clock time as a person reads it (the robot's log, the station's events, `cmd`, the
    page): ISO 8601 in UTC, to the second; None stays None. Every time a packet decodes to has one."""
    return None if t is None else datetime.fromtimestamp(t, timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def clock_time(v: object) -> str | None:
    """`iso_time` of a value a packet's clock can hold, None for any other (an answer's extra a
    hostile peer filled is shown as the number it is, never raised on)."""
    return iso_time(float(v)) if type(v) in (int, float) and 0 <= v <= MAX_TIME else None

# -- sizes a real sensor cannot exceed ------------------------------------------------------
# Every size a decoded field gives (a frame, a label map, a pixel count, label and band
# counts) is checked against these before anything is allocated from it, so an authentic but
# absurd packet (a 20-byte MASK claiming a 65535 x 65535 frame) is refused, not built.
MAX_FRAME_SIDE = 16384  # a camera frame's height or width; the largest sensors sold are ~14200
MAX_FRAME_PIXELS = MAX_FRAME_SIDE * MAX_FRAME_SIDE  # and so a region's pixel count
MAX_MASK_SIDE = 64  # the MASK packet's mode-pooled label map
MAX_LABELS = 256  # label ids 0..255 (labels travel as uint8)
MAX_BANDS = 16
MAX_NAME = 16  # a feature space or band name
MIN_LEVELS, MAX_LEVELS = 2, 65536  # a sensor's levels (PercentileCodec.for_levels' range)
MAX_ANGLES = 64  # angles in a SWEEP command's list


class PacketTooLarge(ValueError):
    """A packet whose body would exceed MAX_BODY: the encoder refuses it (the sender decides
    what to leave out or split), since no link could carry it."""


class Kind(enum.IntEnum):
    MODELS = 1
    MASK = 2
    STATUS = 3
    COMMAND = 4
    ACK = 5
    NACK = 6
    LOG = 7
    UNCHANGED = 8


Scalar = None | bool | int | float | str | bytes
Extras = Mapping[str, Any]


def unpack_body(body: bytes) -> list:
    """msgpack-decode one untrusted body with every length bounded; [version, kind, ...]."""
    if not isinstance(body, (bytes, bytearray, memoryview)):
        raise FrameError(f"packet body must be bytes, got {type(body).__name__}")
    if len(body) > MAX_BODY:
        raise FrameError(f"packet body of {len(body)} bytes exceeds {MAX_BODY}")
    try:
        obj = msgpack.unpackb(
            bytes(body), raw=False, strict_map_key=False, use_list=True, timestamp=0,
            max_str_len=MAX_STR, max_bin_len=MAX_BODY, max_array_len=MAX_ARRAY,
            max_map_len=MAX_MAP, max_ext_len=0,
        )
    # msgpack reports malformed input as ValueError subclasses (also bad UTF-8), but
    # deep nesting and odd ext payloads can surface as other errors.
    except (ValueError, TypeError, OverflowError, RecursionError) as exc:
        raise FrameError(f"not a valid msgpack body: {exc}") from None
    if type(obj) is not list or len(obj) < 2:
        raise FrameError("packet body must be an array [version, kind, ...]")
    if type(obj[0]) is not int or not SCHEMA_VERSION <= obj[0] <= NEWEST_VERSION:
        raise FrameError(f"unsupported schema version {obj[0]!r} (expected {SCHEMA_VERSION}..{NEWEST_VERSION})")
    if type(obj[1]) is not int or obj[1] not in Kind._value2member_map_:
        raise FrameError(f"unknown packet kind {obj[1]!r}")
    return obj


def pack_body(kind: Kind, version: int, fields: list, extras: Extras) -> bytes:
    items = [version, int(kind), *fields]
    if extras:
        items.append(check_extras(dict(extras), "extras"))
    return msgpack.packb(items, use_bin_type=True)


def split_fields(items: list, kind: Kind, n: int) -> tuple[list, dict]:
    """The n fields of a body after [version, kind], and its extras map (empty if absent)."""
    fields = items[2:]
    if len(fields) == n:
        return fields, {}
    if len(fields) == n + 1:
        return fields[:n], check_extras(fields[n], "extras")
    raise FrameError(f"{kind.name} packet has {len(fields)} fields, expected {n} (+ optional extras)")


# -- strict scalar checks ------------------------------------------------------------------


def want_int(v: Any, name: str, lo: int, hi: int) -> int:
    if type(v) is not int:
        raise FrameError(f"{name} must be an integer, got {type(v).__name__}")
    if not lo <= v <= hi:
        raise FrameError(f"{name} = {v} outside [{lo}, {hi}]")
    return v


def want_float(v: Any, name: str, lo: float = -math.inf, hi: float = math.inf,
               allow_int: bool = False) -> float:
    if not (type(v) is float or (allow_int and type(v) is int)):
        raise FrameError(f"{name} must be a float, got {type(v).__name__}")
    v = float(v)
    if not math.isfinite(v):
        raise FrameError(f"{name} must be finite, got {v}")
    if not lo <= v <= hi:
        raise FrameError(f"{name} = {v} outside [{lo}, {hi}]")
    return v


def want_str(v: Any, name: str, max_len: int = MAX_STR, allow_empty: bool = True) -> str:
    if type(v) is not str:
        raise FrameError(f"{name} must be a string, got {type(v).__name__}")
    if len(v) > max_len or (not allow_empty and not v):
        raise FrameError(f"{name} must be {'1' if not allow_empty else '0'}..{max_len} characters")
    if not v.isprintable():
        raise FrameError(f"{name} contains unprintable characters")
    return v


def want_bin(v: Any, name: str) -> bytes:
    if type(v) is not bytes:
        raise FrameError(f"{name} must be binary, got {type(v).__name__}")
    return v


def want_enum(v: Any, enum_type: type[enum.IntEnum], name: str) -> Any:
    if type(v) is not int or v not in enum_type._value2member_map_:
        raise FrameError(f"unknown {name} {v!r}")
    return enum_type(v)


def _check_scalar(v: Any, name: str) -> Scalar:
    if v is None or type(v) in (bool, int, bytes):
        if type(v) is int and not -(2**63) <= v < 2**64:
            raise FrameError(f"{name} integer out of range")
        if type(v) is bytes and len(v) > MAX_STR:
            raise FrameError(f"{name} is longer than {MAX_STR} bytes")
        return v
    if type(v) is float:
        return want_float(v, name)
    if type(v) is str:
        return want_str(v, name)
    raise FrameError(f"{name} has unsupported type {type(v).__name__}")


def check_extras(v: Any, name: str) -> dict[str, Any]:
    """Extension fields for later schema growth: str keys, scalar or short-list values."""
    if not isinstance(v, dict):
        raise FrameError(f"{name} must be a map")
    if len(v) > MAX_EXTRAS:
        raise FrameError(f"{name} has more than {MAX_EXTRAS} entries")
    out: dict[str, Any] = {}
    for key, value in v.items():
        key = want_str(key, f"{name} key", MAX_EXTRA_KEY, allow_empty=False)
        if isinstance(value, (list, tuple)):
            if len(value) > MAX_EXTRA_LIST:
                raise FrameError(f"{name}[{key}] has more than {MAX_EXTRA_LIST} items")
            out[key] = tuple(_check_scalar(x, f"{name}[{key}]") for x in value)
        else:
            out[key] = _check_scalar(value, f"{name}[{key}]")
    return out


# -- view angles, carried as integer centidegrees (0.01 degree resolution) ----------------


def angles_to_wire(angles: tuple[float, float], name: str) -> list[int]:
    elevation, azimuth = (float(a) for a in angles)
    if not (math.isfinite(elevation) and math.isfinite(azimuth)):
        raise ValueError(f"{name} angles must be finite, got {angles}")
    if not -90.0 <= elevation <= 90.0:
        raise ValueError(f"{name} elevation {elevation} outside [-90, 90]")
    return [round(elevation * 100), round((azimuth % 360.0) * 100) % 36000]


def angles_from_wire(el: Any, az: Any, name: str) -> tuple[float, float]:
    e = want_int(el, f"{name} elevation", -9000, 9000)
    a = want_int(az, f"{name} azimuth", 0, 35999)
    return (e / 100, a / 100)


def band_names_problem(names: tuple[str, ...]) -> str | None:
    """What keeps these band names out of a MODELS packet (None: nothing)."""
    bad = [n for n in names if not 1 <= len(n) <= MAX_NAME or not n.isprintable()]
    if bad:
        return f"{bad[0]!r}: a band name is 1..{MAX_NAME} printable characters"
    if len(set(names)) != len(names):
        return f"a name repeats in {', '.join(names)}"
    if len(names) > MAX_BANDS:
        return f"{len(names)} names: a capture holds at most {MAX_BANDS} bands"
    return None
