"""The palette of clutter types: ISODATA centres seen so far, so a label means the same clutter
in every view (persisted by `onboard.capture.segmentation`)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from radio.packets.base import MAX_LABELS


@dataclass
class Palette:
    """Cluster centres seen so far; a centre's index is its label in every view."""

    threshold: float = 30.0
    max_entries: int = 16
    entries: list[tuple[float, ...]] = field(default_factory=list)

    def __post_init__(self) -> None:
        if not (np.isfinite(self.threshold) and self.threshold > 0):
            raise ValueError(f"palette: threshold must be positive, got {self.threshold}")
        if not 1 <= self.max_entries <= MAX_LABELS:
            raise ValueError(f"palette: max_entries must be in 1..{MAX_LABELS}")

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
