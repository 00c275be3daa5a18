"""`btf-host mask`: a label mask by clustering or bottom-up segmentation."""
from __future__ import annotations

import argparse
import math

import numpy as np

from tools.cli.options import CliError, add_force, check_out
from tools.data.masks import segment as segment_image

METHODS = ("isodata", "kmeans", "felzenszwalb", "slic")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("image")
    p.add_argument("--method", choices=METHODS, required=True)
    p.add_argument("--k", type=int, default=4, help="clutter classes (default 4)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--scale", type=float, default=100.0, help="felzenszwalb scale")
    p.add_argument("--segments", type=int, default=400, help="slic superpixels")
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
        stretched_8bit,
        write_mask,
    )

    if not 1 <= args.k <= 255:
        raise CliError(f"--k {args.k}: must lie in 1..255")
    if args.segments < 1:
        raise CliError(f"--segments {args.segments}: slic needs at least 1 superpixel")
    if not (math.isfinite(args.scale) and args.scale > 0):
        raise CliError(f"--scale {args.scale}: felzenszwalb needs a positive number")
    check_out(args.out, (args.image,), args.force)
    try:
        image = stretched_8bit(read_image(args.image))  # 16-bit: segmented on its own range
        if image.shape[0] * image.shape[1] < args.k:
            raise CliError(f"image {args.image}: fewer pixels than --k {args.k} classes")
        write_mask(args.out, segment(image, args.method, args.k, args.seed, args.scale, args.segments))
    except ImageError as exc:
        raise CliError(str(exc)) from None
    return 0
