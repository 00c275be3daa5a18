"""`btf-host mask`: a label mask by clustering or bottom-up segmentation."""
from __future__ import annotations

import argparse
import sys

import numpy as np

from onboard.cli.runner import SEED, bounded
from tools.cli.options import CliError, add_force, check_out
from tools.data.masks import segment as segment_image

METHODS = ("isodata", "kmeans", "felzenszwalb", "slic")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("image", help="the photograph to segment (8- or 16-bit PNG, TIFF, JPEG)")
    p.add_argument("--method", choices=METHODS, required=True,
                   help="isodata and kmeans cluster colours into --k classes; felzenszwalb and slic grow regions "
                        "first, then cluster them")
    p.add_argument("--k", type=bounded(int, 1, 255, "classes"), default=4, help="clutter classes, 1..255 (default 4)")
    p.add_argument("--seed", type=SEED, default=0, help="seed of the clustering (the same seed, the same mask)")
    p.add_argument("--scale", type=bounded(float, 0.001, 1e6), default=100.0,
                   help="felzenszwalb scale: larger gives larger regions (default 100)")
    p.add_argument("--segments", type=bounded(int, 1, 100_000, "superpixels"), default=400,
                   help="slic superpixels (default 400)")
    p.add_argument("--out", required=True, help="output mask .png (never the input; an existing file needs --force)")
    add_force(p)


def segment(image: np.ndarray, method: str, k: int, seed: int = 0, scale: float = 100.0,
            segments: int = 400) -> np.ndarray:
    """A uint8 mask, classes darkest first (tools.data.masks: bounded memory, tiled)."""
    return segment_image(image, method, k, seed, scale, segments)


def run(args: argparse.Namespace) -> int:
    # heavy (OpenCV, scipy): loaded to run, not for --help
    from tools.data.images import (
        ImageError,
        read_image,
        segmentation_view,
        write_mask,
    )

    check_out(args.out, (args.image,), args.force, suffixes=(".png",))  # labels stay exact in PNG only
    try:
        image = segmentation_view(read_image(args.image))
        if image.shape[0] * image.shape[1] < args.k:
            raise CliError(f"image {args.image}: fewer pixels than --k {args.k} classes")
        mask = segment(image, args.method, args.k, args.seed, args.scale, args.segments)
        write_mask(args.out, mask)
    except ImageError as exc:
        raise CliError(str(exc)) from None
    classes = int(mask.max()) + 1  # classes are 0..n-1
    if classes < args.k:
        print(f"btf-host: note: {classes} classes of the {args.k} asked for: the image's colours part into no more",
              file=sys.stderr)
    return 0
