"""`btf-host watch`: what the station sees, live (a status subscription), or its snapshot."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from tools.cli.options import CliError
from tools.report.look import azimuth_shown
from tools.station.control import StationClient, StationGone, socket_path
from tools.station.events import line


MISSING_SHOWN = 10  # a sweep's missing poses listed one a line; the rest counted


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--db", help="the station's database (its control socket is DB.sock)")
    p.add_argument("--socket", help="the station's control socket, if not DB.sock")
    p.add_argument("--snapshot", action="store_true", help="print what the station knows once and exit")
    p.add_argument("--json", action="store_true", help="one JSON object a line")


def run(args: argparse.Namespace) -> int:
    if not args.db and not args.socket:
        raise CliError("watch needs --db DB (or --socket PATH) of a running station")
    path = Path(args.socket) if args.socket else socket_path(args.db)
    try:
        client = StationClient.connect(path, timeout=10.0)
    except OSError as exc:
        raise CliError(f"control socket {path}: {exc.strerror or exc}") from None
    if client is None:
        raise CliError(f"no station serves {args.db or path} (start one with 'btf-host station')")
    try:
        client.send({"op": "snapshot" if args.snapshot else "subscribe"})
        first = client.receive(timeout=10.0)
        print(json.dumps(first["snapshot"]) if args.json else summary(first["snapshot"]), flush=True)
        if args.snapshot:
            return 0
        while True:
            ev = client.receive()["event"]
            if args.json:
                print(json.dumps(ev), flush=True)
            elif ev.get("shown", True):  # as its declaration says (tools.station.events)
                print(line(ev, timed=True), flush=True)
    except StationGone:
        raise CliError("the station stopped") from None
    finally:
        client.close()


def summary(s: dict) -> str:
    """The snapshot in a few lines, for a person."""
    from tools.station.rejected_frames import wrong_key_line  # the station's modules: not at btf-host's start

    ln, r, sw = s["link"], s["robot"], s["sweep"]
    pose = ("an unknown pose" if r["pose"] is None
            else f"{r['pose']['elevation']:.1f}°/{azimuth_shown(r['pose']['azimuth']):.1f}°")
    heard = "never" if ln["last_heard_s"] is None else f"{ln['last_heard_s']:g} s ago"
    rejected = ", ".join(f"{k} {v}" for k, v in ln["rejected"].items()) or "none"
    lines = [f"station on {s['station']['port']} -> {s['station']['db']} since {s['station']['started']}",
             f"link {'up' if ln['up'] else 'down'}, heard {heard}; frames sent {ln['frames_sent']}, "
             f"accepted {ln['frames_accepted']}, retransmitted {ln['retransmissions']}, rejected: {rejected}",
             _robot_line(r, pose)]
    if wrong := wrong_key_line(ln["rejected"].get("tag", 0), ln["frames_accepted"]):
        lines.append(wrong)
    if sw["id"] is not None and sw.get("missing") is not None:  # it ended: what it could not measure
        missing = sw["missing"]
        lines.append(f"sweep {sw['id']} done: {sw['measured']} measured, "
                     f"{len(missing) + sw.get('missing_left_out', 0)} missing")
        lines += [f"  missing {k['elevation']:.1f}°/{k['azimuth']:.1f}°"
                  f"{' after ' + str(k['tries']) + ' tries' if k.get('tries', 1) > 1 else ''}: {k['reason']}"
                  for k in missing[:MISSING_SHOWN]]
        if len(missing) > MISSING_SHOWN or sw.get("missing_left_out"):
            lines.append(f"  ... and {max(0, len(missing) - MISSING_SHOWN) + sw.get('missing_left_out', 0)} more")
    elif sw["id"] is not None:
        lines.append(f"sweep {sw['id']}: {sw['next']} of {sw['poses']} poses done, {len(sw['skipped'])} skipped"
                     + ("" if sw["active"] else " (not running)"))
    c = s["captures"]
    lines.append(f"captures stored since then {c['stored']}, duplicates {c['duplicates']}, masks {c['masks']}"
                 + (f", refused {c['bad']}" if c.get("bad") else ""))
    return "\n".join(lines)


def _robot_line(r: dict, pose: str) -> str:
    """What the station knows of the robot; a station just started may know nothing yet, or only
    what an answer to its STATUS said (answers do not carry the robot's id)."""
    refused = (r.get("dead_letters") or {}).get("count")
    if all(r[k] is None for k in ("id", "mode", "last_status", "outbox", "pose")) and not (
            r["faults"] or r["errors"] or refused):
        return "robot not heard yet"
    who = "robot (id not heard yet)" if r["id"] is None else f"robot {r['id']}"
    outbox = "?" if r["outbox"] is None else r["outbox"]
    return (f"{who}: {r['mode'] or 'mode unknown'} at {pose}, outbox {outbox}, faults {_count(r, 'faults')}, "
            f"errors {_count(r, 'errors')}" + (f", {refused} messages refused" if refused else ""))


def _count(robot: dict, name: str) -> str:
    """How many the robot listed, and how many older ones it left out."""
    older = (robot.get("left_out") or {}).get(name, 0)
    return f"{len(robot[name])}" + (f" (+{older} older)" if older else "")
