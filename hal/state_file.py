"""Small versioned JSON files in the robot's state dir (calibrations, the palette): written
whole or not at all, and read back with one error naming what is wrong."""
from __future__ import annotations

import json
import os
from pathlib import Path


def write_state(path: Path, record: dict) -> Path:
    """Write `record` to `path` through a synced temporary file and a rename."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    with open(tmp, "w", encoding="utf-8") as f:
        f.write(json.dumps(record, indent=2) + "\n")
        f.flush()
        os.fsync(f.fileno())  # a power cut must not leave a torn file behind the rename
    os.replace(tmp, path)
    return path


def read_state(path: Path, version: int = 1) -> dict | None:
    """The record at `path`, None when there is none; ValueError saying what is wrong with it."""
    if not path.is_file():
        return None
    try:
        raw = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"unreadable ({exc})") from None
    if not isinstance(raw, dict) or raw.get("version") != version:
        got = raw.get("version") if isinstance(raw, dict) else type(raw).__name__
        raise ValueError(f"unknown version {got!r}")
    return raw
