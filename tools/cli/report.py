"""`btf-host report --db DB --out DIR`: an HTML report of a database."""
from __future__ import annotations

import argparse
from pathlib import Path

from onboard.cli.runner import SEED
from tools.cli.options import CliError, add_source_filters, choose_source, writable_place
from tools.store.database import CorruptDatabase, Store


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--db", required=True, help="database written by listen, fit, ingest or demo")
    p.add_argument("--out", required=True,
                   help="output directory (created if missing; one holding a report needs --force)")
    p.add_argument("--force", action="store_true", help="replace the report in --out")
    p.add_argument("--seed", type=SEED, default=0, help="seed of the synthetic images")
    add_source_filters(p)
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _check_out(out: Path, force: bool) -> None:
    if out.exists() and not out.is_dir():
        raise CliError(f"--out {out} is not a directory")
    writable_place(out, f"--out {out}")
    if (out / "index.html").exists() and not force:
        raise CliError(f"--out {out}: {out / 'index.html'} exists; pass --force to replace the report")


def run(args: argparse.Namespace) -> int:
    # heavy (OpenCV, scipy): loaded to run, not for --help
    from tools.data.images import ImageError
    from tools.report.capture_views import Frames
    from tools.report.document import write_report

    if not Path(args.db).is_file():
        raise CliError(f"database {args.db}: no such file")
    out = Path(args.out)
    _check_out(out, args.force)
    try:
        with Store.open(args.db, create=False) as store:
            caps = store.captures()
            if not caps:
                raise CliError(f"database {args.db}: no captures to report")
            if args.robot is not None or args.scene is not None:
                # Several robots or scenes under one filter are fine here: the report lists them all.
                kept = [c for c in caps if args.robot in (None, c.robot) and args.scene in (None, c.scene)]
                if not kept:
                    choose_source(caps, args.db, args.robot, args.scene)  # names what the database holds
            # an ingested dataset's captures are shown beside the image each was fitted from
            path = write_report(store, out, measured=Frames(), seed=args.seed, robot=args.robot, scene=args.scene,
                                progress=not args.quiet)
    except CorruptDatabase as exc:
        raise CliError(str(exc)) from None
    except (ImageError, OSError) as exc:
        raise CliError(f"report {args.out}: {exc}") from None
    print(path)
    return 0
