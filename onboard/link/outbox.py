"""The robot's persistent outbox: every packet is stored here before it is sent.

A row leaves the outbox only when the host acknowledged it (`ack`). SQLite in WAL mode
with synchronous=FULL makes each `put` durable before it returns, so killing the robot
at any instant loses no packet whose `put` returned and never duplicates a row. The row
id is the packet's persistent message id across restarts (AUTOINCREMENT never reuses
an id, even after the newest rows were acknowledged).

At its quota the outbox refuses new rows with `OutboxFull`; the runtime pauses
acquisition and says so. Nothing is ever dropped to make room.

A small key-value `state` table lives in the same database, so the runtime can commit
"these packets are queued" and "this pose is done" (sweep progress, the next capture
sequence) as one transaction with `commit`: a kill leaves both or neither.

A `replies` table remembers the answers to the last `REMEMBERED_REPLIES` commands, each
committed with the packet carrying it and whatever the command produced; a command id
seen again (the base retrying across a robot restart) is answered from here, not re-run.

A message the base could not use (its NACK UNUSABLE names the message) is set aside with
`set_aside`: moved, with its body when it is still queued, into the dead letters
(`onboard.link.dead_letters`), so it is never sent again and STATUS shows it.

A new outbox draws a random `incarnation`: its row ids and capture numbers start again, and
the host tells them from the old ones' by it. On a full disk the writes that free room or say
why (acknowledgement deletes, replies, STATUS: every write without a `reserve`) restart the
WAL and try once more after `on_full` (called on every write that finds the disk full: the
robot releases its disk reserve); bulk data raises `DiskFull` at once. A damaged file raises
`OutboxDamaged` (`open_outbox` moves it aside and starts a new one); any other failure to open
is `OutboxError`.
"""
from __future__ import annotations

import os
import secrets
import sqlite3
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Mapping, TypeVar

from onboard.link import dead_letters

T = TypeVar("T")

# Rough per-row cost of SQLite's record and index overhead, so many tiny rows count too.
ROW_OVERHEAD = 64
DEFAULT_QUOTA = 64 * 1024 * 1024
SCHEMA_VERSION = 4  # 2 added the state table, 3 the replies, 4 the dead letters; older files gain them on open
INCARNATION_KEY = "incarnation"  # state entry: this outbox's random id, hex
REMEMBERED_REPLIES = 256  # commands answered from memory; older ids are forgotten

_SCHEMA = (
    """CREATE TABLE IF NOT EXISTS outbox (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    kind INTEGER NOT NULL,
    created REAL NOT NULL,
    body BLOB NOT NULL
)""",
    "CREATE TABLE IF NOT EXISTS state (key TEXT PRIMARY KEY, value TEXT NOT NULL)",
    """CREATE TABLE IF NOT EXISTS replies (
    n INTEGER PRIMARY KEY AUTOINCREMENT,
    command_id INTEGER NOT NULL UNIQUE,
    msg_id INTEGER NOT NULL,
    kind INTEGER NOT NULL,
    body BLOB NOT NULL
)""",
    dead_letters.TABLE,
)


@dataclass(frozen=True)
class Reply:
    """A command's answer: its packet, and (once committed) the outbox row carrying it."""

    command_id: int
    kind: int
    body: bytes
    msg_id: int = 0


class OutboxError(RuntimeError):
    """The outbox cannot be opened or written; the message names the file and why."""


class OutboxFull(OutboxError):
    """The outbox is at its quota: acquisition must pause until the host acknowledges."""


class DiskFull(OutboxFull):
    """The disk under the outbox has no room: acquisition pauses until it has."""


class OutboxDamaged(OutboxError):
    """The outbox file is damaged (not a database, malformed, text that does not decode)."""


class Outbox:
    """A durable FIFO of packet bodies keyed by a persistent message id."""

    def __init__(self, path: str | Path, quota_bytes: int = DEFAULT_QUOTA,
                 on_full: Callable[[], object] = lambda: None) -> None:
        if not isinstance(quota_bytes, int) or isinstance(quota_bytes, bool) or quota_bytes <= 0:
            raise ValueError(f"outbox quota must be a positive number of bytes, got {quota_bytes!r}")
        self.path = Path(path)
        self.quota_bytes = quota_bytes
        self.on_full = on_full  # called when a write that frees room finds the disk full
        self._lock = threading.Lock()
        self._conn: sqlite3.Connection | None = None
        try:
            self._count, self._payload = (int(v) for v in self._open())
            damage = self._damage()
            if damage:
                raise OutboxDamaged(f"outbox {self.path}: damaged: {damage}")
            self.incarnation = self._incarnation()
        except (sqlite3.DatabaseError, OutboxError) as exc:
            if self._conn is not None:
                self._conn.close()
            if isinstance(exc, OutboxError):
                raise
            if _damaged(exc):
                raise OutboxDamaged(f"outbox {self.path}: damaged: {exc}") from exc
            raise OutboxError(f"outbox {self.path}: cannot open: {exc}") from exc

    def _open(self) -> tuple[int, int]:
        # Autocommit: each statement is its own durable transaction.
        self._conn = sqlite3.connect(str(self.path), isolation_level=None, check_same_thread=False,
                                     timeout=10.0)
        self.new = self._conn.execute("SELECT 1 FROM sqlite_master WHERE name = 'outbox'").fetchone() is None
        mode = self._conn.execute("PRAGMA journal_mode=WAL").fetchone()[0]
        if str(mode).lower() != "wal":
            raise OutboxError(f"outbox {self.path}: WAL journal not available (got {mode!r})")
        self._conn.execute("PRAGMA synchronous=FULL")
        version = self._conn.execute("PRAGMA user_version").fetchone()[0]
        if version not in (0, 1, 2, 3, SCHEMA_VERSION):
            raise OutboxDamaged(f"outbox {self.path}: schema version {version}, expected {SCHEMA_VERSION}")
        for statement in _SCHEMA:
            self._conn.execute(statement)
        self._conn.execute(f"PRAGMA user_version={SCHEMA_VERSION}")
        return self._conn.execute("SELECT COUNT(*), COALESCE(SUM(LENGTH(body)), 0) FROM outbox").fetchone()

    def _damage(self) -> str:
        """What is wrong with the file's content, "" when nothing: the structure, the type of
        every value read back, and text that does not decode (bit rot)."""
        check = str(self._conn.execute("PRAGMA quick_check").fetchone()[0])
        if check != "ok":
            return check
        for table, test in (("outbox", "typeof(kind) != 'integer' OR typeof(body) != 'blob'"),
                            ("replies", "typeof(command_id) != 'integer' OR typeof(msg_id) != 'integer'"
                                        " OR typeof(kind) != 'integer' OR typeof(body) != 'blob'"),
                            ("state", "typeof(key) != 'text' OR typeof(value) != 'text'"),
                            ("dead_letters", dead_letters.TYPES)):
            bad = self._conn.execute(f"SELECT COUNT(*) FROM {table} WHERE {test}").fetchone()[0]
            if bad:
                return f"{bad} {table} rows hold values of the wrong type"
        self._conn.execute("SELECT key, value FROM state").fetchall()  # raises on undecodable text
        return ""

    def _incarnation(self) -> str:
        """This outbox's incarnation, drawn when it is new. An outbox that handed out capture
        numbers before incarnations existed keeps "" (its numbers go on, not start again)."""
        text = self.state(INCARNATION_KEY)
        if text is None:
            numbered = self.state("next_seq") is not None or (self.path.parent / "seq").exists()
            text = "" if numbered else secrets.token_hex(8)
            self.commit(state={INCARNATION_KEY: text})
        try:
            if len(bytes.fromhex(text)) > 16:
                raise ValueError("longer than 16 bytes")
        except ValueError as exc:
            raise OutboxDamaged(f"outbox {self.path}: incarnation {text[:40]!r}: {exc}") from None
        return text

    # -- queue -------------------------------------------------------------------------

    def put(self, kind: int, body: bytes, created: float | None = None) -> int:
        """Store one packet body durably and return its message id."""
        return self.commit([(kind, body)], created=created)[0]

    def commit(
        self,
        packets: Iterable[tuple[int, bytes]] = (),
        state: Mapping[str, str] | None = None,
        created: float | None = None,
        reserve: int = 0,
        reply: Reply | None = None,
    ) -> list[int]:
        """Store packets and state entries in one durable transaction; their message ids.

        A `reply` is queued last and remembered for its command id (the oldest memory
        past `REMEMBERED_REPLIES` is forgotten in the same transaction). All or nothing:
        past the quota less `reserve` bytes (`OutboxFull`) or on a write error nothing
        is stored. Bulk data passes a reserve so replies still fit.
        """
        rows = [_checked(kind, body) for kind, body in packets]
        if reply is not None:
            if not isinstance(reply.command_id, int) or reply.command_id < 0:
                raise ValueError(f"reply command id must be a non-negative int, got {reply.command_id!r}")
            rows.append(_checked(reply.kind, reply.body))
        entries = [(str(k), str(v)) for k, v in (state or {}).items()]
        stamp = time.time() if created is None else float(created)
        size = sum(len(b) for _, b in rows)
        with self._lock:
            need = self.bytes_used + size + ROW_OVERHEAD * len(rows)
            if rows and need > self.quota_bytes - reserve:
                raise OutboxFull(
                    f"outbox full: {self.bytes_used} of {self.quota_bytes} bytes used by "
                    f"{self._count} unacknowledged packets; acquisition paused until the host acknowledges"
                )
            ids = self._write(lambda: self._insert(rows, entries, stamp, reply), essential=reserve == 0)
            self._count += len(rows)
            self._payload += size
            return ids

    def _insert(self, rows: list[tuple[int, bytes]], entries: list[tuple[str, str]], stamp: float,
                reply: Reply | None) -> list[int]:
        ids: list[int] = []
        self._conn.execute("BEGIN IMMEDIATE")
        try:
            for kind, body in rows:
                cur = self._conn.execute(
                    "INSERT INTO outbox (kind, created, body) VALUES (?, ?, ?)", (kind, stamp, body)
                )
                ids.append(int(cur.lastrowid))
            if reply is not None:
                self._remember(reply.command_id, ids[-1], *rows[-1])
            self._conn.executemany(
                "INSERT INTO state (key, value) VALUES (?, ?) "
                "ON CONFLICT(key) DO UPDATE SET value = excluded.value", entries
            )
            self._conn.execute("COMMIT")
        except BaseException:
            if self._conn.in_transaction:  # SQLite may have rolled back already (a full disk)
                self._conn.execute("ROLLBACK")
            raise
        return ids

    def _write(self, write: Callable[[], T], essential: bool) -> T:
        """`write()`; on a full disk, an essential write (one that frees room or says why)
        makes room and tries once more. DiskFull, or OutboxError for any other failure."""
        for attempt in (0, 1):
            try:
                return write()
            except sqlite3.OperationalError as exc:
                if not _full(exc, self.path.parent):
                    raise OutboxError(f"outbox {self.path}: write failed: {exc}") from exc
                if not attempt:
                    self.on_full()
                if attempt or not essential:
                    raise DiskFull(f"disk full under {self.path.parent}: {exc}") from exc
                try:  # the next writes reuse the WAL from its start instead of growing it
                    self._conn.execute("PRAGMA wal_checkpoint(RESTART)")
                except sqlite3.Error:
                    pass
        raise AssertionError("unreachable")

    def _remember(self, command_id: int, msg_id: int, kind: int, body: bytes) -> None:
        self._conn.execute(
            "INSERT OR REPLACE INTO replies (command_id, msg_id, kind, body) VALUES (?, ?, ?, ?)",
            (command_id, msg_id, kind, body),
        )
        self._conn.execute(
            "DELETE FROM replies WHERE n <= (SELECT MAX(n) FROM replies) - ?", (REMEMBERED_REPLIES,)
        )

    def remembered(self, command_id: int) -> Reply | None:
        """The committed answer to command `command_id`, or None if never seen (or forgotten)."""
        with self._lock:
            row = self._conn.execute(
                "SELECT kind, body, msg_id FROM replies WHERE command_id = ?", (command_id,)
            ).fetchone()
        return None if row is None else Reply(command_id, int(row[0]), bytes(row[1]), int(row[2]))

    def state(self, key: str) -> str | None:
        """A state entry stored by `commit`, or None when there is none."""
        with self._lock:
            row = self._conn.execute("SELECT value FROM state WHERE key = ?", (key,)).fetchone()
        return None if row is None else str(row[0])

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
        """Delete an acknowledged message; False if it was already gone (duplicate acks are
        normal). On a full disk it makes room first (DiskFull if even that fails)."""
        with self._lock:
            row = self._conn.execute(
                "SELECT LENGTH(body) FROM outbox WHERE id = ?", (msg_id,)
            ).fetchone()
            if row is None:
                return False
            # One process owns the outbox, so the row cannot vanish between the two statements.
            self._write(lambda: self._conn.execute("DELETE FROM outbox WHERE id = ?", (msg_id,)), essential=True)
            self._count -= 1
            self._payload -= int(row[0])
            return True

    def set_aside(self, msg_id: int, reason: str, refused: float | None = None) -> bool:
        """The base refused message `msg_id`: out of the queue (never offered again) into the dead
        letters (`onboard.link.dead_letters`), with its body if it is still queued; whether it was."""
        stamp = time.time() if refused is None else float(refused)
        with self._lock:
            row = self._conn.execute("SELECT kind, created, body FROM outbox WHERE id = ?", (msg_id,)).fetchone()
            known = self._conn.execute("SELECT 1 FROM dead_letters WHERE msg_id = ?", (msg_id,)).fetchone()
            if known is not None and row is None:
                return False
            self._write(lambda: self._transaction(
                lambda: dead_letters.move(self._conn, msg_id, row, stamp, str(reason), known is not None)),
                essential=True)
            if row is not None:
                self._count -= 1
                self._payload -= len(row[2])
            return row is not None

    def dead_letters(self, limit: int = dead_letters.KEPT) -> tuple[int, list[dead_letters.DeadLetter]]:
        """How many messages were ever set aside, and the newest `limit` of those kept."""
        with self._lock:
            return dead_letters.read(self._conn, limit)

    def _transaction(self, body: Callable[[], None]) -> None:
        self._conn.execute("BEGIN IMMEDIATE")
        try:
            body()
            self._conn.execute("COMMIT")
        except BaseException:
            if self._conn.in_transaction:
                self._conn.execute("ROLLBACK")
            raise

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
        return self.full_for(0)

    def full_for(self, reserve: int) -> bool:
        """True when not even a small packet would fit below the quota less `reserve`."""
        return self.bytes_used + ROW_OVERHEAD + 1 > self.quota_bytes - reserve

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


NO_ROOM = 1 << 20  # an I/O error with less free than this is the disk being full (tmpfs, ext4)


def _full(exc: sqlite3.Error, where: Path) -> bool:
    """Whether a failed write failed for lack of room. SQLite says SQLITE_FULL when a write
    returns ENOSPC, but an I/O error when growing the WAL or its index fails for the same cause."""
    name = getattr(exc, "sqlite_errorname", "") or ""
    if name == "SQLITE_FULL" or "full" in str(exc).lower():
        return True
    return name.startswith("SQLITE_IOERR") and free_bytes(where) < NO_ROOM


def free_bytes(where: Path) -> int:
    """Bytes free for an unprivileged writer under `where` (a large number when unknown)."""
    try:
        st = os.statvfs(where)
    except OSError:
        return 1 << 62
    return st.f_bavail * st.f_frsize


def _damaged(exc: sqlite3.Error) -> bool:
    """Whether SQLite's error says the file's content is bad (rather than the disk or the OS)."""
    name = getattr(exc, "sqlite_errorname", "") or ""
    return name.startswith(("SQLITE_CORRUPT", "SQLITE_NOTADB")) or "decode" in str(exc)


def open_outbox(path: str | Path, quota_bytes: int = DEFAULT_QUOTA,
                on_full: Callable[[], object] = lambda: None) -> tuple[Outbox, str]:
    """The outbox at `path`, and what was done to open it: a damaged file (and its WAL) is
    moved aside to `<name>.damaged-<UTC time>` and a new outbox, a new incarnation, starts.
    Restarting cannot mend a damaged file; moving it keeps it for inspection."""
    path = Path(path)
    try:
        return Outbox(path, quota_bytes, on_full), ""
    except OutboxDamaged as exc:
        aside = path.with_name(f"{path.name}.damaged-{time.strftime('%Y%m%dT%H%M%SZ', time.gmtime())}")
        for suffix in ("", "-wal", "-shm"):
            src = path.with_name(path.name + suffix)
            if src.exists():
                src.rename(aside.with_name(aside.name + suffix))
        box = Outbox(path, quota_bytes, on_full)
        return box, (f"{exc}; moved aside to {aside.name} (its unsent packets are not sent) and "
                     f"started a new outbox, incarnation {box.incarnation}")


def _checked(kind: int, body: bytes) -> tuple[int, bytes]:
    if not isinstance(kind, int) or isinstance(kind, bool) or not 0 <= kind < 256:
        raise ValueError(f"outbox kind must be an int in 0..255, got {kind!r}")
    if not isinstance(body, (bytes, bytearray, memoryview)):
        raise TypeError(f"outbox body must be bytes, got {type(body).__name__}")
    body = bytes(body)
    if not body:
        raise ValueError("outbox body must not be empty")
    return kind, body
