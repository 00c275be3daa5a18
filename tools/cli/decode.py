"""`btf-host decode FILE`: a recorded byte stream of frames as JSON lines."""
from __future__ import annotations

import argparse
import binascii
import json
from pathlib import Path

from cobs import cobs

from radio import FrameError
from radio import packets as pk
from radio.auth import MemoryCounterStore
from radio.frame import CRC_LEN, HEADER, OVERHEAD, Deframer, FrameKind, decode
from radio.keys import KeyFileError, load_key
from radio.link import Delivered, Link
from tools.cli.options import CliError
from tools.station.receiver import packet_json


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", help="raw bytes as read from the serial port")
    a = p.add_mutually_exclusive_group(required=True)
    a.add_argument("--key", help="link key file: authenticate frames and decode their packets")
    a.add_argument("--no-auth", action="store_true", help="unauthenticated: frame headers only")


def headers(bodies: list[bytes]) -> list[dict]:
    """Frame headers without the key: CRC checked, the tag not (marked so)."""

    out = []
    for i, raw in enumerate(bodies):
        row: dict = {"frame": i, "authenticated": False}
        try:
            body = cobs.decode(raw)
        except cobs.DecodeError as exc:
            out.append({**row, "error": f"cobs: {exc}"})
            continue
        if len(body) < OVERHEAD:
            out.append({**row, "error": f"length: {len(body)} bytes"})
            continue
        if binascii.crc_hqx(body[:-CRC_LEN], 0xFFFF) != int.from_bytes(body[-CRC_LEN:], "big"):
            out.append({**row, "error": "crc: CRC mismatch"})
            continue
        first, sender, link, seq, counter = HEADER.unpack_from(body)
        try:
            kind = FrameKind(first & 0x0F).name
        except ValueError:
            kind = first & 0x0F
        out.append({**row, "version": first >> 4, "kind": kind, "sender": sender, "link": link,
                    "seq": seq, "counter": int.from_bytes(counter, "big"),
                    "payload_bytes": len(body) - OVERHEAD})
    return out


def authenticated(bodies: list[bytes], key: bytes) -> list[dict]:
    """Each frame checked with the key; reliable messages reassembled and decoded as packets."""
    links: dict[tuple[int, int], Link] = {}
    out: list[dict] = []
    for i, raw in enumerate(bodies):
        try:
            f = decode(raw, key)
        except FrameError as exc:
            out.append({"frame": i, "error": str(exc)})
            continue
        out.append({"frame": i, "authenticated": True, "kind": f.kind.name, "sender": f.sender,
                    "link": f.link, "seq": f.seq, "counter": f.counter, "payload_bytes": len(f.payload)})
        k = (f.sender, f.link)
        if k not in links:  # a receiver per sender, as the peer would run
            links[k] = Link((f.sender + 1) % 256, f.sender, f.link, key, MemoryCounterStore())
        links[k].receive(b"\x00" + raw + b"\x00", float(i))
        for ev in links[k].pop_events():
            if isinstance(ev, Delivered):
                try:
                    out.append({"message": ev.msg_id, "sender": ev.sender, **packet_json(pk.decode(ev.payload))})
                except FrameError as exc:
                    out.append({"message": ev.msg_id, "sender": ev.sender, "error": str(exc)})
    return out


def run(args: argparse.Namespace) -> int:
    path = Path(args.file)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise CliError(f"{path}: no such file") from None
    except OSError as exc:
        raise CliError(f"{path}: cannot read ({exc.strerror})") from None
    key = None
    if args.key:
        try:
            key = load_key(args.key)
        except KeyFileError as exc:
            raise CliError(str(exc)) from None
    bodies = Deframer(max_body=8192).feed(data + b"\x00")
    rows = headers(bodies) if key is None else authenticated(bodies, key)
    for row in rows:
        print(json.dumps(row))
    return 0
