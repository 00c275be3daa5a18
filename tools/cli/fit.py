"""`btf-host fit`: Johnson models from an image on disk, with the robot's own fitter."""
from __future__ import annotations

import argparse
import dataclasses
import json
import time

import numpy as np

from btf.dependence import window
from onboard.cli.runner import RetryLater
from tools.cli.options import FEATURE_SPACES, CliError, band_names, elevation, label
from tools.store.database import CorruptDatabase, Store, StoreUnavailable

ROBOT_ID = "host"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = "Fit Johnson models per (label, band); without --mask the whole image is label 0."
    p.add_argument("image", help="the photograph to fit (8- or 16-bit PNG, TIFF, JPEG)")
    p.add_argument("--mask", help="label mask PNG, same size as the image")
    p.add_argument("--space", choices=FEATURE_SPACES + ("auto",),
                   help="feature space (default: the image's own: gray for a one-band image, rgb for colour, "
                        "raw for other counts); auto chooses it as btf-host spaces does (docs/spaces.md)")
    p.add_argument("--angle", type=float, help="view elevation in degrees (needed with --db)")
    p.add_argument("--db", help="store the models as a capture in this database, under --robot and --scene")
    p.add_argument("--robot", type=label, default=ROBOT_ID, metavar="NAME",
                   help=f"with --db: the camera or series the photograph belongs to (default {ROBOT_ID!r})")
    p.add_argument("--scene", type=label, metavar="NAME",
                   help="with --db: the sample or place photographed; photographs of different robots or scenes "
                        "are never interpolated together (synth and report choose one with --robot and --scene)")
    p.add_argument("--band-names", type=band_names, metavar="NAMES",
                   help="space raw: the image's bands by name, comma-separated in file order (e.g. "
                        "blue,green,red,nir); the report draws those named red, green and blue as colour")
    p.add_argument("--json", action="store_true", help="print the models document (MODELS.json)")
    p.add_argument("--independent-only", action="store_true",
                   help="skip measuring grain and band correlation (synthesis then draws independent pixels)")


def _open(db: str) -> Store:
    """The database, opened before any fitting: a wrong path or file is said at once."""
    try:
        return Store.open(db)
    except StoreUnavailable as exc:  # a full disk, an I/O error: not the file's fault (exit 1)
        raise RetryLater(str(exc)) from None
    except CorruptDatabase as exc:
        raise CliError(str(exc)) from None


def _store(store: Store, args: argparse.Namespace, fitted, choice=None) -> int:
    """Stores the fit as the next capture of --robot under --scene; its sequence number."""
    try:
        with store.batch():  # the capture, its mask and its space's reason: all stored, or none
            seq = store.next_sequence(args.robot)
            if not store.add_capture(args.robot, seq, time.time(), None, (args.angle, 0.0),
                                     fitted.feats.space.value, fitted.feats.band_names, fitted.results,
                                     scene=args.scene or "", dependence=fitted.dependence,
                                     levels=fitted.feats.levels, pca=fitted.pca):
                raise CliError(f"database {args.db}: capture {args.robot}/{seq} was taken by another writer; "
                               "not stored (run fit again)")
            if args.mask:
                store.add_mask(f"{args.robot}/{seq}", fitted.labels, args.robot)
            if choice is not None:
                store.add_space_choice(args.robot, seq, choice.reason)
    except CorruptDatabase as exc:
        raise CliError(str(exc)) from None
    return seq


def run(args: argparse.Namespace) -> int:
    if args.db and args.angle is None:
        raise CliError("--db needs --angle: every stored capture has a view angle")
    if not args.db and (args.robot != ROBOT_ID or args.scene is not None):
        raise CliError("--robot and --scene label what --db stores: give --db DB too")
    if args.angle is not None:
        elevation(args.angle)
    if args.band_names and args.space not in (None, "raw"):
        raise CliError(f"--band-names names an image's own bands: use it with --space raw, not {args.space}")
    store = _open(args.db) if args.db else None
    try:
        return _fit(args, store)
    finally:
        if store is not None:
            store.close()


def _auto(args: argparse.Namespace):
    """The space `--space auto` fits in (btf.fit.space_choice over the photograph's spaces)."""
    # heavy (OpenCV, scipy): loaded to run, not for --help
    from tools.analysis.spaces import auto_space
    from tools.data.images import read_image, read_mask

    image = read_image(args.image)
    labels = read_mask(args.mask, image.shape[:2]) if args.mask else np.zeros(image.shape[:2], np.uint8)
    return auto_space(image, labels)


def _named(fitted, names: tuple[str, ...]):
    """The fit with its raw bands under the names given."""
    feats = fitted.feats
    if feats.space.value != "raw":
        raise CliError(f"--band-names names an image's own bands; this fit is in {feats.space.value} "
                       f"(bands {', '.join(feats.band_names)}): add --space raw")
    if len(names) != len(feats.band_names):
        raise CliError(f"--band-names gives {len(names)} names for an image of {len(feats.band_names)} bands")
    return dataclasses.replace(fitted, feats=dataclasses.replace(feats, band_names=names))


def _fit(args: argparse.Namespace, store: Store | None) -> int:
    # heavy (OpenCV, scipy): loaded to run, not for --help
    from tools.analysis.models_doc import models_document
    from tools.data.images import fit_image

    try:
        choice = _auto(args) if args.space == "auto" else None
        space = choice.space if choice is not None else args.space
        fitted = fit_image(args.image, args.mask, space, dependence=not args.independent_only)
    except ValueError as exc:  # ImageError too
        raise CliError(str(exc)) from None
    if args.band_names:
        fitted = _named(fitted, args.band_names)
    feats, pca, results = fitted.feats, fitted.pca, fitted.results
    doc = models_document(feats.space.value, feats.band_names, feats.levels, args.angle, results,
                          pca=None if pca is None else pca.to_record(), image=str(args.image),
                          dependence=fitted.dependence)  # levels only with --independent-only
    if choice is not None:
        doc["space_choice"] = {"automatic": True, "reason": choice.reason}
    if store is not None:
        seq = _store(store, args, fitted, choice)
        doc["stored"] = {"db": str(args.db), "robot": args.robot, "scene": args.scene or "", "sequence": seq}
    if args.json:
        print(json.dumps(doc, indent=1))
    else:
        for row in doc["models"]:
            seen = f"  levels {row['lo']}..{row['hi']}" if "lo" in row else ""
            print(f"label {row['label']:3d} band {row['band_name']:>3}  {row['family']:<5} "
                  f"gamma {row['gamma']:9.4f} delta {row['delta']:8.4f} xi {row['xi']:9.3f} "
                  f"lam {row['lam']:9.3f}  n {row['count']}{seen}")
        _print_dependence(doc["dependence"], feats.band_names)
        if choice is not None:
            print(f"space chosen automatically: {choice.reason}")
        if store is not None:
            scene = f" (scene {args.scene})" if args.scene else ""
            print(f"stored as capture {args.robot}/{seq}{scene} in {args.db}")
    return 0


def _print_dependence(section: dict | None, band_names: tuple[str, ...]) -> None:
    """One line per region: the autocorrelation at the nearest lags across, down and along both
    diagonals (band average; "?" where no band's lag was measured), and the band correlations."""
    if section is None:
        return
    pairs = [(a, b) for i, a in enumerate(band_names) for b in band_names[i + 1:]]
    for reg in section["regions"]:
        lags = window(reg["radius"])
        known = [[v for v in col if v is not None] for col in zip(*reg["acf"])]  # None: not measured
        mean = [f"{sum(col) / len(col):.2f}" if col else "?" for col in known]
        grain = " ".join(f"{dy},{dx}:{mean[lags.index((dy, dx))]}" for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)))
        colour = " ".join(f"{a}{b} {r:.2f}" for (a, b), r in zip(pairs, reg["corr"]))
        print(f"label {reg['label']:3d} grain dy,dx:r {grain}" + (f"  bands {colour}" if colour else ""))
