"""MASK packets: a capture's label map, mode-pooled to at most 64 x 64 and run-length encoded.

Wire fields after [version, kind]: robot, seq, frame_h, frame_w, h, w,
values (one byte per run), runs (big-endian uint16 per run) [, extras].
Runs go row-major, adjacent runs have different labels, and their lengths sum to h * w.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

from radio import FrameError
from radio.packets.base import MAX_FRAME_SIDE, MAX_MASK_SIDE, UINT32, Kind
from radio.packets.schema import Bin, Declared, Field, Int

MAX_SIDE = MAX_MASK_SIDE


@dataclass(frozen=True, slots=True)
class MaskPacket(Declared):
    """A capture's label map, mode-pooled to at most 64 x 64, as runs: row-major, adjacent runs of
    different labels, their lengths summing to the map's cells."""

    KIND: ClassVar[Kind] = Kind.MASK
    WIRE: ClassVar[tuple[Field, ...]] = (
        Field("robot_id", Int(0, 0xFFFF), "the robot", label="robot id"),
        Field("seq", Int(0, UINT32), "the capture's number", label="capture seq"),
        Field("frame_height", Int(1, MAX_FRAME_SIDE), "the camera frame's height"),
        Field("frame_width", Int(1, MAX_FRAME_SIDE), "its width"),
        Field("mask_height", Int(1, MAX_SIDE), "the pooled map's height (at most the frame's)"),
        Field("mask_width", Int(1, MAX_SIDE), "its width (at most the frame's)"),
        Field("values", Bin(), "the label of each run", label="mask values"),
        Field("runs", Bin(), "each run's length, big-endian uint16", label="mask runs"),
    )
    robot_id: int
    seq: int
    frame_shape: tuple[int, int]  # the camera frame (height, width) the map was taken from
    shape: tuple[int, int]  # the downsampled map (height, width)
    values: bytes  # label of each run
    runs: tuple[int, ...]  # length of each run
    extras: Mapping[str, Any] = field(default_factory=dict)

    def label_map(self) -> np.ndarray:
        """The downsampled label map, uint8 of `shape`."""
        return np.repeat(np.frombuffer(self.values, dtype=np.uint8), self.runs).reshape(self.shape)

    def full_size(self) -> np.ndarray:
        """The label map stretched back to the frame size: each cell over exactly the frame
        rows and columns it was pooled from (downsample_labels)."""
        small = self.label_map()
        (fh, fw), (h, w) = self.frame_shape, self.shape
        return small[cell_of(fh, h)[:, None], cell_of(fw, w)[None, :]]

    def wire_values(self) -> dict[str, Any]:
        runs = np.asarray(self.runs, dtype=np.int64)
        if runs.size and (runs.min() < 1 or runs.max() > 0xFFFF):
            raise ValueError("mask runs must be 1..65535 long")
        (fh, fw), (h, w) = self.frame_shape, self.shape
        return {"robot_id": self.robot_id, "seq": self.seq, "frame_height": fh, "frame_width": fw,
                "mask_height": h, "mask_width": w, "values": bytes(self.values), "runs": runs.astype(">u2").tobytes()}

    @classmethod
    def from_values(cls, f: dict[str, Any], extras: dict, version: int, compute: bool = True) -> MaskPacket:
        robot, seq, fh, fw = f["robot_id"], f["seq"], f["frame_height"], f["frame_width"]
        h, w, values, raw_runs = f["mask_height"], f["mask_width"], f["values"], f["runs"]
        if h > fh or w > fw:
            raise FrameError(f"mask {h} x {w} is larger than its frame {fh} x {fw}")
        if len(raw_runs) != 2 * len(values) or not values:
            raise FrameError("mask needs one 2-byte run length per label value")
        runs = np.frombuffer(raw_runs, dtype=">u2").astype(np.int64)
        if runs.min() < 1:
            raise FrameError("mask has an empty run")
        if int(runs.sum()) != h * w:
            raise FrameError(f"mask runs cover {int(runs.sum())} cells, expected {h} x {w} = {h * w}")
        v = np.frombuffer(values, dtype=np.uint8)
        if np.any(v[1:] == v[:-1]):
            raise FrameError("adjacent mask runs carry the same label")
        return cls(robot, seq, (fh, fw), (h, w), values, tuple(int(r) for r in runs), extras)


def downsample_labels(labels: np.ndarray, max_side: int = MAX_SIDE) -> np.ndarray:
    """Mode-pool a label map so neither side exceeds max_side (ties go to the lower label).

    This is the map a MASK packet carries, and the one the robot compares to decide whether
    a new MASK is due. Cells are rows and columns between the rounded points of an even split.
    """
    return pool_labels(labels, max_side)[0]


def pool_labels(labels: np.ndarray, max_side: int = MAX_SIDE) -> tuple[np.ndarray, np.ndarray]:
    """(downsample_labels' map, the pixels of each label 0..255): both from one count of each
    cell's labels, so a caller that needs both reads the map once."""
    labels = np.asarray(labels)
    if labels.ndim != 2 or labels.size == 0:
        raise ValueError(f"label map must be a non-empty 2-D array, got shape {labels.shape}")
    if labels.dtype.kind not in "iu" or labels.min() < 0 or labels.max() > 255:
        raise ValueError("label map must hold integer labels 0..255")
    if not 1 <= max_side <= MAX_SIDE:
        raise ValueError(f"max_side must be 1..{MAX_SIDE}, got {max_side}")
    H, W = labels.shape
    scale = max(H, W) / max_side
    if scale <= 1.0:
        return labels.astype(np.uint8), np.bincount(labels.reshape(-1), minlength=256)
    h, w = max(1, min(max_side, round(H / scale))), max(1, min(max_side, round(W / scale)))
    rows, cols = cell_edges(H, h), cell_edges(W, w)
    col_cell = np.repeat(np.arange(w, dtype=np.intp), np.diff(cols)) << 8
    out = np.empty((h, w), dtype=np.uint8)
    total = np.zeros(w * 256, dtype=np.int64)
    index = np.empty((int(np.diff(rows).max()), W), dtype=np.intp)
    for i in range(h):  # one row of cells at a time: memory is a few frame rows, not the frame
        band = labels[rows[i]:rows[i + 1]]
        at = index[:len(band)]
        np.bitwise_or(col_cell, band, out=at)
        counts = np.bincount(at.reshape(-1), minlength=w * 256)
        out[i] = counts.reshape(w, 256).argmax(axis=1)  # first maximum: the lower label on ties
        total += counts
    return out, total.reshape(w, 256).sum(axis=0)


def cell_edges(full: int, cells: int) -> np.ndarray:
    """The first frame row (or column) of each of `cells` cells, and `full` at the end."""
    return np.linspace(0, full, cells + 1).round().astype(np.intp)


def cell_of(full: int, cells: int) -> np.ndarray:
    """The cell each of `full` frame rows (or columns) was pooled into."""
    return np.searchsorted(cell_edges(full, cells), np.arange(full), side="right") - 1


def mask_packet(
    labels: np.ndarray, *, robot_id: int, seq: int, max_side: int = MAX_SIDE,
    extras: Mapping[str, Any] | None = None, pooled: np.ndarray | None = None,
) -> MaskPacket:
    """Downsample a frame's label map and run-length encode it; `pooled`: the map
    downsample_labels(labels, max_side) already made (not made again)."""
    small = downsample_labels(labels, max_side) if pooled is None else np.asarray(pooled, dtype=np.uint8)
    flat = small.reshape(-1)
    starts = np.flatnonzero(np.r_[True, flat[1:] != flat[:-1]])
    runs = np.diff(np.r_[starts, flat.size])
    return MaskPacket(
        robot_id, seq, tuple(int(s) for s in np.shape(labels)), small.shape,
        flat[starts].astype(np.uint8).tobytes(), tuple(int(r) for r in runs), dict(extras or {}),
    )
