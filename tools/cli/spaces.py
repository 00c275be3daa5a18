"""`btf-host spaces`: which mask and feature space to model a photograph in (the paper's Table 1)."""
from __future__ import annotations

import argparse
import re

from onboard.cli.runner import SEED
from tools.cli.options import FEATURE_SPACES, CliError, add_force, check_out

MASK_METHODS = ("isodata", "kmeans", "slic", "felzenszwalb")
DEFAULT_MASKS = "isodata5,isodata8"
DEFAULT_CLASSES = 5  # a mask method named without its number of classes


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = ("Fit, synthesize and judge a photograph under every mask x feature space: Table 1 (each "
                     "synthesis's correlation per band with the photograph), the Table-2 error, the fit's exact L1, "
                     "the band decorrelation, the texture figures, bytes on the wire and fit time. The last line is "
                     "the choice and its reason (docs/spaces.md gives the criterion).")
    p.add_argument("image", nargs="?", help="the photograph (8- or 16-bit PNG, TIFF, JPEG); not with --db")
    masks = p.add_mutually_exclusive_group()
    masks.add_argument("--mask", help="one label mask PNG, same size as the photograph, instead of --masks")
    masks.add_argument("--masks", default=None, metavar="LIST",
                       help=f"masks to make, comma-separated: a method ({', '.join(MASK_METHODS)}) and its classes, "
                            f"e.g. isodata5, kmeans4 (no number: {DEFAULT_CLASSES}); default {DEFAULT_MASKS}")
    p.add_argument("--spaces", metavar="LIST",
                   help=f"feature spaces, comma-separated, of {', '.join(FEATURE_SPACES)} (default: every space the "
                        "photograph offers: gray alone for one band, rgb and gray at 16 bits)")
    p.add_argument("--seed", type=SEED, default=0,
                   help="seed of the masks and the syntheses; the Table-2 error is drawn at SEED and SEED+1, their "
                        "difference is its noise")
    p.add_argument("--json", action="store_true", help="print the table and the choice as one JSON document")
    p.add_argument("--picture", metavar="OUT.png",
                   help="write the photograph beside the chosen and the worst synthesis (an existing file needs --force)")
    add_force(p)
    p.add_argument("--db", help="database of captures: judge a stored capture (with --capture) instead of a file")
    p.add_argument("--capture", metavar="ROBOT/SEQ", help="with --db: the capture whose image to judge")
    p.add_argument("--robot-config", metavar="ROBOT.toml",
                   help="with --db: a fake robot's configuration, whose scene renders a robot capture's frame")


def mask_specs(text: str) -> list[tuple[str, str, int]]:
    """(name, method, classes) of each item of --masks."""
    out = []
    for item in (t.strip() for t in text.split(",")):
        m = re.fullmatch(r"([a-z]+)(\d*)", item)
        if not m or m.group(1) not in MASK_METHODS:
            raise CliError(f"--masks {text}: {item!r} is not a mask; give a method ({', '.join(MASK_METHODS)}) "
                           "and its classes, e.g. isodata5")
        k = int(m.group(2)) if m.group(2) else DEFAULT_CLASSES
        if not 1 <= k <= 255:
            raise CliError(f"--masks {text}: {item} asks for {k} classes; give 1..255")
        out.append((item, m.group(1), k))
    if len({n for n, _, _ in out}) != len(out):
        raise CliError(f"--masks {text}: a mask named twice")
    return out


def space_names(text: str | None) -> tuple[str, ...] | None:
    """The spaces --spaces names (None: every space the photograph offers)."""
    if text is None:
        return None
    asked = tuple(t.strip() for t in text.split(","))
    bad = [s for s in asked if s not in FEATURE_SPACES]
    if bad:
        raise CliError(f"--spaces {text}: {', '.join(bad)} is not a feature space; choose from {', '.join(FEATURE_SPACES)}")
    if len(set(asked)) != len(asked):
        raise CliError(f"--spaces {text}: a space named twice")
    return asked


def run(args: argparse.Namespace) -> int:
    if args.picture:
        check_out(args.picture, (args.image, args.mask), args.force, suffixes=(".png",), option="--picture")
    masks = mask_specs(args.masks or DEFAULT_MASKS)  # said before any work
    spaces = space_names(args.spaces)
    from tools.cli.spaces_run import execute  # heavy (OpenCV, scipy): loaded to run, not for --help

    return execute(args, masks, spaces)
