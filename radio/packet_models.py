"""MODELS and UNCHANGED packets: one capture's Johnson models, or the note that nothing moved.

A model travels as its four Slifker-Shapiro percentiles x(-3z), x(-z), x(z), x(3z) in the
fitter's fixed point (`PercentileCodec.for_levels(levels)`: 16-bit codes for 8-bit sensors,
32-bit for deeper ones), packed for the whole capture into one big-endian binary blob. The
label's pixel count and z-ladder index are shared by its bands. The receiver recomputes each
model with `model_from_percentiles`, exactly as the robot did, so the host's models equal the
robot's bit for bit. Fixed point costs, for 8-bit sensors, a step of 2**-8 gray level: every
percentile is within 2**-9 < 0.01 gray level of the fitter's float value.

Wire fields after [version, kind]:
  MODELS    robot, seq, time, cmd_el, cmd_az, meas_el, meas_az, feature_space, [bands],
            levels, labels_blob (>BBI per label: label, z index, count),
            codes_blob (per label, per band, 4 codes), tails (nil | records) [, extras]
  UNCHANGED robot, seq, time, cmd_el, cmd_az, meas_el, meas_az, ref_seq [, extras]
Angles are integer centidegrees (0.01 degree); censored fractions are 1/65535 fixed point.

Tails: only the rare models that are not plain "label's z, no shift, nothing censored, support
as fitted" get a record, so an ordinary model stays at 8 bytes. A record is >H (model index
= label position * bands + band, times 16, plus flags), then with flag CENSORED >BbHH (z index,
shift code in 1/32, censored low and high), then with SUPPORT_LOW the lowest and with
SUPPORT_HIGH the highest occupied level (B up to 256 levels, else H): the fitted support fell
short of it and was widened (onboard.percentile.widen). A support-only record costs 3 bytes. Flag FALLBACK (with CENSORED) marks the normal fallback of onboard.censor.
"""
from __future__ import annotations

import enum
import math
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from onboard.censor import CENSOR_SCALE, MAX_SHIFT_CODE, SHIFT_SCALE, fallback_probs
from onboard.fit import Z_LADDER, FitResult, PercentileCodec, model_from_percentiles, support_point
from onboard.johnson import Johnson
from radio import FrameError
from radio.packet_base import (
    UINT32, Kind, angles_from_wire, angles_to_wire, want_bin, want_float, want_int, want_str,
)

MAX_LABELS = 256
MAX_BANDS = 16
MAX_NAME = 16
MIN_LEVELS, MAX_LEVELS = 2, 65536  # PercentileCodec.for_levels' range
_LABEL = struct.Struct(">BBI")
_TAIL_HEAD = struct.Struct(">H")
_CENSOR = struct.Struct(">BbHH")


class TailFlag(enum.IntFlag):
    CENSORED = 1
    FALLBACK = 2
    SUPPORT_LOW = 4
    SUPPORT_HIGH = 8


@dataclass(frozen=True, slots=True)
class Tail:
    """A model's placement when it differs from its label's plain one (see module doc)."""

    z_index: int
    shift_code: int = 0
    censored_low: float = 0.0
    censored_high: float = 0.0
    fallback: bool = False
    support_low: int | None = None  # lowest occupied level, when the support was widened to it
    support_high: int | None = None


@dataclass(frozen=True, slots=True)
class LabelModels:
    """One region's wire record: shared fields, four percentile codes per band, and a Tail
    (or None) per band."""

    label: int
    count: int
    z_index: int
    codes: tuple[tuple[int, int, int, int], ...]
    tails: tuple[Tail | None, ...] = ()

    @property
    def censored_low(self) -> float:
        """The largest censored fraction at the low end over the label's bands."""
        return max((t.censored_low for t in self.tails if t is not None), default=0.0)

    @property
    def censored_high(self) -> float:
        return max((t.censored_high for t in self.tails if t is not None), default=0.0)

    def tail(self, band: int) -> Tail | None:
        return self.tails[band] if band < len(self.tails) else None


@dataclass(frozen=True, slots=True)
class ModelsPacket:
    KIND: ClassVar[Kind] = Kind.MODELS
    robot_id: int
    seq: int
    time: float
    commanded: tuple[float, float]  # (elevation, azimuth) in degrees
    measured: tuple[float, float]
    feature_space: str
    bands: tuple[str, ...]
    levels: int
    labels: tuple[LabelModels, ...]
    extras: Mapping[str, Any] = field(default_factory=dict)
    # Filled by decode: (label, band index) -> the model recomputed from the codes.
    models: Mapping[tuple[int, int], Johnson] = field(default_factory=dict, compare=False, repr=False)

    def _wire(self) -> list:
        codec = PercentileCodec.for_levels(self.levels)
        dtype = ">u2" if codec.bits <= 16 else ">u4"
        codes = np.array([c for lab in self.labels for c in lab.codes], dtype=np.int64).reshape(-1)
        if codes.size and (codes.min() < 0 or codes.max() > np.iinfo(dtype).max):
            raise ValueError(f"percentile codes do not fit {dtype}")
        labels = b"".join(_LABEL.pack(x.label, x.z_index, x.count) for x in self.labels)
        code = struct.Struct(">B" if self.levels <= 256 else ">H")
        records = []
        for i, lab in enumerate(self.labels):
            for band, t in enumerate(lab.tails):
                if t is not None:
                    records.append(_tail_bytes(i * len(self.bands) + band, t, code))
        censored = b"".join(records) if records else None
        return [
            self.robot_id, self.seq, float(self.time),
            *angles_to_wire(self.commanded, "commanded"), *angles_to_wire(self.measured, "measured"),
            self.feature_space, list(self.bands), self.levels,
            labels, codes.astype(dtype).tobytes(), censored,
        ]

    @classmethod
    def _from_wire(cls, f: list, extras: dict, compute: bool = True) -> ModelsPacket:
        robot, seq = want_int(f[0], "robot id", 0, 0xFFFF), want_int(f[1], "capture seq", 0, UINT32)
        t = want_float(f[2], "time", 0.0)
        commanded = angles_from_wire(f[3], f[4], "commanded")
        measured = angles_from_wire(f[5], f[6], "measured")
        space = want_str(f[7], "feature space", MAX_NAME, allow_empty=False)
        if type(f[8]) is not list or not 1 <= len(f[8]) <= MAX_BANDS:
            raise FrameError(f"bands must be a list of 1..{MAX_BANDS} names")
        bands = tuple(want_str(b, "band name", MAX_NAME, allow_empty=False) for b in f[8])
        if len(set(bands)) != len(bands):
            raise FrameError("band names repeat")
        levels = want_int(f[9], "levels", MIN_LEVELS, MAX_LEVELS)
        codec = PercentileCodec.for_levels(levels)
        width = 2 if codec.bits <= 16 else 4
        label_blob, code_blob = want_bin(f[10], "labels"), want_bin(f[11], "codes")
        if len(label_blob) % _LABEL.size or len(label_blob) // _LABEL.size > MAX_LABELS:
            raise FrameError("labels blob length is not a whole number of label records")
        n = len(label_blob) // _LABEL.size
        if len(code_blob) != n * len(bands) * 4 * width:
            raise FrameError(
                f"codes blob has {len(code_blob)} bytes, expected {n * len(bands) * 4 * width}"
            )
        codes = np.frombuffer(code_blob, dtype=">u2" if width == 2 else ">u4").astype(np.int64)
        codes = codes.reshape(n, len(bands), 4)
        if np.any(np.diff(codes, axis=2) < 0):
            raise FrameError("percentile codes decrease within a model")
        if codes.size and codes.max() > (1 << codec.bits) - 1:
            raise FrameError(f"percentile code exceeds {codec.bits}-bit range")
        tails = _tails(f[12], n, len(bands), struct.Struct(">B" if levels <= 256 else ">H"), levels)
        records, last = [], -1
        for i, (label, z_index, count) in enumerate(_LABEL.iter_unpack(label_blob)):
            if label <= last:
                raise FrameError("label ids must be strictly increasing")
            last = label
            if z_index >= len(Z_LADDER):
                raise FrameError(f"z ladder index {z_index} outside 0..{len(Z_LADDER) - 1}")
            records.append(LabelModels(
                label, count, z_index, tuple(tuple(int(c) for c in m) for m in codes[i]), tails[i],
            ))
        packet = cls(robot, seq, t, commanded, measured, space, bands, levels, tuple(records), extras)
        if compute:
            object.__setattr__(packet, "models", _recompute(packet, codec))
        return packet


@dataclass(frozen=True, slots=True)
class UnchangedPacket:
    """A capture whose models all lie within tolerance of capture `ref_seq` at the same pose."""

    KIND: ClassVar[Kind] = Kind.UNCHANGED
    robot_id: int
    seq: int
    time: float
    commanded: tuple[float, float]
    measured: tuple[float, float]
    ref_seq: int
    extras: Mapping[str, Any] = field(default_factory=dict)

    def _wire(self) -> list:
        return [
            self.robot_id, self.seq, float(self.time),
            *angles_to_wire(self.commanded, "commanded"), *angles_to_wire(self.measured, "measured"),
            self.ref_seq,
        ]

    @classmethod
    def _from_wire(cls, f: list, extras: dict, compute: bool = True) -> UnchangedPacket:
        seq = want_int(f[1], "capture seq", 0, UINT32)
        ref = want_int(f[7], "reference seq", 0, UINT32)
        if ref >= seq:
            raise FrameError(f"reference capture {ref} is not before capture {seq}")
        return cls(
            want_int(f[0], "robot id", 0, 0xFFFF), seq, want_float(f[2], "time", 0.0),
            angles_from_wire(f[3], f[4], "commanded"), angles_from_wire(f[5], f[6], "measured"),
            ref, extras,
        )


def models_packet(
    fits: Mapping[tuple[int, int], FitResult], *, robot_id: int, seq: int, time: float,
    commanded: tuple[float, float], measured: tuple[float, float], feature_space: str,
    bands: Sequence[str], levels: int = 256,
    censored: Mapping[int, tuple[float, float]] | None = None,
    extras: Mapping[str, Any] | None = None,
) -> ModelsPacket:
    """Build a MODELS packet from the fitter's results keyed by (label, band index)."""
    codec = PercentileCodec.for_levels(levels)
    censored = censored or {}
    stray = set(censored) - {lab for lab, _ in fits}
    if stray:
        raise ValueError(f"censored fractions for labels without models: {sorted(stray)}")
    records = []
    for label in sorted({lab for lab, _ in fits}):
        per_band = [fits.get((label, b)) for b in range(len(bands))]
        if any(r is None for r in per_band):
            raise ValueError(f"label {label} lacks a model for some of the {len(bands)} bands")
        if len({r.count for r in per_band}) != 1:
            raise ValueError(f"label {label}: bands disagree on pixel count")
        for r in per_band:
            if r.z not in Z_LADDER:
                raise ValueError(f"label {label}: z = {r.z} is not on the z ladder")
        plain = [r for r in per_band if not _special(r)]
        z = (plain or per_band)[0].z
        override = censored.get(label)
        if override is not None:
            for v in override:
                _censor_code(v)
        records.append(LabelModels(
            label, int(per_band[0].count), Z_LADDER.index(z),
            tuple(tuple(int(c) for c in codec.encode(r.percentiles)) for r in per_band),
            tuple(_tail_of(r, z, override, codec) for r in per_band),
        ))
    if len(fits) != len(records) * len(bands):
        raise ValueError("fits hold band indices outside the band list")
    return ModelsPacket(
        robot_id, seq, time, tuple(commanded), tuple(measured), feature_space, tuple(bands),
        levels, tuple(records), dict(extras or {}),
    )


def _special(r: FitResult) -> bool:
    return bool(r.shift or r.censored_low or r.censored_high or r.fallback or r.support)


def _tail_of(r: FitResult, label_z: float, override: tuple[float, float] | None,
             codec: PercentileCodec) -> Tail | None:
    """The record a model needs beyond its label's fields, or None for a plain model. The
    `censored` override of models_packet annotates fits that measured no censoring."""
    low, high = r.censored_low, r.censored_high
    if override is not None and not (low or high or r.fallback):
        low, high = override
    if not (r.z != label_z or r.shift or low or high or r.fallback or r.support):
        return None
    ends = (None, None) if r.support is None else tuple(
        None if v is None else _level_of(v, side, codec) for side, v in enumerate(r.support))
    code = round(r.shift * SHIFT_SCALE)
    if code / SHIFT_SCALE != r.shift or abs(code) > MAX_SHIFT_CODE:
        raise ValueError(f"shift {r.shift} is not a multiple of 1/{SHIFT_SCALE} within the int8 range")
    if r.fallback and (_censor_code(low) / CENSOR_SCALE, _censor_code(high) / CENSOR_SCALE) != (low, high):
        raise ValueError("a fallback model needs its censored fractions in 1/65535 fixed point")
    return Tail(Z_LADDER.index(r.z), code, float(low), float(high), bool(r.fallback), *ends)


def _level_of(point: float, side: int, codec: PercentileCodec) -> int:
    level = round(point + 0.5 - side)
    if support_point(level, side, codec) != point:
        raise ValueError(f"support point {point} is not a level")
    return level


def _tail_bytes(index: int, t: Tail, code: struct.Struct) -> bytes:
    flags = TailFlag(0)
    out = b""
    if t.z_index or t.shift_code or t.censored_low or t.censored_high or t.fallback:
        flags |= TailFlag.CENSORED | (TailFlag.FALLBACK if t.fallback else 0)
        out += _CENSOR.pack(t.z_index, t.shift_code, _censor_code(t.censored_low), _censor_code(t.censored_high))
    if t.support_low is not None:
        flags |= TailFlag.SUPPORT_LOW
        out += code.pack(t.support_low)
    if t.support_high is not None:
        flags |= TailFlag.SUPPORT_HIGH
        out += code.pack(t.support_high)
    return _TAIL_HEAD.pack(index << 4 | int(flags)) + out


def _tails(v: Any, n: int, n_bands: int, code: struct.Struct, levels: int) -> list[tuple[Tail | None, ...]]:
    out: list[list[Tail | None]] = [[None] * n_bands for _ in range(n)]
    if v is None:
        return [tuple(t) for t in out]
    blob = want_bin(v, "censored and support records")
    pos, last = 0, -1
    while pos < len(blob):
        if pos + _TAIL_HEAD.size > len(blob):
            raise FrameError("censored and support records end inside a record")
        (head,) = _TAIL_HEAD.unpack_from(blob, pos)
        index, flags = head >> 4, head & 0xF
        pos += _TAIL_HEAD.size
        if index <= last or index >= n * n_bands:
            raise FrameError(f"censored record for model {index}: out of order or past {n * n_bands} models")
        if not flags or (flags & TailFlag.FALLBACK and not flags & TailFlag.CENSORED):
            raise FrameError(f"censored record for model {index} has bad flags {flags:#x}")
        last = index
        z_index, shift, low, high, ends = 0, 0, 0, 0, [None, None]
        if flags & TailFlag.CENSORED:
            if pos + _CENSOR.size > len(blob):
                raise FrameError("censored and support records end inside a record")
            z_index, shift, low, high = _CENSOR.unpack_from(blob, pos)
            pos += _CENSOR.size
            if z_index >= len(Z_LADDER):
                raise FrameError(f"censored record: z ladder index {z_index} outside 0..{len(Z_LADDER) - 1}")
            if abs(shift) > MAX_SHIFT_CODE:
                raise FrameError(f"censored record: shift code {shift} outside +-{MAX_SHIFT_CODE}")
            if low + high > CENSOR_SCALE + 1:  # two halves may each round up
                raise FrameError("censored fractions of a model add up to more than 1")
        for side, flag in enumerate((TailFlag.SUPPORT_LOW, TailFlag.SUPPORT_HIGH)):
            if flags & flag:
                if pos + code.size > len(blob):
                    raise FrameError("censored and support records end inside a record")
                (ends[side],) = code.unpack_from(blob, pos)
                pos += code.size
                if ends[side] >= levels:
                    raise FrameError(f"censored record: support level {ends[side]} outside 0..{levels - 1}")
        out[index // n_bands][index % n_bands] = Tail(
            z_index, shift, low / CENSOR_SCALE, high / CENSOR_SCALE, bool(flags & TailFlag.FALLBACK), *ends)
    return [tuple(t) for t in out]


def _recompute(packet: ModelsPacket, codec: PercentileCodec) -> dict[tuple[int, int], Johnson]:
    out = {}
    for rec in packet.labels:
        for band, codes in enumerate(rec.codes):
            t = rec.tail(band)
            z = Z_LADDER[rec.z_index if t is None or not _placed(t) else t.z_index]
            kw: dict[str, Any] = {}
            if t is not None:
                kw["shift"] = t.shift_code / SHIFT_SCALE
                if t.fallback:
                    kw["normal_probs"] = fallback_probs(t.censored_low, t.censored_high)
                if t.support_low is not None or t.support_high is not None:
                    kw["support"] = tuple(None if v is None else support_point(v, side, codec)
                                          for side, v in enumerate((t.support_low, t.support_high)))
            try:
                model = model_from_percentiles(codec.decode(codes), z, rec.count, **kw)
            except (ValueError, ArithmeticError) as exc:
                raise FrameError(f"label {rec.label} band {band}: no model from codes {codes}: {exc}") from None
            out[(rec.label, band)] = model
    return out


def _placed(t: Tail) -> bool:
    return bool(t.z_index or t.shift_code or t.censored_low or t.censored_high or t.fallback)


def _censor_code(fraction: float) -> int:
    if not (math.isfinite(fraction) and 0.0 <= fraction <= 1.0):
        raise ValueError(f"censored fraction {fraction} outside [0, 1]")
    return round(fraction * CENSOR_SCALE)
