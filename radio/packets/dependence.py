"""The dependence section of a MODELS blob: per label, its observed levels, grain and band correlation.

Version 1 (what robots send while every lag is measured):
  marker   0x80, then the version byte 1 (no section of the older layout starts so: a record
           of it that begins with -128 is all -128)
  shape    one byte: bits 0-3 the window radius R (1..8), bit 4 one autocorrelation row per
           band (else one row, the bands' average), bits 5-7 zero
  kinds    2 bits per label in the packet's label order (label i at bits 2(i % 4) of byte
           i // 4): bit 0 its observed levels follow, bit 1 its grain follows; never 0 for all
  records  per label with a kind, in order: the observed levels, lo for each band then hi for
           each band (uint8 up to 256 levels, else >u2), then the grain: the B(B-1)/2 band
           correlations (upper triangle, row-major) and the autocorrelation at the 2R(R+1) lags
           of btf.dependence.window(R), row by row, each an int8 in steps of 1/127
For RGB at R = 6 with one row, a label costs 6 + 3 + 84 = 93 bytes (gray 2 + 84 = 86, 16-bit
gray 88); its levels alone 6 (gray 2). A record is bounded by its shape: at most
2 x 16 x 2 + 120 + 16 x 144 bytes.

Version 2 (written only when some lag was not measured: too few pixel pairs): version 1's layout
with the version byte 2, where an autocorrelation code -128 is a lag not measured (the record's
`unmeasured`). A band correlation of -128 stays an error, and so does any -128 in version 1.

The older layout (robots before the version): per label 11 bytes for RGB, B(B-1)/2 band
correlations then the autocorrelation at `LAGS` along rows and along columns, all -128 for
"not measured"; decoded into records of the separable window (Dependence.from_lags).

The section sits inside the MODELS blob (`radio.packets.models`), flagged by one bit of the
label bitmap's length byte; its length follows from its header and the labels and bands.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from btf.dependence import LAGS, MAX_RADIUS, Dependence, corr_size, window_size
from radio import FrameError
from radio.packets.base import want_bin

SCALE = 127
ABSENT = -128
MARKER, VERSION = 0x80, 1
GAPS_VERSION = 2  # version 1 plus -128 for a lag not measured
_PER_BAND = 0x10
_RADIUS_MASK = 0x0F
_LEVELS, _GRAIN = 1, 2


def record_size(n_bands: int, radius: int | None = None, levels: int = 256, rows: int = 1,
                grain: bool = True, observed: bool = True) -> int:
    """Bytes of one label's record; radius None: the older layout's."""
    if radius is None:
        return corr_size(n_bands) + 2 * len(LAGS)
    return ((2 * n_bands * (1 if levels <= 256 else 2)) if observed else 0) + (
        corr_size(n_bands) + rows * window_size(radius) if grain else 0)


def _quantize(values: Sequence[float]) -> np.ndarray:
    v = np.asarray(values, dtype=np.float64)
    if not np.all(np.isfinite(v)):
        raise ValueError("dependence values must be finite")
    return np.rint(np.clip(v, -1.0, 1.0) * SCALE).astype(np.int8)


def _shape_of(deps: Mapping[int, Dependence], n_bands: int) -> tuple[int, int]:
    """(radius, rows) every measured record of the section shares."""
    shapes = {(d.radius, len(d.acf)) for d in deps.values() if d.measured}
    if len(shapes) > 1:
        raise ValueError(f"one packet's records need one window and row count, got {sorted(shapes)}")
    radius, rows = shapes.pop() if shapes else (1, 1)
    if rows not in (1, n_bands):
        raise ValueError(f"{rows} autocorrelation rows for {n_bands} bands")
    return radius, rows


def encode_dependence(deps: Mapping[int, Dependence], labels: Sequence[int], n_bands: int,
                      levels: int = 256) -> bytes:
    """The section for `labels` (the packet's order); labels without an entry carry nothing."""
    stray = set(deps) - set(labels)
    if stray:
        raise ValueError(f"dependence for labels the packet does not carry: {sorted(stray)}")
    radius, rows = _shape_of(deps, n_bands)
    version = GAPS_VERSION if any(d.unmeasured for d in deps.values()) else VERSION
    kinds = bytearray((len(labels) + 3) // 4)
    body = bytearray()
    level_type = np.uint8 if levels <= 256 else np.dtype(">u2")
    for i, lab in enumerate(labels):
        dep = deps.get(lab)
        if dep is None:
            continue
        if dep.n_bands != n_bands:
            raise ValueError(f"label {lab}: dependence has {dep.n_bands} bands, packet {n_bands}")
        kind = (_LEVELS if dep.lo else 0) | (_GRAIN if dep.measured else 0)
        kinds[i // 4] |= kind << (2 * (i % 4))
        if dep.lo:
            if max(dep.hi) >= levels:
                raise ValueError(f"label {lab}: observed level {max(dep.hi)} beyond {levels} levels")
            body += np.array(dep.lo + dep.hi).astype(level_type).tobytes()
        if dep.measured:
            codes = _quantize((*dep.corr, *(v for row in dep.acf for v in row)))
            for r, gap in enumerate(dep.unmeasured):
                codes[len(dep.corr) + r * window_size(radius) + np.array(gap, dtype=np.intp)] = ABSENT
            body += codes.tobytes()
    return bytes([MARKER, version, radius | (_PER_BAND if rows > 1 else 0)]) + bytes(kinds) + bytes(body)


def is_versioned(blob: bytes, pos: int) -> bool:
    return len(blob) >= pos + 2 and blob[pos] == MARKER and blob[pos + 1] != MARKER


def decode_dependence(blob: Any, labels: Sequence[int], n_bands: int, levels: int = 256,
                      pos: int = 0) -> tuple[dict[int, Dependence], int]:
    """Untrusted section at `pos` -> ({label: Dependence}, the position after it); either
    layout. FrameError names what is wrong."""
    blob = want_bin(blob, "dependence")
    if not is_versioned(blob, pos):
        end = pos + len(labels) * record_size(n_bands)
        if end > len(blob):
            raise FrameError(f"dependence section has {len(blob) - pos} bytes, expected "
                             f"{len(labels)} labels x {record_size(n_bands)}")
        return _decode_lags(blob[pos:end], labels, n_bands), end
    if len(blob) < pos + 3:
        raise FrameError("dependence section is shorter than its header")
    version, shape = blob[pos + 1], blob[pos + 2]
    if version not in (VERSION, GAPS_VERSION):
        raise FrameError(f"dependence section version {version}; this host reads versions {VERSION} and {GAPS_VERSION}")
    radius, rows = shape & _RADIUS_MASK, (n_bands if shape & _PER_BAND else 1)
    if not 1 <= radius <= MAX_RADIUS or shape & ~(_RADIUS_MASK | _PER_BAND):
        raise FrameError(f"dependence shape byte {shape:#04x}: radius outside 1..{MAX_RADIUS} or unknown bits")
    pos += 3
    n_kind = (len(labels) + 3) // 4
    if pos + n_kind > len(blob):
        raise FrameError("dependence section is cut short in its label kinds")
    kinds = [blob[pos + i // 4] >> (2 * (i % 4)) & 3 for i in range(len(labels))]
    if len(labels) % 4 and blob[pos + n_kind - 1] >> (2 * (len(labels) % 4)):
        raise FrameError("dependence kinds set for labels the packet does not carry")
    pos += n_kind
    out: dict[int, Dependence] = {}
    for lab, kind in zip(labels, kinds):
        if kind:
            out[int(lab)], pos = _record(blob, pos, int(lab), kind, n_bands, levels, radius, rows,
                                         version == GAPS_VERSION)
    if not out:
        raise FrameError("dependence section flagged but no label has a record")
    return out, pos


def _record(blob: bytes, pos: int, label: int, kind: int, n_bands: int, levels: int, radius: int,
            rows: int, gaps: bool) -> tuple[Dependence, int]:
    size = record_size(n_bands, radius, levels, rows, bool(kind & _GRAIN), bool(kind & _LEVELS))
    if pos + size > len(blob):
        raise FrameError(f"label {label}: dependence record needs {size} bytes, {len(blob) - pos} left")
    lo = hi = ()
    if kind & _LEVELS:
        width = 1 if levels <= 256 else 2
        seen = np.frombuffer(blob, np.uint8 if width == 1 else ">u2", 2 * n_bands, pos).astype(np.int64)
        lo, hi = tuple(seen[:n_bands].tolist()), tuple(seen[n_bands:].tolist())
        if any(a > b for a, b in zip(lo, hi)) or max(hi) >= levels:
            raise FrameError(f"label {label}: observed levels lo {lo}, hi {hi} not within 0 <= lo <= hi < {levels}")
        pos += 2 * n_bands * width
    if not kind & _GRAIN:
        return Dependence.observed(lo, hi), pos
    nc, nw = corr_size(n_bands), window_size(radius)
    codes = np.frombuffer(blob, np.int8, nc + rows * nw, pos)
    absent = codes == ABSENT
    if absent[:nc].any() or (absent.any() and not gaps):
        raise FrameError(f"label {label}: dependence code -128 outside [-127, 127]")
    v = np.where(absent, 0, codes).astype(np.float64) / SCALE
    acf = tuple(tuple(v[nc + r * nw:nc + (r + 1) * nw]) for r in range(rows))
    unmeasured = tuple(tuple(np.flatnonzero(absent[nc + r * nw:nc + (r + 1) * nw]).tolist()) for r in range(rows))
    return Dependence(tuple(v[:nc]), acf, radius, lo, hi, unmeasured), pos + nc + rows * nw


def _decode_lags(blob: bytes, labels: Sequence[int], n_bands: int) -> dict[int, Dependence]:
    """The older layout: band correlations and autocorrelation at LAGS along rows and columns."""
    size = record_size(n_bands)
    codes = np.frombuffer(blob, dtype=np.int8).reshape(len(labels), size)
    out: dict[int, Dependence] = {}
    nc, nl = corr_size(n_bands), len(LAGS)
    for lab, row in zip(labels, codes):
        absent = row == ABSENT
        if absent.all():
            continue
        if absent.any():
            raise FrameError(f"label {lab}: dependence code -128 outside [-127, 127]")
        v = row.astype(np.float64) / SCALE
        out[int(lab)] = Dependence.from_lags(tuple(v[:nc]), tuple(v[nc:nc + nl]), tuple(v[nc + nl:]))
    if not out:
        raise FrameError("dependence section flagged but no label has a measurement")
    return out


def encode_lags(deps: Mapping[int, tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]],
                labels: Sequence[int], n_bands: int) -> bytes:
    """The older layout from {label: (corr, dx, dy)}: what robots before the version sent (kept to
    test that their packets still decode)."""
    out = np.full((len(labels), record_size(n_bands)), ABSENT, dtype=np.int8)
    for i, lab in enumerate(labels):
        if lab in deps:
            out[i] = _quantize([v for part in deps[lab] for v in part])
    return out.tobytes()


def quantized(deps: Mapping[int, Dependence], labels: Sequence[int], n_bands: int,
              levels: int = 256) -> dict[int, Dependence]:
    """`deps` as the host will receive them (int8 steps), so a packet equals its decoded self."""
    return decode_dependence(encode_dependence(deps, labels, n_bands, levels), labels, n_bands, levels)[0]
