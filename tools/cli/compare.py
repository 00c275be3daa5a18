"""`btf-host compare`: the paper's metrics between a reference and a test image."""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from onboard.cli.runner import bounded
from tools.analysis.radiometry import CLIPPED_REFERENCE, normalise_image, reference_means
from tools.cli.options import CliError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("ref", help="the reference image (a photograph)")
    p.add_argument("test", help="the image compared with it (a synthesis), same size and depth")
    p.add_argument("--mask", help="label mask: histogram metrics per region")
    p.add_argument("--space", choices=("rgb", "hsv", "gray", "raw"),
                   help="hsv treats H as circular; gray compares one band, raw the images' own bands (default: "
                        "the images' own: gray for one band, e.g. thermal, rgb for colour, raw for other counts)")
    p.add_argument("--reference-label", type=bounded(int, 0, 255), metavar="L",
                   help="scale TEST's bands so its mean on mask label L (the grey reference card) matches REF's: "
                        "takes out a change of light or exposure between the two (needs --mask)")
    p.add_argument("--json", action="store_true", help="print the metrics as one JSON document")


def _normalise(ref, test, mask, label: int, path: str) -> list[float]:
    """Scales `test` in place so its reference region's mean level per band is `ref`'s; the factors."""


    if mask is None:
        raise CliError("--reference-label needs --mask (which label is the reference card)")
    levels = 256 if test.dtype == np.uint8 else 65536
    try:
        want, have = reference_means(ref, mask, label), reference_means(test, mask, label)
    except ValueError as exc:
        raise CliError(f"mask: {exc}") from None
    if np.any(have <= 0) or np.any(want <= 0):
        raise CliError(f"image {path}: the reference region (label {label}) is black in a band; nothing to scale by")
    for image, name in ((ref, "REF"), (test, "TEST")):
        pixels = image[mask == label]  # (n, bands)
        clipped = float(np.mean(np.any((pixels <= 0) | (pixels >= levels - 1), axis=-1)))
        if clipped > CLIPPED_REFERENCE:
            print(f"btf-host: warning: {name}'s reference region has {clipped:.0%} of its pixels at a sensor limit; "
                  "its level understates the light", file=sys.stderr)
    factors = want / have
    normalise_image(test, factors, levels)
    return [float(f) for f in factors]


def run(args: argparse.Namespace) -> int:
    # heavy (OpenCV, scipy): loaded to run, not for --help
    from tools.analysis.metrics import (
        METRICS,
        compare_bands,
    )
    from tools.data.images import ImageError, default_space, feature_bands, read_image, read_mask

    try:
        ref = read_image(args.ref)
        test = read_image(args.test)
        if ref.dtype != test.dtype:
            raise ImageError(f"image {args.test}: {test.dtype.itemsize * 8}-bit pixels, {args.ref} has "
                             f"{ref.dtype.itemsize * 8}-bit; compare images of one depth")
        if ref.shape[:2] != test.shape[:2]:
            raise ImageError(f"image {args.test}: size {test.shape[1]}x{test.shape[0]} differs from "
                             f"{args.ref}'s {ref.shape[1]}x{ref.shape[0]}")
        mask = read_mask(args.mask, ref.shape[:2]) if args.mask else None
        if ref.shape[2] != test.shape[2] and 1 < min(ref.shape[2], test.shape[2]):
            raise ImageError(f"image {args.test}: {test.shape[2]} bands, {args.ref} has {ref.shape[2]}; "
                             "compare images of the same bands")
        space = args.space or default_space(ref)
        if ref.shape[2] != test.shape[2] and space != "gray":  # a one-band image against a colour one
            raise ImageError(f"image {args.test}: {test.shape[2]} band(s), {args.ref} has {ref.shape[2]}; "
                             "compare a one-band image with a colour one in gray (--space gray)")
        factors = None if args.reference_label is None else _normalise(ref, test, mask, args.reference_label, args.test)
        a, _ = feature_bands(ref, space)
        del ref  # each image gives way to its bands: peak memory stays near the images themselves
        b, _ = feature_bands(test, space)
        del test
    except (ImageError, ValueError) as exc:
        raise CliError(str(exc)) from None
    circular = ("H",) if space == "hsv" else ()
    result = compare_bands(a.data, b.data, a.band_names, a.levels, mask, circular=circular)
    if args.json:
        doc = result.to_json()
        doc["space"] = space
        if factors is not None:
            doc["reference"] = {"label": args.reference_label, "factors": factors}
        print(json.dumps(doc, indent=1))
        return 0
    if factors is not None:
        print(f"TEST scaled by {', '.join(f'{f:.4f}' for f in factors)} per band (reference label "
              f"{args.reference_label})")
    print("correlation  " + "  ".join(f"{k} {v:.4f}" for k, v in result.correlation.items()))
    print(f"{'label':>5} {'band':>4} " + " ".join(f"{m:>9}" for m in METRICS))
    for r in result.regions:
        print(f"{r.label:5d} {r.band:>4} " + " ".join(f"{getattr(r, m):9.4f}" for m in METRICS))
    print(f"{'total':>10} " + " ".join(f"{result.total[m]:9.4f}" for m in METRICS))
    return 0
