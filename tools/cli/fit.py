"""`btf-host fit`: Johnson models from an image on disk, with the robot's own fitter."""
from __future__ import annotations

import argparse
import json
import time

from tools.cli.options import FEATURE_SPACES, CliError, elevation
from tools.store.database import CorruptDatabase, Store

ROBOT_ID = "host"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = "Fit Johnson models per (label, band); without --mask the whole image is label 0."
    p.add_argument("image")
    p.add_argument("--mask", help="label mask PNG, same size as the image")
    p.add_argument("--space", choices=FEATURE_SPACES, default="rgb")
    p.add_argument("--angle", type=float, help="view elevation in degrees (needed with --db)")
    p.add_argument("--db", help="store the models as a capture of robot 'host' in this database")
    p.add_argument("--json", action="store_true", help="print the models document (MODELS.json)")
    p.add_argument("--independent-only", action="store_true",
                   help="skip measuring grain and band correlation (synthesis then draws independent pixels)")


def _store(args: argparse.Namespace, fitted) -> int:
    """Stores the fit as the next capture of robot 'host'; its sequence number."""
    try:
        with Store.open(args.db) as store:
            seq = store.next_sequence(ROBOT_ID)
            if not store.add_capture(ROBOT_ID, seq, time.time(), None, (args.angle, 0.0), args.space,
                                     fitted.feats.band_names, fitted.results, dependence=fitted.dependence,
                                     levels=fitted.feats.levels):
                raise CliError(f"database {args.db}: capture {ROBOT_ID}/{seq} was taken by another writer; "
                               "not stored (run fit again)")
            if args.mask:
                store.add_mask(f"{ROBOT_ID}/{seq}", fitted.labels, ROBOT_ID)
    except CorruptDatabase as exc:
        raise CliError(str(exc)) from None
    return seq


def run(args: argparse.Namespace) -> int:
    # heavy (OpenCV, scipy): loaded to run, not for --help
    from tools.analysis.synth import models_document
    from tools.data.images import fit_image

    if args.db and args.angle is None:
        raise CliError("--db needs --angle: every stored capture has a view angle")
    if args.angle is not None:
        elevation(args.angle)
    try:
        fitted = fit_image(args.image, args.mask, args.space, dependence=not args.independent_only)
    except ValueError as exc:  # ImageError too
        raise CliError(str(exc)) from None
    feats, pca, results = fitted.feats, fitted.pca, fitted.results
    doc = models_document(args.space, feats.band_names, feats.levels, args.angle, results,
                          pca=None if pca is None else pca.to_record(), image=str(args.image),
                          dependence=None if args.independent_only else fitted.dependence)
    if args.db:
        seq = _store(args, fitted)
        doc["stored"] = {"db": str(args.db), "robot": ROBOT_ID, "sequence": seq}
    if args.json:
        print(json.dumps(doc, indent=1))
    else:
        for row in doc["models"]:
            print(f"label {row['label']:3d} band {row['band_name']:>3}  {row['family']:<5} "
                  f"gamma {row['gamma']:9.4f} delta {row['delta']:8.4f} xi {row['xi']:9.3f} "
                  f"lam {row['lam']:9.3f}  n {row['count']}")
        _print_dependence(doc["dependence"], feats.band_names)
        if args.db:
            print(f"stored as capture {ROBOT_ID}/{seq} in {args.db}")
    return 0


def _print_dependence(section: dict | None, band_names: tuple[str, ...]) -> None:
    """One line per region: autocorrelation at each lag along rows and columns, band correlations."""
    if section is None:
        return
    lags = section["lags"]
    pairs = [(a, b) for i, a in enumerate(band_names) for b in band_names[i + 1:]]
    for reg in section["regions"]:
        grain = " ".join(f"{lag}:{x:.2f}/{y:.2f}" for lag, x, y in zip(lags, reg["dx"], reg["dy"]))
        colour = " ".join(f"{a}{b} {r:.2f}" for (a, b), r in zip(pairs, reg["corr"]))
        print(f"label {reg['label']:3d} grain lag:h/v {grain}" + (f"  bands {colour}" if colour else ""))
