"""The outbox's dead letters: the robot's messages the base could not use (its NACK UNUSABLE
named them). Each is moved out of the queue, with its body when the robot still held it, so it
is never offered again; the newest `KEPT` stay for a person, and a state entry counts them all.
The outbox (`onboard.link.outbox.Outbox.set_aside`) runs these inside its own transaction."""
from __future__ import annotations

import sqlite3
from dataclasses import dataclass

KEPT = 64  # dead letters kept; older ones are counted only
COUNT_KEY = "dead_letters"  # state entry: how many were ever set aside
TABLE = """CREATE TABLE IF NOT EXISTS dead_letters (
    msg_id INTEGER PRIMARY KEY,
    kind INTEGER,
    created REAL,
    refused REAL NOT NULL,
    reason TEXT NOT NULL,
    body BLOB
)"""
# The type of every value read back (the outbox's damage check).
TYPES = "typeof(msg_id) != 'integer' OR typeof(reason) != 'text' OR typeof(refused) NOT IN ('real', 'integer')"


@dataclass(frozen=True)
class DeadLetter:
    """A message the base refused: its kind and body when the robot still held it."""

    msg_id: int
    kind: int | None
    refused: float
    reason: str
    body: bytes | None


def move(conn: sqlite3.Connection, msg_id: int, queued: tuple | None, refused: float, reason: str,
         counted: bool) -> None:
    """Inside a transaction: message `msg_id` (its queued (kind, created, body), or None) out of
    the outbox into the dead letters; counted unless it was set aside before."""
    kind, created, body = queued or (None, None, None)
    conn.execute("INSERT OR REPLACE INTO dead_letters (msg_id, kind, created, refused, reason, body)"
                 " VALUES (?, ?, ?, ?, ?, ?)", (msg_id, kind, created, refused, reason, body))
    conn.execute("DELETE FROM outbox WHERE id = ?", (msg_id,))
    conn.execute("DELETE FROM dead_letters WHERE msg_id NOT IN (SELECT msg_id FROM dead_letters"
                 " ORDER BY refused DESC, msg_id DESC LIMIT ?)", (KEPT,))
    if not counted:
        conn.execute("INSERT INTO state (key, value) VALUES (?, '1') ON CONFLICT(key) DO UPDATE"
                     " SET value = CAST(CAST(value AS INTEGER) + 1 AS TEXT)", (COUNT_KEY,))


def read(conn: sqlite3.Connection, limit: int) -> tuple[int, list[DeadLetter]]:
    """How many were ever set aside, and the newest `limit` kept."""
    rows = conn.execute("SELECT msg_id, kind, refused, reason, body FROM dead_letters"
                        " ORDER BY refused DESC, msg_id DESC LIMIT ?", (limit,)).fetchall()
    total = conn.execute("SELECT value FROM state WHERE key = ?", (COUNT_KEY,)).fetchone()
    count = int(total[0]) if total is not None and str(total[0]).isdigit() else len(rows)
    return count, [DeadLetter(int(m), None if k is None else int(k), float(t), str(r), None if b is None else bytes(b))
                   for m, k, t, r, b in rows]
