"""`btf-host listen`: the station in the foreground, printing each packet it receives, stores
and acknowledges; it serves `cmd` clients like `btf-host station`."""
from __future__ import annotations

import argparse
import asyncio
import json
import sys
import time

from onboard.cli.runner import bounded
from tools.cli.options import CliError
from tools.cli.station import add_station_options
from tools.station.start import open_station, serve


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_station_options(p, log=False)
    p.add_argument("--until-idle", type=bounded(float, 0, 86400, "s"), default=0.0, metavar="S",
                   help="exit after S seconds without a delivered packet (0: run until Ctrl-C)")
    p.add_argument("--json", action="store_true", help="one JSON object per received packet on stdout")


def run(args: argparse.Namespace) -> int:
    # heavy (OpenCV, scipy): loaded to run, not for --help
    from tqdm import tqdm

    bar = tqdm(desc="captures", unit="cap", file=sys.stderr, disable=args.json or not sys.stderr.isatty())

    def show(item) -> None:
        if args.json:
            print(json.dumps(item.to_json()), flush=True)
        elif item.kind.value == "link":  # the link itself (a wrong key, stale counters): its line alone
            tqdm.write(f"{item.kind.value:>9}: {item.text}")
        else:
            tqdm.write(f"{item.kind.value:>9} robot {item.robot} seq {item.seq}: {item.text}"
                       + ("" if item.stored or item.kind.value not in ("capture", "mask", "unchanged")
                          else " (already stored)"))
        if item.kind.value in ("capture", "unchanged") and item.stored:
            bar.update()
        st = parts.station.pump.stats()
        bar.set_postfix(link="up" if parts.station.pump.up else "down", rejected=sum(st.rejected.values()),
                        retx=st.retransmissions, dup=st.duplicates, refresh=False)

    # The station in the foreground: it serves `cmd` too; its log goes to DB.log only.
    parts = open_station(args.port, args.key, args.db, baud=args.baud, scene=args.scene, sock=args.socket,
                         echo=None, status_every=0, on_item=show)
    station = parts.station
    idle = (lambda: time.monotonic() - station.last_delivery > args.until_idle) if args.until_idle else None
    try:
        asyncio.run(serve(parts, until=idle))
    finally:
        bar.close()
        parts.close()
    if station.failure is not None and station.failure.status == 2:
        raise CliError(str(station.failure))
    st = station.pump.stats()
    c = station.receiver.counts
    summary = {"captures": c["capture"] + c["unchanged"], "masks": c["mask"], "status": c["status"],
               "logs": c["log"], "bad": c["bad"], "duplicates": station.receiver.duplicates,
               "rejected": st.rejected, "retransmissions": st.retransmissions}
    if args.json:
        print(json.dumps({"kind": "summary", **summary}))
    else:
        print("received " + ", ".join(f"{k} {v}" for k, v in summary.items()), file=sys.stderr)
    if station.failure is not None:
        print(f"btf-host: error: {station.failure}", file=sys.stderr)
        return station.failure.status
    if station.wrong_key:  # it listened to the end; nothing it heard could be read
        print(f"btf-host: error: {station.wrong_key}", file=sys.stderr)
        return 2
    return 0
