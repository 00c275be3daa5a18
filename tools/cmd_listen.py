"""`btf-host listen`: receive, authenticate, store and acknowledge the robot's packets.

A packet that cannot be stored ends it with one line and nothing of it acknowledged: status 1
for a database the disk has no room for (run it again once there is), 2 for a damaged one.
"""
from __future__ import annotations

import argparse
import json
import sys
import time

from onboard.cli_runner import RetryLater
from tools.cli import CliError


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser("listen", help="receive captures over a serial link into a database")
    p.add_argument("--port", required=True, help="pyserial URL: /dev/ttyUSB0, a pty path, socket://host:port, "
                   "btfsim://?port=URL&loss=0.2 (a simulated lossy radio)")
    p.add_argument("--db", required=True, help="SQLite database (created if missing)")
    p.add_argument("--key", required=True, help="link key file (btf-host keygen)")
    p.add_argument("--baud", type=int, default=115200)
    p.add_argument("--scene", default="", help="scene name to file the captures under")
    p.add_argument("--until-idle", type=float, default=0.0, metavar="S",
                   help="exit after S seconds without a delivered packet (0: run until Ctrl-C)")
    p.add_argument("--json", action="store_true", help="one JSON object per received packet on stdout")
    return p


def open_session(port_url: str, key_file: str, db: str | None, baud: int, scene: str = ""):
    """(HostSession, Store or None) for the CLI commands; CliError for any bad input."""
    from radio.auth import FileCounterStore
    from radio.keys import KeyFileError, counters_beside, load_key
    from radio.link import Link
    from radio.ports import open_url
    from radio.pump import LinkPump
    from tools.receiver import HOST_NODE, LINK_ID, ROBOT_NODE, HostSession, Receiver
    from tools.store import CorruptDatabase, Store, StoreUnavailable

    try:
        key = load_key(key_file)
    except KeyFileError as exc:
        raise CliError(str(exc)) from None
    except OSError as exc:
        raise RetryLater(f"key file {key_file}: {exc}") from None
    store = None
    if db is not None:
        try:
            store = Store.open(db)
        except StoreUnavailable as exc:  # a full disk, an I/O error: not the file's fault
            raise RetryLater(str(exc)) from None
        except CorruptDatabase as exc:
            raise CliError(str(exc)) from None
    try:
        # Counters survive restarts (and, by the clock, a lost file), so replays stay refused
        # and a running robot accepts the next session. listen and cmd speak as one host.
        counters = FileCounterStore(counters_beside(key_file))
    except ValueError as exc:
        if store is not None:
            store.close()
        raise CliError(str(exc)) from None
    try:
        port = open_url(port_url, baud, timeout=0.01)
    except Exception as exc:
        if store is not None:
            store.close()
        raise CliError(f"port {port_url}: cannot open: {exc}") from None
    if counters.note:  # the counters file was lost (or this host's first run with this key)
        print(f"btf-host: {counters.note}", file=sys.stderr)
    link = Link(HOST_NODE, ROBOT_NODE, LINK_ID, key, counters, heartbeat=1.0, link_timeout=5.0)
    return HostSession(LinkPump(link, port), Receiver(store, scene)), store


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from tools.receiver import StoreFailed

    if args.until_idle < 0:
        raise CliError(f"--until-idle {args.until_idle}: must not be negative")
    session, store = open_session(args.port, args.key, args.db, args.baud, args.scene)
    bar = tqdm(desc="captures", unit="cap", file=sys.stderr, disable=args.json or not sys.stderr.isatty())
    failed = None
    try:
        while True:
            for item in session.step():
                if args.json:
                    print(json.dumps(item.to_json()), flush=True)
                else:
                    tqdm.write(f"{item.kind.value:>9} robot {item.robot} seq {item.seq}: {item.text}"
                               + ("" if item.stored or item.kind.value not in ("capture", "mask", "unchanged")
                                  else " (already stored)"))
                if item.kind.value in ("capture", "unchanged") and item.stored:
                    bar.update()
            st = session.stats()
            bar.set_postfix(link="up" if session.up else "down", rejected=sum(st.rejected.values()),
                            retx=st.retransmissions, dup=st.duplicates, refresh=False)
            if args.until_idle and time.monotonic() - session.last_delivery > args.until_idle:
                break
    except KeyboardInterrupt:
        pass
    except StoreFailed as exc:  # nothing unstored was acknowledged: the robot sends it again
        failed = exc
    finally:
        bar.close()
        session.close()
        if store is not None:
            store.close()
    if failed is not None:
        text = f"{failed}; nothing unstored was acknowledged (the robot keeps it)"
        raise (CliError if failed.damaged else RetryLater)(text)
    st = session.stats()
    c = session.receiver.counts
    summary = {"captures": c["capture"] + c["unchanged"], "masks": c["mask"], "status": c["status"],
               "logs": c["log"], "bad": c["bad"], "duplicates": session.receiver.duplicates,
               "rejected": st.rejected, "retransmissions": st.retransmissions}
    if args.json:
        print(json.dumps({"kind": "summary", **summary}))
    else:
        print("received " + ", ".join(f"{k} {v}" for k, v in summary.items()), file=sys.stderr)
    return 0
