"""`btf-host report --db DB --out DIR`: an HTML report of a database."""
from __future__ import annotations

import argparse
from pathlib import Path

from tools.cli import CliError


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser("report", help="an HTML report with images, histograms and tables")
    p.add_argument("--db", required=True, help="database written by listen, fit or demo")
    p.add_argument("--out", required=True, help="output directory (created if missing)")
    p.add_argument("--seed", type=int, default=0, help="seed of the synthetic images")
    return p


def run(args: argparse.Namespace) -> int:
    from tools.images import ImageError
    from tools.report import write_report
    from tools.store import CorruptDatabase, Store

    if not Path(args.db).is_file():
        raise CliError(f"database {args.db}: no such file")
    try:
        with Store.open(args.db, create=False) as store:
            if not store.captures():
                raise CliError(f"database {args.db}: no captures to report")
            path = write_report(store, Path(args.out), seed=args.seed)
    except CorruptDatabase as exc:
        raise CliError(str(exc)) from None
    except (ImageError, OSError) as exc:
        raise CliError(f"report {args.out}: {exc}") from None
    print(path)
    return 0
