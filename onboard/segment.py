"""Label maps: mask files, ISODATA with a persistent palette, and when the MASK map changed.

A `Segmenter` turns each feature frame into an H x W uint8 label map and says
when that map has changed enough that the host needs a new MASK packet.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from onboard.features import FeatureFrame
from onboard.imageio import read_png
from onboard.isodata import IsodataParams, Labeller, fit_centres, spread, subsample
from radio.packet_mask import MAX_SIDE, downsample_labels

MAX_LABEL = 255


# --- mask files -----------------------------------------------------------------------
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


# --- palette of clutter types ---------------------------------------------------------
@dataclass
class Palette:
    """Cluster centres seen so far; a centre's index is its label in every view."""

    threshold: float = 30.0
    max_entries: int = 16
    entries: list[tuple[float, ...]] = field(default_factory=list)

    def __post_init__(self) -> None:
        if not (np.isfinite(self.threshold) and self.threshold > 0):
            raise ValueError(f"palette: threshold must be positive, got {self.threshold}")
        if not 1 <= self.max_entries <= MAX_LABEL + 1:
            raise ValueError(f"palette: max_entries must be in 1..{MAX_LABEL + 1}")

    def match(self, centres: np.ndarray) -> np.ndarray:
        """Palette label for each centre (uint8), adding entries for new clutter types.

        Greedy on ascending distance, one centre per entry; a centre farther than the
        threshold from every free entry becomes a new entry, or (palette full) takes
        its nearest entry.
        """
        c = np.asarray(centres, dtype=np.float64)
        if c.ndim != 2 or not np.all(np.isfinite(c)):
            raise ValueError(f"palette: centres must be a finite 2-D array, got shape {c.shape}")
        if self.entries and len(self.entries[0]) != c.shape[1]:
            raise ValueError(f"palette: entries have {len(self.entries[0])} bands, centres {c.shape[1]}")
        out = np.full(len(c), -1)
        if self.entries:
            e = np.asarray(self.entries)
            d = np.sqrt(((c[:, None, :] - e[None, :, :]) ** 2).sum(axis=2))
            used = set()
            for flat in np.argsort(d, axis=None, kind="stable"):
                i, j = divmod(int(flat), len(e))
                if d[i, j] > self.threshold:
                    break
                if out[i] < 0 and j not in used:
                    out[i] = j
                    used.add(j)
        for i in np.flatnonzero(out < 0):
            if len(self.entries) < self.max_entries:
                self.entries.append(tuple(float(v) for v in c[i]))
                out[i] = len(self.entries) - 1
            else:
                e = np.asarray(self.entries)
                out[i] = int(np.argmin(((e - c[i]) ** 2).sum(axis=1)))
        return out.astype(np.uint8)

    def to_record(self) -> dict:
        return {"threshold": self.threshold, "max_entries": self.max_entries,
                "entries": [list(e) for e in self.entries]}

    @staticmethod
    def from_record(rec: dict) -> "Palette":
        try:
            entries = [tuple(float(v) for v in e) for e in rec["entries"]]
            pal = Palette(float(rec["threshold"]), int(rec["max_entries"]), entries)
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"palette record: malformed ({exc})") from None
        if len({len(e) for e in entries}) > 1 or len(entries) > pal.max_entries:
            raise ValueError("palette record: entries disagree in size or exceed max_entries")
        if entries and not np.all(np.isfinite(np.asarray(entries))):
            raise ValueError("palette record: non-finite entry")
        return pal


# --- the runtime's segmenter ----------------------------------------------------------
class SegmentMethod(enum.Enum):
    MASK = "mask"
    ISODATA = "isodata"


@dataclass(frozen=True)
class SegmentConfig:
    method: SegmentMethod
    mask_path: str | None = None
    n_labels: int | None = None
    mask_colours: tuple[tuple[int, int, int], ...] | None = None
    isodata: IsodataParams = IsodataParams()
    palette_threshold: float = 30.0
    palette_size: int = 16
    mask_side: int = MAX_SIDE  # longest side of the MASK packet's label map
    change_fraction: float = 0.02  # share of MASK cells that must differ to resend
    # Centres are refitted when the mean distance to the nearest centre on a small sample
    # grows past (1 + refit_drift) times its value when they were fitted; 0: every frame.
    refit_drift: float = 0.25
    drift_sample: int = 2000

    def __post_init__(self) -> None:
        if not isinstance(self.method, SegmentMethod):
            object.__setattr__(self, "method", SegmentMethod(self.method))
        if self.method is SegmentMethod.MASK and not self.mask_path:
            raise ValueError("segmentation: method 'mask' needs mask_path")
        if not 1 <= self.mask_side <= MAX_SIDE:
            raise ValueError(f"segmentation: mask_side must be in 1..{MAX_SIDE}, got {self.mask_side}")
        if not 0 <= self.change_fraction <= 1:
            raise ValueError(f"segmentation: change_fraction must be in 0..1, got {self.change_fraction}")
        if not (np.isfinite(self.refit_drift) and self.refit_drift >= 0) or self.drift_sample < 1:
            raise ValueError("segmentation: refit_drift must be >= 0 and drift_sample >= 1")


class Segmenter:
    """Labels for each feature frame; `changed` says whether a new MASK is due.

    ISODATA centres belong to the scene, not the frame: they are fitted once, matched to
    the palette, and baked into a `Labeller`; later frames are only looked up. A cheap
    drift check on a small sample refits when the centres no longer fit the view.
    """

    def __init__(self, config: SegmentConfig, palette: Palette | None = None) -> None:
        self.config = config
        self.changed = False
        self.small: np.ndarray | None = None
        self._sent: np.ndarray | None = None
        self.palette: Palette | None = None
        self._mask: np.ndarray | None = None
        self._labeller: Labeller | None = None
        self._fit_spread = 0.0
        self._frames = 0
        self.refits = 0  # how many times centres were fitted (for STATUS and tests)
        if config.method is SegmentMethod.MASK:
            # read at start so a bad mask file stops the runtime before the first pose
            self._mask = load_mask(config.mask_path, config.n_labels, colours=config.mask_colours)
        else:
            self.palette = palette or Palette(config.palette_threshold, config.palette_size)

    @classmethod
    def from_config(cls, config: SegmentConfig, palette_record: dict | None = None) -> "Segmenter":
        return cls(config, Palette.from_record(palette_record) if palette_record else None)

    def labels_for(self, frame: FeatureFrame) -> np.ndarray:
        shape = frame.data.shape[:2]
        if self._mask is not None:
            if self._mask.shape != shape:
                raise ValueError(f"mask: {self.config.mask_path} is {self._mask.shape[1]}x"
                                 f"{self._mask.shape[0]}, the frame is {shape[1]}x{shape[0]}")
            labels = self._mask
        else:
            labels = self._labels_isodata(frame.data)
        self.note(labels)
        return labels

    def new_scene(self) -> None:
        """Forget the scene's centres: the next frame fits them again."""
        self._labeller = None

    def _labels_isodata(self, data: np.ndarray) -> np.ndarray:
        p = self.config.isodata
        x = data.reshape(-1, data.shape[-1])
        self._frames += 1
        check = subsample(x, self.config.drift_sample, p.seed + self._frames)
        lab = self._labeller
        if (lab is None or lab.bands != x.shape[1] or self.config.refit_drift == 0
                or spread(check, lab.centres) > self._fit_spread * (1 + self.config.refit_drift)):
            centres = fit_centres(subsample(x, p.subsample, p.seed), p)
            lab = self._labeller = Labeller(centres, self.palette.match(centres))
            # One level of slack keeps a near-perfect fit from refitting on noise.
            self._fit_spread = spread(check, centres) + 1.0
            self.refits += 1
        return lab.assign(data)

    def force_send(self) -> None:
        """The next map counts as changed (the host asked for the mask)."""
        self._sent = None

    def note(self, labels: np.ndarray) -> None:
        """Record this frame's label map (from any source) and set `changed`: the map compared
        is the one the MASK packet carries (radio.packet_mask.downsample_labels)."""
        small = downsample_labels(labels, self.config.mask_side)
        sent = self._sent
        self.changed = (
            sent is None or sent.shape != small.shape
            or np.count_nonzero(sent != small) > self.config.change_fraction * small.size
        )
        if self.changed:
            self._sent = small
        self.small = small
