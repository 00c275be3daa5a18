"""`btf-host mask`: a label mask by clustering or bottom-up segmentation."""
from __future__ import annotations

import argparse

from tools.cli import CliError
from tools.images import ImageError, read_image, write_mask
from tools.masks import METHODS, segment


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("mask", help="segment an image into K clutter classes")
    p.add_argument("image")
    p.add_argument("--method", choices=METHODS, required=True)
    p.add_argument("--k", type=int, default=4, help="clutter classes (default 4)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--scale", type=float, default=100.0, help="felzenszwalb scale")
    p.add_argument("--segments", type=int, default=400, help="slic superpixels")
    p.add_argument("--out", required=True, help="output mask .png")
    return p


def run(args: argparse.Namespace) -> int:
    if not 1 <= args.k <= 255:
        raise CliError(f"--k {args.k}: must lie in 1..255")
    try:
        image = read_image(args.image)
        if image.shape[0] * image.shape[1] < args.k:
            raise CliError(f"image {args.image}: fewer pixels than --k {args.k} classes")
        write_mask(args.out, segment(image, args.method, args.k, args.seed, args.scale, args.segments))
    except ImageError as exc:
        raise CliError(str(exc)) from None
    return 0
