"""Photographs for the texture benchmark, each fitted and measured as the robot does.

Every image ships inside a public package (scikit-image's data module, matplotlib's sample
data); none is a render of our scene model. Gray textures are one region (the whole frame),
scenes get a seeded 3-class k-means mask (benchmarks.photo_cases), and the 16-bit case is
matplotlib's sample elevation raster (jacksboro_fault_dem.npz), its metres as 16-bit levels.
The steps of `btf-host fit` (and of the robot, `robot=True`: a lattice of anchors, not every
pixel pair, on a smaller window): FrameFitter, the observed levels from its histograms, the dependence pass, and the int8
steps of the radio (radio.packets.dependence.quantized).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from benchmarks.photo_cases import kmeans_mask
from btf.dependence import Dependence
from btf.fit.dependence import measure, observed
from btf.fit.fitter import FrameFitter
from btf.johnson import Johnson
from radio.packets.dependence import quantized
from tools.analysis.pair_sums import every_pair
from tools.data.images import HOST_CORR_POINTS, HOST_RADIUS

TEXTURES = ("grass", "gravel", "brick")
GRAY_SCENES = ("camera", "moon", "coins")
RGB_SCENES = ("coffee", "chelsea", "astronaut", "rocket", "immunohistochemistry", "grace_hopper", "motorcycle")
DEEP = ("elevation16",)
ALL = TEXTURES + GRAY_SCENES + RGB_SCENES + DEEP
MIN_REGION = 500  # regions with fewer pixels are not judged


@dataclass(frozen=True)
class Photo:
    name: str
    pixels: np.ndarray  # H x W x B, uint8 or uint16
    labels: np.ndarray  # H x W uint8
    levels: int
    models: dict[tuple[int, int], Johnson]
    dependence: dict[int, Dependence]

    @property
    def regions(self) -> list[int]:
        counts = np.bincount(self.labels.ravel())
        return [int(k) for k in np.flatnonzero(counts >= MIN_REGION)]


def pixels_of(name: str) -> np.ndarray:
    """The photograph as H x W x B (one band for gray files)."""
    import skimage.data

    if name == "grace_hopper":
        import matplotlib.cbook as cbook
        import matplotlib.image as mimage

        img = np.asarray(mimage.imread(cbook.get_sample_data("grace_hopper.jpg")), dtype=np.uint8)
    elif name == "motorcycle":
        img = skimage.data.stereo_motorcycle()[0]
    elif name == "elevation16":
        import matplotlib.cbook as cbook

        img = cbook.get_sample_data("jacksboro_fault_dem.npz")["elevation"].astype(np.uint16)
    else:
        img = np.asarray(getattr(skimage.data, name)())
    img = img[..., None] if img.ndim == 2 else img[..., :3]
    return np.ascontiguousarray(img)


def load(name: str, side: int | None = None, per_band: bool | None = None, robot: bool = False) -> Photo:
    """A photograph (its top-left `side` x `side` crop when given), fitted and measured as
    `btf-host fit` does, or as the robot does."""
    img = pixels_of(name)
    if side is not None:
        img = np.ascontiguousarray(img[:side, :side])
    levels = 256 if img.dtype == np.uint8 else 65536
    if name in TEXTURES:
        labels = np.zeros(img.shape[:2], np.uint8)
    else:
        view = img if levels == 256 else np.clip((img - img.min()) * (255.0 / max(1, np.ptp(img))), 0, 255)
        labels = kmeans_mask(view.astype(np.uint8)).astype(np.uint8)
    n_bands = img.shape[2]
    fitter = FrameFitter(int(labels.max()) + 1, n_bands, bins=levels)
    fitter.add(img, labels)
    fits = fitter.fit()
    models = {k: r.model for k, r in fits.items()}
    seen = observed(fitter.counts, fitter.centre0, fitter.bin_width, levels)
    reach = {} if robot else {"radius": HOST_RADIUS, "corr_points": HOST_CORR_POINTS, "pair_sums": every_pair}
    deps = measure(img, labels, models, levels, per_band=per_band, levels_seen=seen, **reach)
    ids = sorted(deps)
    return Photo(name, img, labels, levels, models, quantized(deps, ids, n_bands, levels))
