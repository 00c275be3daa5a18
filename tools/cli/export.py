"""`btf-host export --db DB --out DIR [--format parquet|csv]`: the database's BTF as files pandas,
DuckDB and Dask read (tools.data.export; docs/export.md), partitioned by robot and scene."""
from __future__ import annotations

import argparse
from pathlib import Path

from tools.cli.options import CliError, add_force, writable_place
from tools.store.database import CorruptDatabase, Store

FORMATS = ("parquet", "csv")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--db", required=True, help="database written by station, listen, ingest or demo")
    p.add_argument("--out", required=True,
                   help="output directory; an earlier export of the same database gets only the new captures")
    p.add_argument("--format", default="parquet", choices=FORMATS, help="parquet (default) or csv")
    add_force(p)


def run(args: argparse.Namespace) -> int:
    if not Path(args.out).is_file():  # a file is refused by the export itself
        writable_place(Path(args.out), f"--out {args.out}")
    from tools.data.export import ExportError, export  # pyarrow: loaded to run, not for --help

    try:
        with Store.open(args.db, create=False) as store:
            if not store.captures():
                raise CliError(f"database {args.db}: no captures to export")
            report = export(store, args.out, args.format, replace=args.force)
    except (ExportError, CorruptDatabase) as exc:
        raise CliError(str(exc)) from None
    except OSError as exc:
        raise CliError(f"--out {args.out}: cannot write ({exc.strerror or exc})") from None
    what = "new export" if report.fresh else "added to the export"
    print(f"{report.out}: {what}: {report.rows} row(s) in {report.files} file(s), "
          f"{report.partitions} robot and scene partition(s)")
    return 0
