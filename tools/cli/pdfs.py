"""`btf-host pdfs`: the paper's Table 2, Johnson against its peers per (label, band)."""
from __future__ import annotations

import argparse
import json

from onboard.cli.runner import SEED
from tools.cli.options import FEATURE_SPACES, CliError


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("image", help="the photograph (8- or 16-bit PNG, TIFF, JPEG)")
    p.add_argument("--mask", required=True, help="label mask PNG, same size as the image: one row per region")
    p.add_argument("--space", choices=FEATURE_SPACES,
                   help="the bands compared (default: the image's own: gray for a one-band image, rgb for colour, "
                        "raw for other counts)")
    p.add_argument("--seed", type=SEED, default=0, help="seed of the peers' samples (the same seed, the same table)")
    p.add_argument("--json", action="store_true", help="print the table as one JSON document")


def run(args: argparse.Namespace) -> int:
    # heavy (OpenCV, scipy): loaded to run, not for --help
    from tools.analysis.pdfs import PEERS, table
    from tools.data.images import ImageError, feature_bands, read_image, read_mask

    try:
        image = read_image(args.image)
        mask = read_mask(args.mask, image.shape[:2])
        feats, _ = feature_bands(image, args.space)
    except (ImageError, ValueError) as exc:
        raise CliError(str(exc)) from None
    t = table(feats.data, mask, feats.band_names, levels=feats.levels, seed=args.seed)
    if args.json:
        doc = t.to_json()
        doc["space"] = feats.space.value
        print(json.dumps(doc, indent=1))
        return 0
    print(f"{'label':>5} {'band':>4} {'count':>8} " + " ".join(f"{p:>10}" for p in PEERS))
    for r in t.rows:
        print(f"{r.label:5d} {r.band:>4} {r.count:8d} " + " ".join(f"{r.errors[p]:10.4f}" for p in PEERS))
    print(f"{'total':>19} " + " ".join(f"{t.total[p]:10.4f}" for p in PEERS))
    return 0
