"""`btf-host cmd`: one remote-control command to the robot, printing its answer."""
from __future__ import annotations

import argparse
import json
import time

from tools.cli import CliError


def _floats(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected comma-separated numbers") from None


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser("cmd", help="send the robot a command and print its answer")
    p.add_argument("--port", required=True, help="pyserial URL of the link")
    p.add_argument("--key", required=True, help="link key file")
    p.add_argument("--baud", type=int, default=115200)
    p.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for the answer")
    p.add_argument("--json", action="store_true", help="print the answer as one JSON object")
    c = p.add_subparsers(dest="what", required=True, metavar="COMMAND")
    g = c.add_parser("goto", help="move the arm")
    g.add_argument("--elevation", type=float, required=True)
    g.add_argument("--azimuth", type=float, default=0.0)
    c.add_parser("capture", help="capture at the current pose")
    s = c.add_parser("sweep", help="start a sweep: --start/--stop/--step or --elevations")
    s.add_argument("--start", type=float, help="first elevation, e.g. 90")
    s.add_argument("--stop", type=float, help="last elevation, e.g. 30")
    s.add_argument("--step", type=float, help="elevation step, e.g. 10")
    s.add_argument("--elevations", type=_floats, help="explicit elevations, e.g. 90,80,70")
    s.add_argument("--azimuths", type=_floats, default=[0.0], help="e.g. 0,90")
    c.add_parser("abort", help="stop the sweep and hold the arm")
    st = c.add_parser("set", help="change a run-time setting")
    st.add_argument("setting", help="section.key, e.g. skip.min_pixels")
    st.add_argument("value", help="the value (JSON if it parses, else a string)")
    c.add_parser("status", help="the robot's state")
    c.add_parser("torque-off", help="stop and release the servos")
    m = c.add_parser("send-mask", help="re-send the label map of a capture")
    m.add_argument("--seq", type=int, required=True, help="capture sequence number")
    return p


def command_of(args: argparse.Namespace):
    """(CommandName, args) for the parsed subcommand."""
    from radio.packet import CommandName as C

    w = args.what
    if w == "goto":
        return C.GOTO, {"elevation": args.elevation, "azimuth": args.azimuth}
    if w == "sweep":
        ranged = (args.start, args.stop, args.step)
        if args.elevations is not None and any(v is not None for v in ranged):
            raise CliError("sweep takes either --start/--stop/--step or --elevations, not both")
        if not args.azimuths:
            raise CliError("sweep needs at least one azimuth")
        if args.elevations is not None:
            if not args.elevations:
                raise CliError("sweep needs at least one elevation")
            return C.SWEEP, {"elevations": args.elevations, "azimuths": args.azimuths}
        if any(v is None for v in ranged):
            raise CliError("sweep needs --start, --stop and --step (or --elevations)")
        return C.SWEEP, {"start": args.start, "stop": args.stop, "step": args.step,
                         "azimuths": args.azimuths}
    if w == "set":
        try:
            value = json.loads(args.value)
        except ValueError:
            value = args.value
        return C.SET, {"key": args.setting, "value": value}
    if w == "send-mask":
        if args.seq < 0:
            raise CliError(f"--seq {args.seq}: must not be negative")
        return C.SEND_MASK, {"seq": args.seq}
    return {"capture": C.CAPTURE, "abort": C.ABORT, "status": C.STATUS, "torque-off": C.TORQUE_OFF}[w], {}


def run(args: argparse.Namespace) -> int:
    from radio import packet as pk
    from tools.cmd_listen import open_session

    name, cargs = command_of(args)
    try:
        pk.encode(pk.CommandPacket(0, name, cargs))
    except ValueError as exc:
        raise CliError(f"{args.what}: {exc}") from None
    session, _ = open_session(args.port, args.key, None, args.baud)
    try:
        cid = session.command(name, cargs)
        t0 = time.monotonic()
        while cid not in session.answers:
            if time.monotonic() - t0 > args.timeout:
                raise CliError(f"no answer from the robot within {args.timeout:g} s")
            session.step()
        # One more turn so our acknowledgement of the answer goes out.
        session.step()
    finally:
        session.close()
    item = session.answers[cid]
    ok = isinstance(item.packet, pk.AckPacket)
    if args.json:
        print(json.dumps({"command": args.what, "ok": ok, **item.to_json()["packet"]}))
    else:
        extras = ", ".join(f"{k}={v}" for k, v in item.packet.extras.items())
        print(f"{item.text}" + (f" ({extras})" if extras else ""))
    return 0 if ok else 1
