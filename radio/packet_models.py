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
            codes_blob (per label, per band, 4 codes), censored (nil | >HH per label) [, extras]
  UNCHANGED robot, seq, time, cmd_el, cmd_az, meas_el, meas_az, ref_seq [, extras]
Angles are integer centidegrees (0.01 degree); censored fractions are 1/65535 fixed point.
"""
from __future__ import annotations

import math
import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from onboard.fit import Z_LADDER, FitResult, PercentileCodec, model_from_percentiles
from onboard.johnson import Johnson
from radio import FrameError
from radio.packet_base import (
    UINT32, Kind, angles_from_wire, angles_to_wire, want_bin, want_float, want_int, want_str,
)

MAX_LABELS = 256
MAX_BANDS = 16
MAX_NAME = 16
MIN_LEVELS, MAX_LEVELS = 2, 65536  # PercentileCodec.for_levels' range
CENSOR_SCALE = 65535
_LABEL = struct.Struct(">BBI")
_CENSOR = struct.Struct(">HH")


@dataclass(frozen=True, slots=True)
class LabelModels:
    """One region's wire record: shared fields, then four percentile codes per band."""

    label: int
    count: int
    z_index: int
    codes: tuple[tuple[int, int, int, int], ...]
    censored_low: float = 0.0
    censored_high: float = 0.0


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
        censored = None
        if any(x.censored_low or x.censored_high for x in self.labels):
            censored = b"".join(
                _CENSOR.pack(_censor_code(x.censored_low), _censor_code(x.censored_high))
                for x in self.labels
            )
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
        censored = _censored(f[12], n)
        records, last = [], -1
        for i, (label, z_index, count) in enumerate(_LABEL.iter_unpack(label_blob)):
            if label <= last:
                raise FrameError("label ids must be strictly increasing")
            last = label
            if z_index >= len(Z_LADDER):
                raise FrameError(f"z ladder index {z_index} outside 0..{len(Z_LADDER) - 1}")
            records.append(LabelModels(
                label, count, z_index, tuple(tuple(int(c) for c in m) for m in codes[i]),
                *censored[i],
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
        if len({r.count for r in per_band}) != 1 or len({r.z for r in per_band}) != 1:
            raise ValueError(f"label {label}: bands disagree on pixel count or z")
        if per_band[0].z not in Z_LADDER:
            raise ValueError(f"label {label}: z = {per_band[0].z} is not on the z ladder")
        low, high = censored.get(label, (0.0, 0.0))
        records.append(LabelModels(
            label, int(per_band[0].count), Z_LADDER.index(per_band[0].z),
            tuple(tuple(int(c) for c in codec.encode(r.percentiles)) for r in per_band),
            float(low), float(high),
        ))
    if len(fits) != len(records) * len(bands):
        raise ValueError("fits hold band indices outside the band list")
    return ModelsPacket(
        robot_id, seq, time, tuple(commanded), tuple(measured), feature_space, tuple(bands),
        levels, tuple(records), dict(extras or {}),
    )


def _recompute(packet: ModelsPacket, codec: PercentileCodec) -> dict[tuple[int, int], Johnson]:
    out = {}
    for rec in packet.labels:
        z = Z_LADDER[rec.z_index]
        for band, codes in enumerate(rec.codes):
            try:
                model = model_from_percentiles(codec.decode(codes), z, rec.count)
            except (ValueError, ArithmeticError) as exc:
                raise FrameError(f"label {rec.label} band {band}: no model from codes {codes}: {exc}") from None
            out[(rec.label, band)] = model
    return out


def _censor_code(fraction: float) -> int:
    if not (math.isfinite(fraction) and 0.0 <= fraction <= 1.0):
        raise ValueError(f"censored fraction {fraction} outside [0, 1]")
    return round(fraction * CENSOR_SCALE)


def _censored(v: Any, n: int) -> list[tuple[float, float]]:
    if v is None:
        return [(0.0, 0.0)] * n
    blob = want_bin(v, "censored")
    if len(blob) != n * _CENSOR.size:
        raise FrameError(f"censored blob has {len(blob)} bytes, expected {n * _CENSOR.size}")
    out = []
    for low, high in _CENSOR.iter_unpack(blob):
        if low + high > CENSOR_SCALE + 1:  # two halves may each round up
            raise FrameError("censored fractions of a label add up to more than 1")
        out.append((low / CENSOR_SCALE, high / CENSOR_SCALE))
    return out
