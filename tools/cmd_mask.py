"""`btf-host mask`: a label mask by clustering or bottom-up segmentation."""
from __future__ import annotations

import argparse
import math
from typing import TYPE_CHECKING

from tools.cli import CliError, add_force, check_out

if TYPE_CHECKING:  # numpy and the segmenters load where used: --help builds this parser too
    import numpy as np

METHODS = ("isodata", "kmeans", "felzenszwalb", "slic")


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("mask", help="segment an image into K clutter classes")
    p.add_argument("image")
    p.add_argument("--method", choices=METHODS, required=True)
    p.add_argument("--k", type=int, default=4, help="clutter classes (default 4)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--scale", type=float, default=100.0, help="felzenszwalb scale")
    p.add_argument("--segments", type=int, default=400, help="slic superpixels")
    p.add_argument("--out", required=True, help="output mask .png (never the input; an existing file needs --force)")
    add_force(p)
    return p


def _ordered(labels: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """Relabel so class 0 is the darkest: stable masks across runs and methods."""
    import numpy as np

    order = np.argsort(centres.sum(axis=1), kind="stable")
    rank = np.empty(len(order), np.int64)
    rank[order] = np.arange(len(order))
    return rank[labels].astype(np.uint8)


def _compact(labels: np.ndarray, centres: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    import numpy as np

    used = np.unique(labels)
    remap = np.zeros(len(centres), np.int64)
    remap[used] = np.arange(len(used))
    return remap[labels], centres[used]


def _merge_segments(image: np.ndarray, segments: np.ndarray, k: int, seed: int) -> np.ndarray:
    """Merge bottom-up segments into k classes by clustering their mean colours."""
    import numpy as np

    seg = segments.ravel()
    n = int(seg.max()) + 1
    counts = np.bincount(seg, minlength=n).astype(np.float64)
    px = image.reshape(-1, 3).astype(np.float64)
    means = np.stack([np.bincount(seg, px[:, c], n) for c in range(3)], axis=1) / np.maximum(counts, 1)[:, None]
    present = counts > 0
    if present.sum() <= k:
        cls = np.cumsum(present) - 1
        return _ordered(*_compact(cls[segments], means[present]))
    from scipy.cluster.vq import kmeans2

    centres, cls = kmeans2(means[present], k, minit="++", seed=seed)
    full = np.zeros(n, np.int64)
    full[present] = cls
    return _ordered(*_compact(full[segments], centres))


def segment(image: np.ndarray, method: str, k: int, seed: int = 0, scale: float = 100.0,
            segments: int = 400) -> np.ndarray:
    import numpy as np

    if method == "isodata":
        from onboard.isodata import IsodataParams, isodata

        res = isodata(image, IsodataParams(k=k, seed=seed))
        return _ordered(res.labels.astype(np.int64), res.centres)
    if method == "kmeans":
        import cv2

        cv2.setRNGSeed(seed)
        px = image.reshape(-1, 3).astype(np.float32)
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 20, 0.5)
        _, lab, centres = cv2.kmeans(px, k, None, crit, 3, cv2.KMEANS_PP_CENTERS)
        return _ordered(*_compact(lab.reshape(image.shape[:2]), centres.astype(np.float64)))
    from skimage.segmentation import felzenszwalb, slic

    if method == "felzenszwalb":
        return _merge_segments(image, felzenszwalb(image, scale=scale, sigma=0.8, min_size=20), k, seed)
    return _merge_segments(image, slic(image, n_segments=segments, compactness=10, start_label=0), k, seed)


def run(args: argparse.Namespace) -> int:
    from tools.images import ImageError, read_image, write_mask

    if not 1 <= args.k <= 255:
        raise CliError(f"--k {args.k}: must lie in 1..255")
    if args.segments < 1:
        raise CliError(f"--segments {args.segments}: slic needs at least 1 superpixel")
    if not (math.isfinite(args.scale) and args.scale > 0):
        raise CliError(f"--scale {args.scale}: felzenszwalb needs a positive number")
    check_out(args.out, (args.image,), args.force)
    try:
        image = read_image(args.image)
        if image.shape[0] * image.shape[1] < args.k:
            raise CliError(f"image {args.image}: fewer pixels than --k {args.k} classes")
        write_mask(args.out, segment(image, args.method, args.k, args.seed, args.scale, args.segments))
    except ImageError as exc:
        raise CliError(str(exc)) from None
    return 0
