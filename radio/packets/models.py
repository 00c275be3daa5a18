"""MODELS packets: one capture's Johnson models; UNCHANGED, the note that nothing moved since
capture `ref_seq` at the same pose.

A model travels as its four Slifker-Shapiro percentiles x(-3z), x(-z), x(z), x(3z) in the
fitter's fixed point (`PercentileCodec.for_levels(levels)`: 16-bit codes for 8-bit sensors,
32-bit for deeper ones). The label's pixel count and z-ladder index are shared by its bands.
The receiver recomputes each model with `model_from_percentiles`, exactly as the robot did, so
the host's models equal the robot's bit for bit. Fixed point costs, for 8-bit sensors, a step
of 2**-8 gray level: every percentile is within 2**-9 < 0.01 gray level of the fitter's value.

Wire fields after [version, kind]:
  MODELS    robot, seq, time, feature_space, [bands], blob [, extras]
  UNCHANGED robot, seq, time, cmd_el, cmd_az, meas_el, meas_az, ref_seq [, extras]
Angles are integer centidegrees (0.01 degree); censored fractions are 1/65535 fixed point.

The MODELS blob, big-endian, msgpack's per-field bytes saved where they add up:
  angles   >hHhH commanded and measured (elevation, azimuth)
  levels   >H levels - 1
  labels   one byte: nb (0..32) in the low 6 bits, bit 7 set when a dependence section
           follows the codes, bit 6 when a camera section does; an nb-byte bitmap of the
           label ids present (bit i of byte j: label 8j + i; the last byte non-zero), then per
           label, in id order, the varint (LEB128) of count * 16 + z index
  codes    per label, per band, four codes (>H up to 256 levels, else >I)
  dependence  when flagged: per label, its observed levels and (when measured) its grain and
           band correlation (`radio.packets.dependence`: a versioned section, 93 bytes per
           RGB label at the robot's window; robots before the version sent 11); never flagged
           empty
  camera   when flagged: the capture's camera settings, reference level, brackets and (schema
           5) the frame's source file (`radio.packets.camera`, 10 bytes for a locked capture
           without any of these)
  records  (`radio.packets.records`) absent when every model is plain; else 2 bits per model (model i at bits 2(i%4) of
           byte i//4): 0 plain, 1 a read byte, 2 never, 3 a flagged record; then, for each
           non-plain model in order, for 1 the read byte (bits 0-3 z index, bits 4-5 the
           shift: 0, -1/2, +1/2, bit 6 the exact family rule, bit 7 zero), for 3 a flag byte
           (TailFlag) and its fields in flag order: z index B, shift b (1/32), censored low H,
           censored high H.
A model is plain when it was read at its label's z, unshifted, with the SL band and nothing
censored; the fitter chooses among a few reads per region (btf.fit.reads), so a model read
another way costs its 8 bytes, 2 bits and one byte. Dependence costs its section (3 bytes of
header and 2 bits a label, then the records) and no header beyond the flag bit, plus one byte
of the blob's msgpack header when the section pushes it past 255 bytes.
"""
from __future__ import annotations

import struct
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from btf.capture_settings import CaptureSettings
from btf.codec import SHIFT_SCALE, Z_LADDER, PercentileCodec
from btf.dependence import Dependence
from btf.johnson import Johnson
from btf.record import FittedModel
from radio import FrameError
from radio.packets.base import (
    MAX_BANDS,
    MAX_FRAME_PIXELS,
    MAX_LABELS,
    MAX_LEVELS,
    MAX_NAME,
    MIN_LEVELS,
    UINT32,
    Kind,
    angles_from_wire,
    angles_to_wire,
    want_int,
)
from radio.packets.camera import VARINT_FLAGS, decode_camera, encode_camera
from radio.packets.dependence import decode_dependence, encode_dependence, quantized
from radio.packets.records import Tail, censor_code, read_tails, tail_bytes, tail_of
from radio.packets.schema import Angles, Bin, Declared, Field, Int, ListOf, Text, wire
from radio.packets.status import TIME
from radio.varint import get_varint, put_varint

_HEAD = struct.Struct(">hHhHH")  # angles, levels - 1
_Z_BITS = 4  # z index in the low bits of a label's count varint
_HAS_DEPENDENCE = 0x80  # in the bitmap length byte
_HAS_CAMERA = 0x40
_NB_MASK = 0x3F


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

    def censored(self, band: int) -> tuple[float, float]:
        """(low, high): the fractions of this band's pixels censored at each sensor limit."""
        t = self.tail(band)
        return (0.0, 0.0) if t is None else (t.censored_low, t.censored_high)


ROBOT = Int(0, 0xFFFF)
SEQ = Int(0, UINT32)
NAME = Text(MAX_NAME, empty=False)


@dataclass(frozen=True, slots=True)
class ModelsPacket(Declared):
    """One capture's models: the header fields, then one blob (`radio/packets/models.py` gives its layout)."""

    KIND: ClassVar[Kind] = Kind.MODELS
    BYTES_SINCE: ClassVar[int] = VARINT_FLAGS  # the blob's camera section grew a source
    WIRE: ClassVar[tuple[Field, ...]] = (
        Field("robot_id", ROBOT, "the robot", label="robot id"),
        Field("seq", SEQ, "the capture's number", label="capture seq"),
        Field("time", TIME, "the robot's clock at the capture, seconds since 1970"),
        Field("feature_space", NAME, "rgb, hsv, gray, pca, ...", label="feature space"),
        Field("bands", ListOf(NAME, MAX_BANDS, 1), "band names, distinct", label="band name"),
        Field("blob", Bin(), "angles, levels, labels, codes, dependence, camera and records (above)",
              label="models blob"),
    )
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
    # Observed levels, grain and band correlation per label id, for some or all labels (empty: none).
    dependence: Mapping[int, Dependence] = field(default_factory=dict)
    camera: CaptureSettings | None = None  # what the capture was taken with (None: not sent)
    # Filled by decode: (label, band index) -> the record, its model recomputed from the codes.
    fits: Mapping[tuple[int, int], FittedModel] = field(default_factory=dict, compare=False, repr=False)

    @property
    def models(self) -> dict[tuple[int, int], Johnson]:
        """(label, band index) -> the decoded model."""
        return {k: f.model for k, f in self.fits.items()}

    def wire_values(self) -> dict[str, Any]:
        return {"robot_id": self.robot_id, "seq": self.seq, "time": self.time, "feature_space": self.feature_space,
                "bands": self.bands, "blob": self._blob()}

    def _blob(self) -> bytes:
        if not MIN_LEVELS <= self.levels <= MAX_LEVELS:
            raise ValueError(f"levels {self.levels} outside [{MIN_LEVELS}, {MAX_LEVELS}]")
        codec = PercentileCodec.for_levels(self.levels)
        out = bytearray(_HEAD.pack(*angles_to_wire(self.commanded, "commanded"),
                                   *angles_to_wire(self.measured, "measured"), self.levels - 1))
        ids = [x.label for x in self.labels]
        if any(not 0 <= a < MAX_LABELS for a in ids) or any(a >= b for a, b in zip(ids, ids[1:])):
            raise ValueError(f"label ids must be strictly increasing in [0, {MAX_LABELS - 1}], got {ids}")
        bitmap = bytearray(ids[-1] // 8 + 1 if ids else 0)
        for a in ids:
            bitmap[a // 8] |= 1 << (a % 8)
        out.append(len(bitmap) | (_HAS_DEPENDENCE if self.dependence else 0)
                   | (_HAS_CAMERA if self.camera is not None else 0))
        out += bitmap
        for x in self.labels:
            if not (0 <= x.count <= MAX_FRAME_PIXELS and 0 <= x.z_index < len(Z_LADDER)):
                raise ValueError(f"label {x.label}: count {x.count} or z index {x.z_index} out of range")
            put_varint(out, x.count << _Z_BITS | x.z_index)
        dtype = ">u2" if codec.bits <= 16 else ">u4"
        codes = np.array([c for lab in self.labels for c in lab.codes], dtype=np.int64).reshape(-1)
        if codes.size != len(self.labels) * len(self.bands) * 4:
            raise ValueError("every label needs four codes per band")
        if codes.size and (codes.min() < 0 or codes.max() > np.iinfo(dtype).max):
            raise ValueError(f"percentile codes do not fit {dtype}")
        out += codes.astype(dtype).tobytes()
        if self.dependence:
            out += encode_dependence(self.dependence, ids, len(self.bands), self.levels)
        if self.camera is not None:
            out += encode_camera(self.camera, len(self.bands), codec, ids, self.BYTES_SINCE)
        entries = [tail_bytes(t, lab.z_index) for lab in self.labels
                   for t in (lab.tails + (None,) * len(self.bands))[:len(self.bands)]]
        if any(c for c, _ in entries):
            marks = bytearray((len(entries) + 3) // 4)
            for i, (c, _) in enumerate(entries):
                marks[i // 4] |= c << (2 * (i % 4))
            out += marks + b"".join(b for _, b in entries)
        return bytes(out)

    @classmethod
    def from_values(cls, values: dict[str, Any], extras: dict, version: int, compute: bool = True) -> ModelsPacket:
        robot, seq, t, space, bands = (values[k] for k in ("robot_id", "seq", "time", "feature_space", "bands"))
        if len(set(bands)) != len(bands):
            raise FrameError("band names repeat")
        blob = values["blob"]
        if len(blob) < _HEAD.size + 1:
            raise FrameError("models blob is shorter than its header")
        cel, caz, mel, maz, levels = _HEAD.unpack_from(blob)
        commanded = angles_from_wire(cel, caz, "commanded")
        measured = angles_from_wire(mel, maz, "measured")
        levels = want_int(levels + 1, "levels", MIN_LEVELS, MAX_LEVELS)
        codec = PercentileCodec.for_levels(levels)
        has_dependence = bool(blob[_HEAD.size] & _HAS_DEPENDENCE)
        has_camera = bool(blob[_HEAD.size] & _HAS_CAMERA)
        ids, pos = _label_ids(blob, _HEAD.size)
        heads = []
        for label in ids:
            v, pos = get_varint(blob, pos, "label count", 6)
            count, z_index = v >> _Z_BITS, v & ((1 << _Z_BITS) - 1)
            want_int(count, f"label {label} pixel count", 0, MAX_FRAME_PIXELS)
            if z_index >= len(Z_LADDER):
                raise FrameError(f"z ladder index {z_index} outside 0..{len(Z_LADDER) - 1}")
            heads.append((label, count, z_index))
        n, n_bands = len(ids), len(bands)
        width = 2 if codec.bits <= 16 else 4
        size = n * n_bands * 4 * width
        if pos + size > len(blob):
            raise FrameError(f"codes blob has {len(blob) - pos} bytes, expected {size}")
        codes = np.frombuffer(blob, dtype=">u2" if width == 2 else ">u4", count=size // width,
                              offset=pos).astype(np.int64).reshape(n, n_bands, 4)
        if np.any(np.diff(codes, axis=2) < 0):
            raise FrameError("percentile codes decrease within a model")
        pos += size
        dependence: dict[int, Dependence] = {}
        if has_dependence:
            dependence, pos = decode_dependence(blob, ids, n_bands, levels, pos)
        camera = None
        if has_camera:
            camera, pos = decode_camera(blob, pos, n_bands, codec, ids, version)
        tails = read_tails(blob, pos, [z for _, _, z in heads], n_bands)
        records = tuple(
            LabelModels(label, count, z_index, tuple(tuple(int(c) for c in m) for m in codes[i]), tails[i])
            for i, (label, count, z_index) in enumerate(heads))
        packet = cls(robot, seq, t, commanded, measured, space, bands, levels, records, extras, dependence, camera)
        if compute:
            object.__setattr__(packet, "fits", _recompute(packet, codec))
        return packet


@dataclass(frozen=True, slots=True)
class UnchangedPacket(Declared):
    """A capture whose models all lie within tolerance of capture `ref_seq` at the same pose."""

    KIND: ClassVar[Kind] = Kind.UNCHANGED
    robot_id: int = wire(ROBOT, "the robot", label="robot id")
    seq: int = wire(SEQ, "the capture's number", label="capture seq")
    time: float = wire(TIME, "the robot's clock at the capture, seconds since 1970")
    commanded: tuple[float, float] = wire(Angles(), "the pose it was sent to")
    measured: tuple[float, float] = wire(Angles(), "the pose it measured")
    ref_seq: int = wire(SEQ, "the earlier capture whose models these are", label="reference seq")
    extras: Mapping[str, Any] = field(default_factory=dict)

    def problem(self) -> str:
        return "" if self.ref_seq < self.seq else f"reference capture {self.ref_seq} is not before capture {self.seq}"


def models_packet(
    fits: Mapping[tuple[int, int], FittedModel], *, robot_id: int, seq: int, time: float,
    commanded: tuple[float, float], measured: tuple[float, float], feature_space: str,
    bands: Sequence[str], levels: int = 256,
    censored: Mapping[int, tuple[float, float]] | None = None,
    extras: Mapping[str, Any] | None = None,
    dependence: Mapping[int, Dependence] | None = None,
    camera: CaptureSettings | None = None,
) -> ModelsPacket:
    """Build a MODELS packet from the fitter's results keyed by (label, band index);
    `dependence` (per label, optional) is stored as the host will receive it (int8 steps);
    `camera` is what the capture was taken with."""
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
        simple = [r.z for r in per_band if not _special(r)] or [per_band[0].z]
        z = max(simple, key=simple.count)  # the commonest: its models travel free
        override = censored.get(label)
        if override is not None:
            for v in override:
                censor_code(v)
        records.append(LabelModels(
            label, int(per_band[0].count), Z_LADDER.index(z),
            tuple(tuple(int(c) for c in codec.encode(r.percentiles)) for r in per_band),
            tuple(tail_of(r, z, override) for r in per_band),
        ))
    if len(fits) != len(records) * len(bands):
        raise ValueError("fits hold band indices outside the band list")
    ids = [x.label for x in records]
    return ModelsPacket(
        robot_id, seq, time, tuple(commanded), tuple(measured), feature_space, tuple(bands),
        levels, tuple(records), dict(extras or {}),
        quantized(dependence, ids, len(bands), levels) if dependence else {}, camera,
    )


def _special(r: FittedModel) -> bool:
    return bool(r.shift or r.censored_low or r.censored_high or r.fallback or r.exact_family)


def _label_ids(blob: bytes, pos: int) -> tuple[list[int], int]:
    nb = blob[pos] & _NB_MASK
    pos += 1
    if nb > MAX_LABELS // 8 or pos + nb > len(blob) or (nb and not blob[pos + nb - 1]):
        raise FrameError(f"label bitmap of {nb} bytes: too long, cut short or not canonical")
    ids = [8 * j + i for j in range(nb) for i in range(8) if blob[pos + j] >> i & 1]
    return ids, pos + nb


def _recompute(packet: ModelsPacket, codec: PercentileCodec) -> dict[tuple[int, int], FittedModel]:
    out = {}
    for rec in packet.labels:
        for band, codes in enumerate(rec.codes):
            t = rec.tail(band) or Tail(rec.z_index)
            try:
                out[(rec.label, band)] = FittedModel.solve(
                    codec.decode(codes), Z_LADDER[t.z_index], rec.count, shift=t.shift_code / SHIFT_SCALE,
                    censored_low=t.censored_low, censored_high=t.censored_high, fallback=t.fallback,
                    exact_family=t.exact_family)
            except (ValueError, ArithmeticError) as exc:
                raise FrameError(f"label {rec.label} band {band}: no model from codes {codes}: {exc}") from None
    return out
