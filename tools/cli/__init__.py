"""`btf-host`: the base-station command line.

Each subcommand lives in its own module `tools/cli/<name>.py`, exposing
`add_arguments(parser)` and `run(args) -> int`; the options several share are in
`tools.cli.options`. Bad input raises `CliError`, which prints one line and exits with
status 2.
"""
from __future__ import annotations

import argparse

from onboard.cli import runner
from onboard.cli.runner import Subcommand
from tools.store.schema import CorruptDatabase

PROG = "btf-host"
# The subcommands, in the order --help lists them: what each does, and one example.
COMMANDS: tuple[Subcommand, ...] = (
    Subcommand("fit", "fit Johnson models per (label, band) of an image",
               "fit photo.png --mask mask.png --json > models.json"),
    Subcommand("mask", "segment an image into K clutter classes",
               "mask photo.png --method kmeans --k 4 --out mask.png"),
    Subcommand("synth", "synthesize an image from models inside a mask",
               "synth --model models.json --mask mask.png --out synth.png"),
    Subcommand("compare", "correlation, histogram difference, chi2, KS and W1 between two images",
               "compare photo.png synth.png --mask mask.png"),
    Subcommand("pdfs", "the paper's Table 2: histogram error of Johnson against its peers per region",
               "pdfs photo.png --mask mask.png"),
    Subcommand("spaces", "the paper's Table 1 on any photograph: every mask x feature space judged, and the choice",
               "spaces photo.png --masks isodata5,isodata8 --spaces rgb,hsv,pca --picture spaces.png"),
    Subcommand("ingest", "fit every image of a dataset folder into a database (resumable)",
               "ingest DATASET_DIR --layout folder --db dataset.db"),
    Subcommand("resolve", "facet-based or statistical modelling for a grain size",
               "resolve --grain-mm 0.5"),
    Subcommand("report", "an HTML report of a database: results first, then images, plots and tables",
               "report --db demo-out/scene.db --out report"),
    Subcommand("btf", "the BTF as a table: models, moments and leave-one-out per region, band and angle",
               "btf --db demo-out/scene.db --scene mixed --plot mixed-btf.png"),
    Subcommand("export", "the BTF as Parquet or CSV for pandas, DuckDB and Dask: a row per capture, region and band",
               "export --db demo-out/scene.db --out btf-parquet"),
    Subcommand("demo", "everything on fakes: robots over a lossy radio into a database, experiments, report",
               "demo --out demo-out"),
    Subcommand("station", "own the radio: store what the robot sends, serve commands, watchers and the page",
               "station --port /dev/ttyUSB0 --db scene.db --key robot.key --http 8765"),
    Subcommand("listen", "the station in the foreground, printing each packet it stores",
               "listen --port /dev/ttyUSB0 --db scene.db --key robot.key"),
    Subcommand("cmd", "send the robot a command through the station and print its answer",
               "cmd --db scene.db goto --elevation 60 --azimuth 90"),
    Subcommand("watch", "follow a running station: its events as they happen, or its snapshot",
               "watch --db scene.db --snapshot"),
    Subcommand("keygen", "write a fresh 32-byte link key (hex, mode 0600)",
               "keygen --out robot.key"),
    Subcommand("linktest", "exercise the link protocol through a simulated lossy radio",
               "linktest --loss 0.2 --bursty --packets 500"),
    Subcommand("decode", "a recorded byte stream of frames as JSON lines",
               "decode capture.bin --key robot.key"),
)


DESCRIPTION = "The base station of btfscout: fit, synthesize, compare and report; own the radio."


def build_parser() -> argparse.ArgumentParser:
    """The whole parser, every subcommand's arguments included."""
    return runner.build_parser(PROG, "tools.cli", COMMANDS, DESCRIPTION)


def main(argv: list[str] | None = None) -> int:
    # A damaged row met by any reader (synth, report, ...) is one line and status 2, as at opening.
    return runner.main(PROG, "tools.cli", COMMANDS, DESCRIPTION, argv, bad_input=(CorruptDatabase,))
