"""`btf-host decode FILE`: a recorded byte stream of frames as JSON lines."""
from __future__ import annotations

import argparse
import binascii
import json
import sys
from pathlib import Path
from typing import Iterable, Iterator

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


READ_BYTES = 1 << 16  # the recording is read, framed and printed this much at a time


def frames_of(path: Path) -> Iterator[bytes]:
    """The frame bodies of a recording, read a block at a time: the first lines print at once,
    and memory stays flat however long the recording."""
    deframer = Deframer(max_body=8192)
    try:
        with open(path, "rb") as fh:
            while block := fh.read(READ_BYTES):
                yield from deframer.feed(block)
    except OSError as exc:
        raise CliError(f"{path}: cannot read ({exc.strerror or exc})") from None
    yield from deframer.feed(b"\x00")


def headers(bodies: Iterable[bytes]) -> Iterator[dict]:
    """Frame headers without the key: CRC checked, the tag not (marked so)."""
    for i, raw in enumerate(bodies):
        row: dict = {"frame": i, "authenticated": False}
        try:
            body = cobs.decode(raw)
        except cobs.DecodeError as exc:
            yield {**row, "error": f"cobs: {exc}"}
            continue
        if len(body) < OVERHEAD:
            yield {**row, "error": f"length: {len(body)} bytes"}
            continue
        if binascii.crc_hqx(body[:-CRC_LEN], 0xFFFF) != int.from_bytes(body[-CRC_LEN:], "big"):
            yield {**row, "error": "crc: CRC mismatch"}
            continue
        first, sender, link, seq, counter = HEADER.unpack_from(body)
        try:
            kind = FrameKind(first & 0x0F).name
        except ValueError:
            kind = first & 0x0F
        yield {**row, "version": first >> 4, "kind": kind, "sender": sender, "link": link,
               "seq": seq, "counter": int.from_bytes(counter, "big"), "payload_bytes": len(body) - OVERHEAD}


def authenticated(bodies: Iterable[bytes], key: bytes) -> Iterator[dict]:
    """Each frame checked with the key; reliable messages reassembled and decoded as packets."""
    links: dict[tuple[int, int], Link] = {}
    for i, raw in enumerate(bodies):
        try:
            f = decode(raw, key)
        except FrameError as exc:
            yield {"frame": i, "error": str(exc)}
            continue
        yield {"frame": i, "authenticated": True, "kind": f.kind.name, "sender": f.sender,
               "link": f.link, "seq": f.seq, "counter": f.counter, "payload_bytes": len(f.payload)}
        k = (f.sender, f.link)
        if k not in links:  # a receiver per sender, as the peer would run
            links[k] = Link((f.sender + 1) % 256, f.sender, f.link, key, MemoryCounterStore())
        links[k].receive(b"\x00" + raw + b"\x00", float(i))
        for ev in links[k].pop_events():
            if isinstance(ev, Delivered):
                try:
                    yield {"message": ev.msg_id, "sender": ev.sender, **packet_json(pk.decode(ev.payload))}
                except FrameError as exc:
                    yield {"message": ev.msg_id, "sender": ev.sender, "error": str(exc)}


def run(args: argparse.Namespace) -> int:
    path = Path(args.file)
    if not path.exists():
        raise CliError(f"{path}: no such file")
    if path.is_dir():
        raise CliError(f"{path}: cannot read (Is a directory)")
    key = None
    if args.key:
        try:
            key = load_key(args.key)
        except KeyFileError as exc:
            raise CliError(str(exc)) from None
    frames = passed = data = messages = 0
    for row in headers(frames_of(path)) if key is None else authenticated(frames_of(path), key):
        print(json.dumps(row))
        if "frame" in row:
            frames += 1
            passed += bool(row.get("authenticated"))
            data += row.get("kind") == "DATA"
        else:
            messages += 1
    if key is not None and frames and not passed:
        raise CliError(f"no frame of {path} authenticates with {args.key}: wrong key? Give the link's key file, "
                       "or --no-auth for the frame headers alone")
    if key is not None and data and not messages:
        print(f"btf-host: note: {data} DATA frame(s) authenticated but no message put together: the recording "
              "starts after its link came up (no SYN before them)", file=sys.stderr)
    if not frames:
        print(f"btf-host: note: {path}: no frames", file=sys.stderr)
    return 0
