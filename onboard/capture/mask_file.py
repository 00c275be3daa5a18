"""Label mask files: a PNG (gray, indexed or colour) or .npy of one label per pixel."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from btf.fit.png import read_png
from radio.packets.base import MAX_LABELS

MAX_LABEL = MAX_LABELS - 1  # labels are bytes, as on the wire


def load_mask(
    path: str | Path,
    n_labels: int | None = None,
    shape: tuple[int, int] | None = None,
    colours: tuple[tuple[int, int, int], ...] | None = None,
) -> np.ndarray:
    """An H x W uint8 label map from a PNG or .npy file.

    Gray and indexed PNGs hold labels directly (an indexed PNG's palette is only how
    the mask was drawn). RGB/RGBA PNGs are mapped through `colours` (label i is
    colours[i]); without it, the distinct colours in ascending (R, G, B) order are
    labels 0, 1, ...
    """
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"mask: no such file: {p}")
    if p.suffix.lower() == ".npy":
        try:
            a = np.load(p, allow_pickle=False)
        except (ValueError, OSError) as exc:
            raise ValueError(f"mask: cannot read {p}: {exc}") from None
        if a.ndim != 2 or not (np.issubdtype(a.dtype, np.integer) or a.dtype == bool):
            raise ValueError(f"mask: {p} must hold a 2-D integer array, got {a.dtype} {a.shape}")
        labels = a
    elif p.suffix.lower() == ".png":
        img = read_png(p)
        px = img.pixels
        if img.color_type in (2, 6):
            labels = _colours_to_labels(px[..., :3], colours, p)
        elif img.color_type == 4:
            labels = px[..., 0]
        else:
            labels = px
    else:
        raise ValueError(f"mask: {p} is neither .png nor .npy")
    if labels.min() < 0 or labels.max() > MAX_LABEL:
        raise ValueError(f"mask: {p} has labels outside 0..{MAX_LABEL} (max {labels.max()})")
    if n_labels is not None and labels.max() >= n_labels:
        raise ValueError(f"mask: {p} has label {int(labels.max())}, above the {n_labels} labels configured")
    if shape is not None and labels.shape != tuple(shape):
        raise ValueError(f"mask: {p} is {labels.shape[1]}x{labels.shape[0]}, the frame is {shape[1]}x{shape[0]}")
    return np.ascontiguousarray(labels, dtype=np.uint8)


def _colours_to_labels(rgb: np.ndarray, colours, p: Path) -> np.ndarray:
    if rgb.dtype != np.uint8:
        raise ValueError(f"mask: {p} is a 16-bit colour image; use 8-bit colour or gray labels")
    key = (rgb[..., 0].astype(np.int32) << 16) | (rgb[..., 1].astype(np.int32) << 8) | rgb[..., 2]
    if colours is None:
        table = np.unique(key)
        if len(table) > MAX_LABEL + 1:
            raise ValueError(f"mask: {p} has {len(table)} colours, more than {MAX_LABEL + 1} labels")
    else:
        table = np.array([(r << 16) | (g << 8) | b for r, g, b in colours], dtype=np.int64)
    order = np.argsort(table, kind="stable")
    pos = np.searchsorted(table[order], key).clip(0, len(table) - 1)
    found = table[order][pos] == key
    if not found.all():
        k = int(key[~found].flat[0])
        raise ValueError(f"mask: {p} has colour {(k >> 16, (k >> 8) & 255, k & 255)} not in the colour table")
    return order[pos]
