"""`btf-host ingest`: a model database from a folder of images (CUReT, UTIA or plain)."""
from __future__ import annotations

import argparse
import sys

from onboard.cli.runner import bounded
from tools.cli.options import CliError, band_names, elevation
from tools.data.datasets import DatasetError, Layout
from tools.data.ingest import INGEST_SPACES, NADIR, IngestError, ingest
from tools.store.database import CorruptDatabase


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = ("Fit every (image, label, band) of a dataset folder with the robot's fitter and store view and "
                     "illumination angles. Images already in the database are skipped.")
    p.add_argument("dir", help="dataset folder")
    p.add_argument("--layout", required=True, choices=[m.value for m in Layout],
                   help="curet: CUReT's sample folders and angles.txt; utia: UTIA's file names; folder: any images, "
                        "angles from angles.csv or --angle")
    p.add_argument("--db", required=True, help="the database to store into (created if missing; resumable)")
    p.add_argument("--mask", help="label mask PNG for every image, or a folder of <image stem>.png masks")
    p.add_argument("--space", choices=INGEST_SPACES,
                   help="the bands fitted (default: each image's own: gray for one band, rgb for colour, "
                        "raw for other counts)")
    p.add_argument("--band-names", type=band_names, metavar="NAMES",
                   help="raw bands by name, comma-separated in file order (e.g. blue,green,red,nir)")
    p.add_argument("--table", help="angle table (curet: angles.txt, folder: angles.csv in DIR by default)")
    p.add_argument("--angle", type=float, default=NADIR,
                   help="view elevation for a folder without angles (default: 90, straight down)")
    p.add_argument("--workers", type=bounded(int, 0, 256, "processes"),
                   help="local processes (default: CPU count; 0: this process)")
    p.add_argument("--scheduler", help="Dask scheduler address, e.g. tcp://host:8786")
    p.add_argument("--keep-going", action="store_true",
                   help="skip images that cannot be fitted, name them at the end and exit with status 1")
    p.add_argument("--independent-only", action="store_true",
                   help="skip measuring grain and band correlation (synthesis then draws independent pixels)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    # heavy (OpenCV, scipy): loaded to run, not for --help
    from tqdm import tqdm

    if args.scheduler is not None and args.workers is not None:
        raise CliError("--workers and --scheduler exclude each other: the cluster has its own workers")
    elevation(args.angle)
    bar: list = []
    try:
        report = ingest(args.dir, args.layout, args.db, mask=args.mask, space=args.space,
                        workers=args.workers, scheduler=args.scheduler, table=args.table,
                        default_elevation=args.angle,
                        on_total=lambda n: bar.append(tqdm(total=n, unit="img", disable=args.quiet)),
                        on_image=lambda _name: bar[0].update(1), keep_going=args.keep_going,
                        dependence=not args.independent_only, band_names=args.band_names)
    except (DatasetError, IngestError, CorruptDatabase) as exc:
        raise CliError(str(exc)) from None
    finally:
        for b in bar:
            b.close()
    damaged = f"{len(report.damaged)} damaged, " if args.keep_going else ""
    print(f"{report.stored} image(s) stored, {report.skipped} already there, {damaged}"
          f"{report.total} in the dataset; robot {report.robot}")
    if report.damaged:
        for d in report.damaged:
            print(f"btf-host: skipped {d.reason}", file=sys.stderr)
        print(f"btf-host: {len(report.damaged)} damaged image(s) skipped; fix or remove them and run "
              "ingest again (stored images are kept)", file=sys.stderr)
        return 1
    return 0
