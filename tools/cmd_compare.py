"""`btf-host compare`: the paper's metrics between a reference and a test image."""
from __future__ import annotations

import argparse
import json

from tools.cli import CliError


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("compare", help="correlation, histogram difference, chi2, KS, W1 between two images")
    p.add_argument("ref")
    p.add_argument("test")
    p.add_argument("--mask", help="label mask: histogram metrics per region")
    p.add_argument("--space", choices=("rgb", "hsv", "gray"), default="rgb",
                   help="hsv treats H as circular; gray compares one band (e.g. a thermal image)")
    p.add_argument("--json", action="store_true")
    return p


def run(args: argparse.Namespace) -> int:
    from tools.images import ImageError, feature_bands, read_image, read_mask
    from tools.metrics import METRICS, compare_bands

    try:
        ref = read_image(args.ref)
        test = read_image(args.test)
        if ref.dtype != test.dtype:
            raise ImageError(f"image {args.test}: {test.dtype.itemsize * 8}-bit pixels, {args.ref} has "
                             f"{ref.dtype.itemsize * 8}-bit; compare images of one depth")
        if ref.shape != test.shape:
            raise ImageError(f"image {args.test}: size {test.shape[1]}x{test.shape[0]} differs from "
                             f"{args.ref}'s {ref.shape[1]}x{ref.shape[0]}")
        mask = read_mask(args.mask, ref.shape[:2]) if args.mask else None
        a, _ = feature_bands(ref, args.space)
        del ref  # each image gives way to its bands: peak memory stays near the images themselves
        b, _ = feature_bands(test, args.space)
        del test
    except (ImageError, ValueError) as exc:
        raise CliError(str(exc)) from None
    circular = ("H",) if args.space == "hsv" else ()
    result = compare_bands(a.data, b.data, a.band_names, a.levels, mask, circular=circular)
    if args.json:
        doc = result.to_json()
        doc["space"] = args.space
        print(json.dumps(doc, indent=1))
        return 0
    print("correlation  " + "  ".join(f"{k} {v:.4f}" for k, v in result.correlation.items()))
    print(f"{'label':>5} {'band':>4} " + " ".join(f"{m:>9}" for m in METRICS))
    for r in result.regions:
        print(f"{r.label:5d} {r.band:>4} " + " ".join(f"{getattr(r, m):9.4f}" for m in METRICS))
    print(f"{'total':>10} " + " ".join(f"{result.total[m]:9.4f}" for m in METRICS))
    return 0
