"""The options and checks that several `btf-host` subcommands share."""
from __future__ import annotations

import argparse
import math
import os
from collections import Counter
from pathlib import Path

from onboard.cli.runner import CliError, bounded
from radio.packets.base import band_names_problem

# The feature spaces of tools.data.images.SPACES, named here so that building the parser needs no OpenCV.
FEATURE_SPACES = ("rgb", "hsv", "gray", "pca", "raw")
BAUD = bounded(int, 50, 4_000_000, "bits/s")  # a serial port's speed


def add_force(parser: argparse.ArgumentParser, option: str = "--out") -> None:
    parser.add_argument("--force", action="store_true", help=f"replace an existing {option}")


# The image files OpenCV writes (the host's images are written with it).
IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".bmp", ".ppm", ".pgm")


def check_out(out: str | os.PathLike, inputs: tuple, force: bool, suffixes: tuple[str, ...] = IMAGE_SUFFIXES,
              option: str = "--out") -> Path:
    """The output file, checked before any work: refused when it is one of the command's inputs
    (even with --force), when its name ends in none of `suffixes`, when its directory is
    missing or not writable, or, without `force`, when it exists."""
    path = Path(out)
    for given in inputs:
        if given is not None and _same_file(path, Path(given)):
            raise CliError(f"{option} {out} is an input of this command ({given}); write somewhere else")
    if path.is_dir():
        raise CliError(f"{option} {out} is a directory; give a file name")
    if path.suffix.lower() not in suffixes:
        what = f"{path.suffix} is not a file type this command writes" if path.suffix else "the name has no file type"
        raise CliError(f"{option} {out}: {what}; end it in {', '.join(suffixes)}")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise CliError(f"{option} {out}: directory {parent} does not exist; create it first")
    writable_place(parent, f"{option} {out}")
    if path.exists() and not force:
        raise CliError(f"{option} {out} exists; pass --force to replace it")
    return path


def writable_place(directory: Path, said: str) -> None:
    """A directory a command can write into, or the nearest one it would be made in: else one line."""
    where = directory if str(directory) else Path(".")
    while not where.exists() and where != where.parent:
        where = where.parent
    if not where.is_dir():
        raise CliError(f"{said}: {where} is not a directory")
    if not os.access(where, os.W_OK | os.X_OK):
        raise CliError(f"{said}: cannot write in {where} (permission denied); choose another place")


def _same_file(a: Path, b: Path) -> bool:
    try:
        return a.exists() and b.exists() and os.path.samefile(a, b)
    except OSError:
        return a.resolve() == b.resolve()


def elevation(value: float, option: str = "--angle") -> float:
    """An elevation in degrees above the horizon: finite and within 0..90."""
    if not math.isfinite(value):
        raise CliError(f"{option} {value}: not a finite number of degrees")
    if not 0.0 <= value <= 90.0:
        raise CliError(f"{option} {value:g}: an elevation lies in 0..90 degrees")
    return value


LABEL_CHARS = 64


def label(text: str) -> str:
    """An argparse type: a robot or scene name as the database files captures under it."""
    if not 1 <= len(text) <= LABEL_CHARS or not text.isprintable():
        raise argparse.ArgumentTypeError(f"{text!r}: must be 1..{LABEL_CHARS} printable characters")
    return text


def band_names(text: str) -> tuple[str, ...]:
    """An argparse type: an image's bands by name, comma-separated, each as a capture carries one."""
    names = tuple(n.strip() for n in text.split(","))
    problem = band_names_problem(names)
    if problem:
        raise argparse.ArgumentTypeError(problem)
    return names


def add_source_filters(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--robot", help="only this robot's captures (as listed when several are stored)")
    parser.add_argument("--scene", help="only captures of this scene")


def holdings(captures) -> str:
    """What captures a database holds, per robot and scene: 'robot 1 scene dark (2 captures), ...'."""
    counts = Counter((c.robot, c.scene) for c in captures)
    if not counts:
        return "no captures"
    return ", ".join(f"robot {r}" + (f" scene {s}" if s else "") + f" ({n} capture{'s' * (n != 1)})"
                     for (r, s), n in sorted(counts.items()))


def choose_source(captures, db, robot: str | None, scene: str | None) -> tuple[str, str]:
    """The one (robot, scene) the filters leave; an error listing the database's content otherwise."""
    chosen = [c for c in captures if robot in (None, c.robot) and scene in (None, c.scene)]
    if not captures:
        raise CliError(f"database {db}: no captures")
    if not chosen:
        asked = " and ".join(f"{k} {v}" for k, v in (("robot", robot), ("scene", scene)) if v is not None)
        raise CliError(f"database {db}: no captures of {asked}; it holds {holdings(captures)}")
    pairs = sorted({(c.robot, c.scene) for c in chosen})
    if len(pairs) > 1:
        raise CliError(f"database {db} holds several robots and scenes: {holdings(chosen)}; "
                       "choose one with --robot or --scene")
    return pairs[0]


def sources_of(captures, db, robot: str | None, scene: str | None) -> list[tuple[str, str]]:
    """Every (robot, scene) the filters leave (several allowed); an error when there is none."""
    if not captures:
        raise CliError(f"database {db}: no captures")
    chosen = sorted({(c.robot, c.scene) for c in captures if robot in (None, c.robot) and scene in (None, c.scene)})
    if not chosen:
        choose_source(captures, db, robot, scene)  # names what the database holds
    return chosen

