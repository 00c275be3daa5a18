"""Direct computations the feature-space tests check `btf-host spaces` and `--space auto` against."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from btf.fit.features import FeatureSpace, FeatureSpec, PcaBasis, compute
from hal.interfaces import ViewAngles
from hal.scene import render
from tools.data.images import write_image, write_mask


def bands_of(image: np.ndarray, space: str) -> tuple[np.ndarray, int]:
    """The robot's own bands (btf.fit.features) of an 8-bit colour photograph; a one-band one as it is."""
    if image.shape[2] == 1:
        return image, 256 if image.dtype == np.uint8 else 65536
    pca = PcaBasis.fit(image) if space == "pca" else None
    return compute(image, FeatureSpec(FeatureSpace(space)), pca).data, 256


def table2(counts: np.ndarray, models: dict, levels: int, seed: int) -> float:
    """The paper's Table-2 measure on an independent draw, from its definition."""
    rng = np.random.default_rng(seed)
    out = []
    for lab, band in sorted(models):
        c = counts[lab, band]
        n = int(c.sum())
        drawn = models[(lab, band)].sample_pixels(n, rng, levels).astype(np.int64)
        used = np.flatnonzero(c)
        lo, hi = (0, levels - 1) if levels <= 256 else (int(used[0]), int(used[-1]))
        bins = min(256, hi - lo + 1)
        h = np.bincount((np.arange(hi - lo + 1) * bins) // (hi - lo + 1), c[lo:hi + 1], bins)
        s = np.bincount((np.clip(drawn - lo, 0, hi - lo) * bins) // (hi - lo + 1), minlength=bins)
        out.append(np.abs(h / n - s / n).sum())
    return float(np.mean(out))


def stored_plate(host, folder: Path, space: str) -> tuple[Path, np.ndarray, np.ndarray]:
    """A rendered plate fitted in `space` by `btf-host fit --db` with its label map: (database,
    photograph, labels)."""
    view = render("mixed", ViewAngles(50.0, 0.0), (64, 80), seed=0)
    write_image(folder / "plate.png", view.image)
    write_mask(folder / "plate_mask.png", view.mask)
    db = folder / f"{space}.db"
    code, _, err = host("fit", folder / "plate.png", "--mask", folder / "plate_mask.png", "--space", space,
                        "--angle", 50, "--db", db)
    assert code == 0, err
    return db, view.image, view.mask
