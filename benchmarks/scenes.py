"""Test frames for the benchmarks: the fake field scene with synthetic label maps."""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from hal.interfaces import ViewAngles
from hal.scene import render


@lru_cache(maxsize=4)
def field(height: int, width: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(RGB uint8 image, material mask) of the fake field scene seen at 60 degrees elevation."""
    view = render("field", ViewAngles(60.0), size=(height, width), seed=seed)
    return view.image, view.mask


@lru_cache(maxsize=8)
def voronoi_labels(height: int, width: int, n_labels: int, seed: int = 0) -> np.ndarray:
    """Labels 0..n_labels-1 as the Voronoi cells of random seeds: irregular regions of mixed sizes."""
    if n_labels == 1:
        return np.zeros((height, width), np.uint8)
    rng = np.random.default_rng(seed)
    pts = rng.uniform((0, 0), (height, width), (n_labels, 2))
    rows = np.arange(height, dtype=np.float32)[:, None]
    cols = np.arange(width, dtype=np.float32)[None, :]
    best = np.full((height, width), np.inf, np.float32)
    out = np.zeros((height, width), np.uint8)
    for k, (r, c) in enumerate(pts):
        d = (rows - np.float32(r)) ** 2 + (cols - np.float32(c)) ** 2
        closer = d < best
        best[closer] = d[closer]
        out[closer] = k
    return out
