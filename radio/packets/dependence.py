"""The dependence section of a MODELS blob: per label, grain and band correlation in int8.

Per label, in the packet's label order, B(B-1)/2 band correlations (upper triangle,
row-major) then the autocorrelation at `LAGS` along rows (dx) and along columns (dy), each
an int8 in steps of 1/127. A record whose bytes are all -128 means "not measured". For RGB
that is 11 bytes a label. The section sits inside the MODELS blob (`radio.packets.models`),
flagged by one bit of the label bitmap's length byte, so it costs nothing else but, at most,
one byte of the blob's msgpack header when it pushes the blob past 255 bytes.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from btf.dependence import LAGS, Dependence, corr_size
from radio import FrameError
from radio.packets.base import want_bin

SCALE = 127
ABSENT = -128


def record_size(n_bands: int) -> int:
    """Bytes per label: band correlations, then both directions' autocorrelation at LAGS."""
    return corr_size(n_bands) + 2 * len(LAGS)


def section_size(n_labels: int, n_bands: int) -> int:
    return n_labels * record_size(n_bands)


def _quantize(values: Sequence[float]) -> np.ndarray:
    v = np.asarray(values, dtype=np.float64)
    if not np.all(np.isfinite(v)):
        raise ValueError("dependence values must be finite")
    return np.rint(np.clip(v, -1.0, 1.0) * SCALE).astype(np.int8)


def encode_dependence(deps: Mapping[int, Dependence], labels: Sequence[int], n_bands: int) -> bytes:
    """The section for `labels` (the packet's order); labels without an entry are marked absent."""
    stray = set(deps) - set(labels)
    if stray:
        raise ValueError(f"dependence for labels the packet does not carry: {sorted(stray)}")
    out = np.full((len(labels), record_size(n_bands)), ABSENT, dtype=np.int8)
    for i, lab in enumerate(labels):
        dep = deps.get(lab)
        if dep is None:
            continue
        if dep.n_bands != n_bands:
            raise ValueError(f"label {lab}: dependence has {dep.n_bands} bands, packet {n_bands}")
        out[i] = _quantize((*dep.corr, *dep.dx, *dep.dy))
    return out.tobytes()


def decode_dependence(blob: Any, labels: Sequence[int], n_bands: int) -> dict[int, Dependence]:
    """Untrusted section -> {label: Dependence}; FrameError names what is wrong."""
    blob = want_bin(blob, "dependence")
    size = record_size(n_bands)
    if len(blob) != len(labels) * size:
        raise FrameError(f"dependence section has {len(blob)} bytes, expected "
                         f"{len(labels)} labels x {size} = {len(labels) * size}")
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
        out[int(lab)] = Dependence(tuple(v[:nc]), tuple(v[nc:nc + nl]), tuple(v[nc + nl:]))
    return out


def quantized(deps: Mapping[int, Dependence], labels: Sequence[int], n_bands: int) -> dict[int, Dependence]:
    """`deps` as the host will receive them (int8 steps), so a packet equals its decoded self."""
    return decode_dependence(encode_dependence(deps, labels, n_bands), labels, n_bands)
