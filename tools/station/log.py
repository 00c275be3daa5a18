"""The station's log: every event as one JSON object a line in a file beside the database
(`scene.db.log`: what was stored, what was refused and why, link up and down, the failsafe,
every command and its answer), and as one short plain line on stderr, which journald stamps.

Rejected frames are counted by the link; the log turns the counts into what they most likely
mean ("tag mismatch: wrong key?"), at most once a second per reason.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import TextIO

from tools.station.events import Event, line

# What a rejected frame most likely means (radio.frame.Reason values).
LIKELY_CAUSE = {
    "tag": "tag mismatch: wrong key? (--key must hold the robot's link.key_file)",
    "crc": "CRC error: noise on the line, or another baud rate at the other end?",
    "cobs": "framing error: noise, or something else talking on the port?",
    "length": "framing error: noise, or something else talking on the port?",
    "oversize": "frame longer than the MTU: another mtu at the other end?",
    "version": "unknown frame version: the other end runs another protocol version?",
    "kind": "unknown frame kind: the other end runs another protocol version?",
    "sender": "wrong sender: our own frames echoed back, or a second base on the radio?",
    "link": "another link id: a second link on the same radio?",
    "replay": "replayed counter: a frame seen before (duplicated on the air, or replayed)",
    "stale": "counter below the replay window: a frame from long ago",
    "stale_session": "frame of an old session: sent before a restart",
    "payload": "malformed payload",
    "reassembly": "a message that could not be reassembled",
}


def likely_cause(reason: str) -> str:
    return LIKELY_CAUSE.get(reason, reason)


class StationLog:
    """Writes events (`tools.station.events`) to a JSON-lines file and stderr."""

    def __init__(self, path: Path | None, echo: TextIO | None = sys.stderr) -> None:
        self.path, self.echo = path, echo
        self._file = None if path is None else open(path, "a", encoding="utf-8", buffering=1)

    def write(self, event: Event) -> None:
        js = event.to_json()
        if self._file is not None:
            self._file.write(json.dumps(js, separators=(",", ":")) + "\n")
        if self.echo is not None:
            print(line(js), file=self.echo, flush=True)

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None
