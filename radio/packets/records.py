"""The records section of a MODELS blob: how a model differs from its label's plain read.

A model read at its label's z, unshifted, uncensored, with the SL band is plain and has no
record. Any other model gets 2 bits in the records bitmap and then either one read byte (a
model read at another spread or centre, `READ_SHIFTS`) or a flag byte (`TailFlag`) and its
fields; the byte layout is in `radio.packets.models`' module doc. `tail_of` makes a model's
`Tail`, `tail_bytes` writes it, `read_tails` reads a blob's records back strictly.
"""
from __future__ import annotations

import enum
import math
import struct
from dataclasses import dataclass

from btf.codec import CENSOR_SCALE, MAX_SHIFT_CODE, SHIFT_SCALE, Z_LADDER
from btf.record import FittedModel
from radio import FrameError

_U8, _I8, _U16 = struct.Struct(">B"), struct.Struct(">b"), struct.Struct(">H")


class TailFlag(enum.IntFlag):
    CENSORED_LOW = 1
    CENSORED_HIGH = 2
    SHIFT = 4
    FALLBACK = 8
    Z = 16
    EXACT = 32


class TailCode(enum.IntEnum):
    """A model's 2-bit entry in the records bitmap."""

    PLAIN = 0
    READ = 1
    FLAGGED = 3


# The read byte's shifts (codes in 1/32): the centres btf.fit.reads tries.
READ_SHIFTS: tuple[int, ...] = (0, -16, 16)
_READ_EXACT = 0x40


@dataclass(frozen=True, slots=True)
class Tail:
    """A model's placement when it differs from its label's plain one (see module doc)."""

    z_index: int
    shift_code: int = 0
    censored_low: float = 0.0
    censored_high: float = 0.0
    fallback: bool = False
    exact_family: bool = False  # the family from the sign of ln d alone (btf.percentile)


def tail_of(r: FittedModel, label_z: float, override: tuple[float, float] | None) -> Tail | None:
    """The record a model needs beyond its label's fields, or None for a plain model. The
    `censored` override of models_packet annotates fits that measured no censoring."""
    low, high = r.censored_low, r.censored_high
    if override is not None and not (low or high or r.fallback):
        low, high = override
    if not (r.z != label_z or r.shift or low or high or r.fallback or r.exact_family):
        return None
    code = round(r.shift * SHIFT_SCALE)
    if code / SHIFT_SCALE != r.shift or abs(code) > MAX_SHIFT_CODE:
        raise ValueError(f"shift {r.shift} is not a multiple of 1/{SHIFT_SCALE} within the int8 range")
    if r.fallback and (censor_code(low) / CENSOR_SCALE, censor_code(high) / CENSOR_SCALE) != (low, high):
        raise ValueError("a fallback model needs its censored fractions in 1/65535 fixed point")
    return Tail(Z_LADDER.index(r.z), code, float(low), float(high), bool(r.fallback), bool(r.exact_family))


def tail_bytes(t: Tail | None, label_z: int) -> tuple[int, bytes]:
    """(TailCode, bytes) of one model's record (see module doc)."""
    if t is None:
        return TailCode.PLAIN, b""
    low, high = censor_code(t.censored_low), censor_code(t.censored_high)
    if not (low or high or t.fallback) and t.shift_code in READ_SHIFTS:
        return TailCode.READ, bytes([t.z_index | READ_SHIFTS.index(t.shift_code) << 4
                                     | (_READ_EXACT if t.exact_family else 0)])
    fields = [(TailFlag.Z, _U8, t.z_index if t.z_index != label_z else None),
              (TailFlag.SHIFT, _I8, t.shift_code or None),
              (TailFlag.CENSORED_LOW, _U16, low or None), (TailFlag.CENSORED_HIGH, _U16, high or None)]
    flags = TailFlag(0)
    out = b""
    for flag, fmt, value in fields:
        if value is not None:
            flags |= flag
            out += fmt.pack(value)
    if t.fallback:
        flags |= TailFlag.FALLBACK
    if t.exact_family:
        flags |= TailFlag.EXACT
    if not flags:
        return TailCode.PLAIN, b""
    return TailCode.FLAGGED, bytes([flags]) + out


def _take(blob: bytes, pos: int, fmt: struct.Struct) -> tuple[int, int]:
    if pos + fmt.size > len(blob):
        raise FrameError("model records end inside a record")
    return fmt.unpack_from(blob, pos)[0], pos + fmt.size


def read_tails(blob: bytes, pos: int, label_z: list[int], n_bands: int) -> list[tuple[Tail | None, ...]]:
    n = len(label_z) * n_bands
    out: list[list[Tail | None]] = [[None] * n_bands for _ in label_z]
    if pos == len(blob):
        return [tuple(t) for t in out]
    marks_end = pos + (n + 3) // 4
    if marks_end > len(blob):
        raise FrameError("model records end inside their bitmap")
    marks, pos = blob[pos:marks_end], marks_end
    for i in range(n):
        code = marks[i // 4] >> (2 * (i % 4)) & 3
        if code == TailCode.PLAIN:
            continue
        if code == TailCode.READ:
            byte, pos = _take(blob, pos, _U8)
            slot, z_index = byte >> 4 & 3, byte & 0x0F
            if byte & 0x80 or slot >= len(READ_SHIFTS) or z_index >= len(Z_LADDER):
                raise FrameError(f"read byte {byte:#x} of model {i} is not a read")
            out[i // n_bands][i % n_bands] = Tail(z_index, READ_SHIFTS[slot], exact_family=bool(byte & _READ_EXACT))
            continue
        if code != TailCode.FLAGGED:
            raise FrameError(f"model {i} has record code {code}, which no record uses")
        flags, pos = _take(blob, pos, _U8)
        if not flags or flags & ~0x3F or (flags & TailFlag.FALLBACK and not flags & (
                TailFlag.CENSORED_LOW | TailFlag.CENSORED_HIGH)):
            raise FrameError(f"record of model {i} has bad flags {flags:#x}")
        z_index, shift, low, high = label_z[i // n_bands], 0, 0, 0
        if flags & TailFlag.Z:
            z_index, pos = _take(blob, pos, _U8)
            if z_index >= len(Z_LADDER):
                raise FrameError(f"record: z ladder index {z_index} outside 0..{len(Z_LADDER) - 1}")
        if flags & TailFlag.SHIFT:
            shift, pos = _take(blob, pos, _I8)
            if abs(shift) > MAX_SHIFT_CODE:
                raise FrameError(f"record: shift code {shift} outside +-{MAX_SHIFT_CODE}")
        if flags & TailFlag.CENSORED_LOW:
            low, pos = _take(blob, pos, _U16)
        if flags & TailFlag.CENSORED_HIGH:
            high, pos = _take(blob, pos, _U16)
        if low + high > CENSOR_SCALE + 1:  # two halves may each round up
            raise FrameError("censored fractions of a model add up to more than 1")
        out[i // n_bands][i % n_bands] = Tail(
            z_index, shift, low / CENSOR_SCALE, high / CENSOR_SCALE, bool(flags & TailFlag.FALLBACK),
            bool(flags & TailFlag.EXACT))
    if pos != len(blob):
        raise FrameError(f"models blob has {len(blob) - pos} bytes after its records")
    return [tuple(t) for t in out]


def censor_code(fraction: float) -> int:
    if not (math.isfinite(fraction) and 0.0 <= fraction <= 1.0):
        raise ValueError(f"censored fraction {fraction} outside [0, 1]")
    return round(fraction * CENSOR_SCALE)
