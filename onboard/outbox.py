"""The robot's persistent outbox: every packet is stored here before it is sent.

A row leaves the outbox only when the host acknowledged it (`ack`). SQLite in WAL mode
with synchronous=FULL makes each `put` durable before it returns, so killing the robot
at any instant loses no packet whose `put` returned and never duplicates a row. The row
id is the packet's persistent message id across restarts (AUTOINCREMENT never reuses
an id, even after the newest rows were acknowledged).

At its quota the outbox refuses new rows with `OutboxFull`; the runtime pauses
acquisition and says so. Nothing is ever dropped to make room.
"""
from __future__ import annotations

import sqlite3
import threading
import time
from pathlib import Path

# Rough per-row cost of SQLite's record and index overhead, so many tiny rows count too.
ROW_OVERHEAD = 64
DEFAULT_QUOTA = 64 * 1024 * 1024
SCHEMA_VERSION = 1

_SCHEMA = """
CREATE TABLE IF NOT EXISTS outbox (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    kind INTEGER NOT NULL,
    created REAL NOT NULL,
    body BLOB NOT NULL
)
"""


class OutboxError(RuntimeError):
    """The outbox cannot be opened or written; the message names the file and why."""


class OutboxFull(OutboxError):
    """The outbox is at its quota: acquisition must pause until the host acknowledges."""


class Outbox:
    """A durable FIFO of packet bodies keyed by a persistent message id."""

    def __init__(self, path: str | Path, quota_bytes: int = DEFAULT_QUOTA) -> None:
        if not isinstance(quota_bytes, int) or isinstance(quota_bytes, bool) or quota_bytes <= 0:
            raise ValueError(f"outbox quota must be a positive number of bytes, got {quota_bytes!r}")
        self.path = Path(path)
        self.quota_bytes = quota_bytes
        self._lock = threading.Lock()
        try:
            # Autocommit: each statement is its own durable transaction.
            self._conn = sqlite3.connect(
                str(self.path), isolation_level=None, check_same_thread=False, timeout=10.0
            )
            mode = self._conn.execute("PRAGMA journal_mode=WAL").fetchone()[0]
            if str(mode).lower() != "wal":
                raise OutboxError(f"outbox {self.path}: WAL journal not available (got {mode!r})")
            self._conn.execute("PRAGMA synchronous=FULL")
            version = self._conn.execute("PRAGMA user_version").fetchone()[0]
            if version not in (0, SCHEMA_VERSION):
                raise OutboxError(
                    f"outbox {self.path}: schema version {version}, expected {SCHEMA_VERSION}"
                )
            self._conn.execute(_SCHEMA)
            self._conn.execute(f"PRAGMA user_version={SCHEMA_VERSION}")
            count, payload = self._conn.execute(
                "SELECT COUNT(*), COALESCE(SUM(LENGTH(body)), 0) FROM outbox"
            ).fetchone()
        except sqlite3.DatabaseError as exc:
            raise OutboxError(f"outbox {self.path}: cannot open: {exc}") from exc
        self._count = int(count)
        self._payload = int(payload)

    # -- queue -------------------------------------------------------------------------

    def put(self, kind: int, body: bytes, created: float | None = None) -> int:
        """Store one packet body durably and return its message id."""
        if not isinstance(kind, int) or isinstance(kind, bool) or not 0 <= kind < 256:
            raise ValueError(f"outbox kind must be an int in 0..255, got {kind!r}")
        if not isinstance(body, (bytes, bytearray, memoryview)):
            raise TypeError(f"outbox body must be bytes, got {type(body).__name__}")
        body = bytes(body)
        if not body:
            raise ValueError("outbox body must not be empty")
        stamp = time.time() if created is None else float(created)
        with self._lock:
            need = self.bytes_used + len(body) + ROW_OVERHEAD
            if need > self.quota_bytes:
                raise OutboxFull(
                    f"outbox full: {self.bytes_used} of {self.quota_bytes} bytes used by "
                    f"{self._count} unacknowledged packets; acquisition paused until the host acknowledges"
                )
            try:
                cur = self._conn.execute(
                    "INSERT INTO outbox (kind, created, body) VALUES (?, ?, ?)", (kind, stamp, body)
                )
            except sqlite3.OperationalError as exc:
                if "full" in str(exc).lower():
                    raise OutboxFull(f"outbox full: disk full at {self.path}: {exc}") from exc
                raise OutboxError(f"outbox {self.path}: write failed: {exc}") from exc
            self._count += 1
            self._payload += len(body)
            return int(cur.lastrowid)

    def pending(self, limit: int = 64, after: int = 0) -> list[tuple[int, bytes]]:
        """Up to `limit` unacknowledged (id, body) rows with id > `after`, oldest first."""
        if not isinstance(limit, int) or limit <= 0:
            raise ValueError(f"pending limit must be a positive int, got {limit!r}")
        with self._lock:
            rows = self._conn.execute(
                "SELECT id, body FROM outbox WHERE id > ? ORDER BY id LIMIT ?", (after, limit)
            ).fetchall()
        return [(int(i), bytes(b)) for i, b in rows]

    def kind_of(self, msg_id: int) -> int | None:
        """The kind stored with a pending message, or None once it was acknowledged."""
        with self._lock:
            row = self._conn.execute("SELECT kind FROM outbox WHERE id = ?", (msg_id,)).fetchone()
        return None if row is None else int(row[0])

    def ack(self, msg_id: int) -> bool:
        """Delete an acknowledged message; False if it was already gone (duplicate acks are normal)."""
        with self._lock:
            row = self._conn.execute(
                "SELECT LENGTH(body) FROM outbox WHERE id = ?", (msg_id,)
            ).fetchone()
            if row is None:
                return False
            # One process owns the outbox, so the row cannot vanish between the two statements.
            self._conn.execute("DELETE FROM outbox WHERE id = ?", (msg_id,))
            self._count -= 1
            self._payload -= int(row[0])
            return True

    # -- accounting --------------------------------------------------------------------

    def __len__(self) -> int:
        return self._count

    @property
    def bytes_used(self) -> int:
        """Quota bytes in use: stored bodies plus a fixed per-row overhead."""
        return self._payload + ROW_OVERHEAD * self._count

    @property
    def full(self) -> bool:
        """True when not even a small packet would fit; the runtime pauses acquisition."""
        return self.bytes_used + ROW_OVERHEAD + 1 > self.quota_bytes

    def check(self) -> str:
        """SQLite's integrity check: 'ok' for a sound database, else the first problem."""
        with self._lock:
            return str(self._conn.execute("PRAGMA integrity_check").fetchone()[0])

    def close(self) -> None:
        with self._lock:
            self._conn.close()

    def __enter__(self) -> Outbox:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
