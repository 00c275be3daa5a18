"""The bins that histogram differences of deep (16-bit) bands are taken over.

An 8-bit band is compared level by level: 256 bins. A 16-bit band spreads its pixels over
thousands of levels (a thermal image in centikelvin over 20-30 K, say), so a per-level
histogram of even a million pixels is mostly counting noise and Σ|h1 − h2| approaches 2 for
two draws of one distribution. Deep bands are therefore binned into at most DEEP_BINS equal
bins over the levels the band occupies (in both images, for a comparison): the same
resolution an 8-bit sensor has over its range. Cumulative metrics (KS, W1) stay per level.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

DEEP_BINS = 256


@dataclass(frozen=True, slots=True)
class Grid:
    """Bins of `width` levels from level `lo`: level x falls in bin floor((x - lo) / width)."""

    lo: int
    width: float
    bins: int

    @classmethod
    def over(cls, lo: int, hi: int, levels: int, bins: int = DEEP_BINS) -> "Grid":
        """One bin per level for 8-bit bands (or spans of at most `bins` levels), else `bins` bins over lo..hi."""
        if levels <= 256:
            return cls(0, 1.0, levels)
        span = max(1, int(hi) - int(lo) + 1)
        return cls(int(lo), 1.0, span) if span <= bins else cls(int(lo), span / bins, bins)

    @property
    def per_level(self) -> bool:
        return self.width == 1.0

    def rebin(self, counts: np.ndarray) -> np.ndarray:
        """Counts per level (last axis, levels 0..n-1) -> counts per bin."""
        counts = np.asarray(counts)
        inside = counts[..., self.lo:self.lo + math.ceil(self.bins * self.width)]
        starts = np.ceil(self.width * np.arange(self.bins)).astype(np.intp)  # first level of each bin
        return np.add.reduceat(inside, starts, axis=-1)

    def edges(self) -> np.ndarray:
        """The bins' inner borders on the continuous level axis (level x covers x ± 1/2),
        for Johnson.interval_probabilities: what rounding a draw to the levels puts in each bin."""
        return np.ceil(self.lo + self.width * np.arange(1, self.bins)) - 0.5
