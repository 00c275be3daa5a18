"""Real photographs as fitting cases: (image, mask, label, band) -> the region's 8-bit histogram.

Every image ships inside a public package (scikit-image's data module, matplotlib's sample
data); none is a render of our scene model. Masks are k-means on the pixels (seeded), the whole
frame for the texture photographs, and for the Middlebury motorcycle the true depth layers of
its ground-truth disparity map (a segmentation by geometry that no colour clustering made).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# (name, loader, kind): gray textures of ground, rock and vegetation, gray scenes, colour scenes.
TEXTURES = ("grass", "gravel", "brick")
GRAY = ("grass", "gravel", "brick", "moon", "camera", "coins")
RGB = ("rocket", "coffee", "chelsea", "astronaut", "hubble_deep_field", "grace_hopper")
K = 3  # k-means classes per image
BANDS_RGB = ("R", "G", "B")


@dataclass(frozen=True, slots=True)
class Case:
    image: str
    mask: str  # "kmeans3" | "whole" | "depth3"
    label: int
    band: str
    counts: np.ndarray  # 256 level counts

    @property
    def name(self) -> str:
        return f"{self.image}/{self.mask}/{self.label}/{self.band}"

    @property
    def count(self) -> int:
        return int(self.counts.sum())


def load(name: str) -> np.ndarray:
    if name == "grace_hopper":
        import matplotlib.cbook as cbook
        import matplotlib.image as mimage

        return np.asarray(mimage.imread(cbook.get_sample_data("grace_hopper.jpg")), dtype=np.uint8)
    if name == "motorcycle":
        import skimage.data

        return skimage.data.stereo_motorcycle()[0]
    import skimage.data

    return np.asarray(getattr(skimage.data, name)(), dtype=np.uint8)


def kmeans_mask(image: np.ndarray, k: int = K, seed: int = 0) -> np.ndarray:
    """Labels 0..k-1 ordered darkest first (OpenCV k-means, k-means++ seeding, fixed seed)."""
    import cv2

    px = image.reshape(image.shape[0] * image.shape[1], -1).astype(np.float32)
    cv2.setRNGSeed(seed)
    crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 0.1)
    _, lab, centres = cv2.kmeans(px, k, None, crit, 3, cv2.KMEANS_PP_CENTERS)
    order = np.argsort(np.argsort(centres.sum(axis=1)))
    return order[lab.ravel()].reshape(image.shape[:2]).astype(np.int32)


def depth_mask(layers: int = 3) -> np.ndarray:
    """The motorcycle's true depth layers: ground-truth disparity cut at its terciles; pixels
    without a disparity (occluded) are -1 and belong to no region."""
    import skimage.data

    disp = skimage.data.stereo_motorcycle()[2]
    known = np.isfinite(disp)
    cuts = np.quantile(disp[known], np.linspace(0, 1, layers + 1)[1:-1])
    labels = np.digitize(disp, cuts).astype(np.int32)
    labels[~known] = -1
    return labels


def _cases(image: str, mask_kind: str, pixels: np.ndarray, labels: np.ndarray,
           bands: tuple[str, ...], min_pixels: int) -> list[Case]:
    out = []
    planes = pixels.reshape(pixels.shape[0], pixels.shape[1], -1)
    for label in range(int(labels.max()) + 1):
        sel = labels == label
        if int(sel.sum()) < min_pixels:
            continue
        for b, band in enumerate(bands):
            counts = np.bincount(planes[..., b][sel], minlength=256).astype(np.int64)
            out.append(Case(image, mask_kind, label, band, counts))
    return out


def cases(min_pixels: int = 200, quick: bool = False) -> list[Case]:
    """Every case, in a fixed order. `quick`: one gray and one colour image."""
    gray = GRAY[:1] if quick else GRAY
    rgb = RGB[:1] if quick else RGB
    out: list[Case] = []
    for name in gray:
        img = load(name)
        out += _cases(name, "kmeans3", img, kmeans_mask(img), ("Y",), min_pixels)
        if name in TEXTURES:
            out += _cases(name, "whole", img, np.zeros(img.shape, np.int32), ("Y",), min_pixels)
    for name in rgb:
        img = load(name)
        out += _cases(name, "kmeans3", img, kmeans_mask(img), BANDS_RGB, min_pixels)
    if not quick:
        img = load("motorcycle")
        out += _cases("motorcycle", "depth3", img, depth_mask(), BANDS_RGB, min_pixels)
    return out
