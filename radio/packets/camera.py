"""The MODELS blob's camera section: what the capture was taken with (`btf.capture_settings`).

Flagged by bit 6 of the blob's label-bitmap length byte, it follows the dependence section
(before the model records). Layout, big-endian, each field present only when its flag is set:
  flags    schema 5: a varint (one byte below 0x80); schemas 3 and 4: one byte. 0x01 unlocked,
           0x02 exposure, 0x04 gain, 0x08 white balance in kelvin, 0x10 white balance gains,
           0x20 sensor temperature, 0x40 reference, 0x80 brackets, 0x100 source (schema 5)
  exposure varint, µs
  gain     varint, 1/256 steps
  kelvin   varint, K
  gains    two varints (red, blue), 1/1024 steps
  sensor   >h, 1/100 °C
  reference  one byte: the clipped share of its pixels in 1/255 steps; then per band the
           level as a percentile code of the capture's codec (2 bytes for 8-bit sensors)
  brackets one byte n (1..MAX_BRACKETS), n exposure varints (µs); one byte m, then m pairs
           (label id, 1-based bracket index), labels strictly increasing and in the capture
  source   one byte n (1..64), n bytes of printable UTF-8: the file the frame was read from
A locked capture without reference, brackets or source costs 10 bytes (flags, exposure 3, gain 2,
kelvin 2, sensor 2); at schema 5 brackets or a source add one byte of flags.
"""
from __future__ import annotations

import dataclasses
import struct

from btf.capture_settings import MAX_BRACKETS, MAX_SOURCE, CaptureSettings
from btf.codec import PercentileCodec
from radio import FrameError
from radio.varint import get_varint, put_varint

UNLOCKED, EXPOSURE, GAIN, KELVIN, GAINS, SENSOR, REFERENCE, BRACKETS, SOURCE = (1 << i for i in range(9))
VARINT_FLAGS = 5  # the schema version from which the flags are a varint (and may carry SOURCE)
GAIN_SCALE, WB_GAIN_SCALE, SENSOR_SCALE, CLIPPED_SCALE = 256, 1024, 100, 255
MAX_EXPOSURE_US = 2**32 - 1  # about 72 minutes
_SENSOR = struct.Struct(">h")


def _scaled_int(value: float, scale: int, name: str, hi: int = 2**32 - 1) -> int:
    code = round(value * scale)
    if not 0 <= code <= hi:
        raise ValueError(f"camera {name} {value} does not fit the wire (0..{hi / scale:g})")
    return code


def held_by_wire(s: CaptureSettings) -> CaptureSettings:
    """`s` with any value its field cannot carry (a device reporting nonsense) as None: not reported."""
    def within(v: float | None, scale: int, lo: float = 0.0, hi: float = 2**32 - 1) -> float | None:
        return v if v is not None and lo <= round(v * scale) <= hi else None

    gains = s.white_balance_gains
    return dataclasses.replace(
        s, exposure_us=within(s.exposure_us, 1), gain=within(s.gain, GAIN_SCALE),
        white_balance_kelvin=within(s.white_balance_kelvin, 1),
        white_balance_gains=gains if gains is not None and all(within(g, WB_GAIN_SCALE) is not None for g in gains)
        else None,
        sensor_temperature_c=within(s.sensor_temperature_c, SENSOR_SCALE, -32768, 32767))


def encode_camera(s: CaptureSettings, n_bands: int, codec: PercentileCodec, label_ids: list[int],
                  version: int = VARINT_FLAGS) -> bytes:
    """The section's bytes for `s` at schema `version` (ValueError when a value does not fit its
    field, or the version has no field for it)."""
    flags = UNLOCKED if s.unlocked else 0
    out = bytearray()
    if s.exposure_us is not None:
        flags |= EXPOSURE
        put_varint(out, _scaled_int(s.exposure_us, 1, "exposure"))
    if s.gain is not None:
        flags |= GAIN
        put_varint(out, _scaled_int(s.gain, GAIN_SCALE, "gain"))
    if s.white_balance_kelvin is not None:
        flags |= KELVIN
        put_varint(out, _scaled_int(s.white_balance_kelvin, 1, "white balance"))
    if s.white_balance_gains is not None:
        flags |= GAINS
        for g in s.white_balance_gains:
            put_varint(out, _scaled_int(g, WB_GAIN_SCALE, "white balance gain"))
    if s.sensor_temperature_c is not None:
        flags |= SENSOR
        code = round(s.sensor_temperature_c * SENSOR_SCALE)
        if not -32768 <= code <= 32767:
            raise ValueError(f"sensor temperature {s.sensor_temperature_c} C does not fit the wire")
        out += _SENSOR.pack(code)
    if s.reference is not None:
        if len(s.reference) != n_bands:
            raise ValueError(f"reference has {len(s.reference)} levels for {n_bands} bands")
        flags |= REFERENCE
        out.append(round(s.reference_clipped * CLIPPED_SCALE))
        out += b"".join(int(c).to_bytes(codec.bits // 8, "big") for c in codec.encode(list(s.reference)))
    if s.brackets:
        flags |= BRACKETS
        out.append(len(s.brackets))
        for e in s.brackets:
            put_varint(out, _scaled_int(e, 1, "bracket exposure"))
        stray = set(s.bracketed) - set(label_ids)
        if stray:
            raise ValueError(f"bracketed labels {sorted(stray)} have no models in the capture")
        out.append(len(s.bracketed))
        for label in sorted(s.bracketed):
            out += bytes((label, s.bracketed[label]))
    if s.source is not None:
        if version < VARINT_FLAGS:
            raise ValueError(f"camera source needs schema {VARINT_FLAGS}")
        flags |= SOURCE
        raw = s.source.encode("utf-8")
        out.append(len(raw))
        out += raw
    if version < VARINT_FLAGS:
        return bytes((flags,)) + bytes(out)
    head = bytearray()
    put_varint(head, flags)
    return bytes(head) + bytes(out)


def _byte(blob: bytes, pos: int, name: str) -> tuple[int, int]:
    if pos >= len(blob):
        raise FrameError(f"camera section ends inside its {name}")
    return blob[pos], pos + 1


def _varint(blob: bytes, pos: int, name: str, scale: int = 1) -> tuple[float, int]:
    v, pos = get_varint(blob, pos, f"camera {name}", 5)
    if v > MAX_EXPOSURE_US:
        raise FrameError(f"camera {name} code {v} is out of range")
    return v / scale, pos


def decode_camera(blob: bytes, pos: int, n_bands: int, codec: PercentileCodec,
                  label_ids: list[int], version: int = VARINT_FLAGS) -> tuple[CaptureSettings, int]:
    """(the settings, the position after the section) of a schema-`version` body; FrameError
    naming the bad field."""
    if version < VARINT_FLAGS:
        flags, pos = _byte(blob, pos, "flags")
    else:
        if pos >= len(blob):
            raise FrameError("camera section ends inside its flags")
        flags, pos = get_varint(blob, pos, "camera flags", 2)
        if flags >= SOURCE << 1:
            raise FrameError(f"camera flags 0x{flags:x} name fields this schema does not have")
    values: dict = {"unlocked": bool(flags & UNLOCKED)}
    if flags & KELVIN and flags & GAINS:
        raise FrameError("camera section gives both a white balance temperature and gains")
    if flags & EXPOSURE:
        values["exposure_us"], pos = _varint(blob, pos, "exposure")
    if flags & GAIN:
        values["gain"], pos = _varint(blob, pos, "gain", GAIN_SCALE)
    if flags & KELVIN:
        values["white_balance_kelvin"], pos = _varint(blob, pos, "white balance")
    if flags & GAINS:
        red, pos = _varint(blob, pos, "white balance red gain", WB_GAIN_SCALE)
        blue, pos = _varint(blob, pos, "white balance blue gain", WB_GAIN_SCALE)
        values["white_balance_gains"] = (red, blue)
    if flags & SENSOR:
        if pos + _SENSOR.size > len(blob):
            raise FrameError("camera section ends inside its sensor temperature")
        values["sensor_temperature_c"] = _SENSOR.unpack_from(blob, pos)[0] / SENSOR_SCALE
        pos += _SENSOR.size
    if flags & REFERENCE:
        clipped, pos = _byte(blob, pos, "reference")
        width = codec.bits // 8
        if pos + width * n_bands > len(blob):
            raise FrameError("camera section ends inside its reference levels")
        codes = [int.from_bytes(blob[pos + width * b:pos + width * (b + 1)], "big") for b in range(n_bands)]
        pos += width * n_bands
        values["reference"] = tuple(max(0.0, float(v)) for v in codec.decode(codes))
        values["reference_clipped"] = clipped / CLIPPED_SCALE
    if flags & BRACKETS:
        values["brackets"], values["bracketed"], pos = _brackets(blob, pos, label_ids, "exposure_us" in values)
    if flags & SOURCE:
        values["source"], pos = _source(blob, pos)
    try:
        return CaptureSettings(**values), pos
    except ValueError as exc:
        raise FrameError(str(exc)) from None


def _brackets(blob: bytes, pos: int, label_ids: list[int],
              has_exposure: bool) -> tuple[tuple[float, ...], dict[int, int], int]:
    n, pos = _byte(blob, pos, "bracket count")
    if not 1 <= n <= MAX_BRACKETS or not has_exposure:
        raise FrameError(f"camera brackets: {n} exposures (1..{MAX_BRACKETS}, with the capture's own)")
    exposures = []
    for _ in range(n):
        e, pos = _varint(blob, pos, "bracket exposure")
        if e <= 0:
            raise FrameError("camera bracket exposure of 0 us")
        exposures.append(e)
    m, pos = _byte(blob, pos, "bracketed label count")
    if pos + 2 * m > len(blob):
        raise FrameError("camera section ends inside its bracketed labels")
    pairs = [(blob[pos + 2 * i], blob[pos + 2 * i + 1]) for i in range(m)]
    labels = [lab for lab, _ in pairs]
    if any(a >= b for a, b in zip(labels, labels[1:])) or not set(labels) <= set(label_ids):
        raise FrameError(f"camera bracketed labels {labels} not increasing or not in the capture")
    if any(not 1 <= i <= n for _, i in pairs):
        raise FrameError(f"camera bracketed label names a bracket outside 1..{n}")
    return tuple(exposures), dict(pairs), pos + 2 * m


def _source(blob: bytes, pos: int) -> tuple[str, int]:
    n, pos = _byte(blob, pos, "source length")
    if not 1 <= n <= MAX_SOURCE or pos + n > len(blob):
        raise FrameError(f"camera source of {n} bytes: 1..{MAX_SOURCE}, within the section")
    try:
        text = blob[pos:pos + n].decode("utf-8")
    except UnicodeDecodeError:
        raise FrameError("camera source is not UTF-8") from None
    if not text.isprintable():
        raise FrameError("camera source holds unprintable characters")
    return text, pos + n
