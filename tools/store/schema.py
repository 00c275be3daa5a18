"""The base station's database file: its schema and version, the upgrades from each older
version, and opening a file only once it is known to be ours (`connect`).

A file that is not a btfscout database, or is damaged, raises `CorruptDatabase` and is never
written to.
"""
from __future__ import annotations

import sqlite3
from pathlib import Path

SCHEMA_VERSION = 12
# PRAGMA application_id: marks the file as ours ("BTFS").
APPLICATION_ID = 0x42544653
_SQLITE_MAGIC = b"SQLite format 3\x00"

# Per region (btf.dependence, JSON lists): the observed levels per band (lo, hi), and when
# measured the band correlations (corr) and the autocorrelation on the window of `radius` (acf,
# rows); rows of the older layout have corr with dx and dy (autocorrelation at LAGS) instead.
_DEPENDENCE_COLUMNS = """
    capture INTEGER NOT NULL REFERENCES captures(id) ON DELETE CASCADE,
    label INTEGER NOT NULL,
    corr TEXT, dx TEXT, dy TEXT, acf TEXT, radius INTEGER, lo TEXT, hi TEXT,
    PRIMARY KEY (capture, label)
"""
_DEPENDENCE = f"CREATE TABLE dependence ({_DEPENDENCE_COLUMNS});"
_DEPENDENCE_V2 = """
CREATE TABLE dependence (
    capture INTEGER NOT NULL REFERENCES captures(id) ON DELETE CASCADE,
    label INTEGER NOT NULL,
    corr TEXT NOT NULL, dx TEXT NOT NULL, dy TEXT NOT NULL,
    PRIMARY KEY (capture, label)
);
"""
# The PCA basis a robot sent with a capture (PcaBasis.to_record as JSON); later captures of
# the same robot use it until a newer one arrives.
_PCA = """
CREATE TABLE pca_bases (
    capture INTEGER PRIMARY KEY REFERENCES captures(id) ON DELETE CASCADE,
    record TEXT NOT NULL
);
"""
# What a capture was taken with (btf.capture_settings): the camera's reported settings, whether
# it held its lock, the reference's level per band (JSON list) and the brackets (JSON).
_CAMERA = """
CREATE TABLE IF NOT EXISTS capture_camera (
    capture INTEGER PRIMARY KEY REFERENCES captures(id) ON DELETE CASCADE,
    exposure_us REAL, gain REAL, wb_kelvin REAL, wb_red REAL, wb_blue REAL, sensor_c REAL,
    unlocked INTEGER NOT NULL DEFAULT 0,
    reference TEXT, reference_clipped REAL NOT NULL DEFAULT 0,
    brackets TEXT NOT NULL DEFAULT '[]', bracketed TEXT NOT NULL DEFAULT '{}'
);
"""
# The file a replaying camera read the frame from (btf.capture_settings.CaptureSettings.source).
_CAMERA_SOURCE = "ALTER TABLE capture_camera ADD COLUMN source TEXT;"
# A capture is one robot state's (incarnation's) numbered view: a robot whose state was wiped
# numbers its captures from 1 again under a new incarnation ('' for robots older than them).
_CAPTURES = """
CREATE TABLE {name} (
    id INTEGER PRIMARY KEY,
    robot TEXT NOT NULL,
    sequence INTEGER NOT NULL,
    time REAL NOT NULL,
    cmd_elevation REAL, cmd_azimuth REAL,
    elevation REAL NOT NULL, azimuth REAL NOT NULL,
    space TEXT NOT NULL,
    bands TEXT NOT NULL,
    scene TEXT NOT NULL DEFAULT '',
    light_elevation REAL, light_azimuth REAL,
    source TEXT,
    levels INTEGER NOT NULL DEFAULT 256,
    incarnation TEXT NOT NULL DEFAULT '',
    UNIQUE (robot, incarnation, sequence)
);
"""
# Packets the station could not use (undecodable, or refused by the store), raw, for a person
# to look at: the robot was told (a NACK UNUSABLE) and set them aside.
_REJECTED = """
CREATE TABLE IF NOT EXISTS rejected_packets (
    id INTEGER PRIMARY KEY,
    received REAL NOT NULL,
    sender INTEGER,
    incarnation TEXT NOT NULL DEFAULT '',
    msg_id INTEGER,
    reason TEXT NOT NULL,
    body BLOB NOT NULL
);
"""
_BEFORE_INCARNATIONS = ("id, robot, sequence, time, cmd_elevation, cmd_azimuth, elevation, azimuth, space, bands,"
                        " scene, light_elevation, light_azimuth, source, levels")
# A feature space chosen automatically (btf.fit.space_choice): the capture it was resolved at,
# and the criterion's reason; the robot's later captures of the scene keep it.
_SPACE_CHOICES = """
CREATE TABLE IF NOT EXISTS space_choices (
    capture INTEGER PRIMARY KEY REFERENCES captures(id) ON DELETE CASCADE,
    reason TEXT NOT NULL
);
"""
_SCHEMA = _CAPTURES.format(name="captures") + """
CREATE INDEX captures_by_source ON captures (robot, source);
CREATE TABLE models (
    capture INTEGER NOT NULL REFERENCES captures(id) ON DELETE CASCADE,
    label INTEGER NOT NULL, band INTEGER NOT NULL,
    family TEXT NOT NULL,
    gamma REAL NOT NULL, delta REAL NOT NULL, xi REAL NOT NULL, lam REAL NOT NULL,
    p0 REAL, p1 REAL, p2 REAL, p3 REAL,
    z REAL, count INTEGER NOT NULL,
    beta1 REAL, beta2 REAL,
    censored_low REAL NOT NULL DEFAULT 0, censored_high REAL NOT NULL DEFAULT 0,
    shift REAL NOT NULL DEFAULT 0, fallback INTEGER NOT NULL DEFAULT 0,
    exact_family INTEGER NOT NULL DEFAULT 0,
    PRIMARY KEY (capture, label, band)
);
CREATE INDEX models_by_region ON models (label, band);
CREATE TABLE masks (
    id INTEGER PRIMARY KEY,
    robot TEXT NOT NULL DEFAULT '',
    key TEXT NOT NULL,
    height INTEGER NOT NULL, width INTEGER NOT NULL,
    encoding TEXT NOT NULL,
    data BLOB NOT NULL,
    UNIQUE (robot, key)
);
""" + _DEPENDENCE + _PCA + _CAMERA + _CAMERA_SOURCE + _REJECTED + _SPACE_CHOICES
_TABLES = {"captures", "models", "masks"}
# Upgrades from the keyed version to the next; each keeps every existing row.
_MIGRATIONS: dict[int, str] = {
    # illumination angles and the source file of a capture (dataset ingest)
    1: "ALTER TABLE captures ADD COLUMN light_elevation REAL;"
       "ALTER TABLE captures ADD COLUMN light_azimuth REAL;"
       "ALTER TABLE captures ADD COLUMN source TEXT;"
       "CREATE INDEX captures_by_source ON captures (robot, source);",
    # grain and band correlation per region (btf.fit.dependence)
    2: _DEPENDENCE_V2,
    # the PCA basis of a scene, to turn pca captures back into RGB
    3: _PCA,
    # the rest of a model's read (btf.record), so a stored record rebuilds its model
    4: "ALTER TABLE models ADD COLUMN shift REAL NOT NULL DEFAULT 0;"
       "ALTER TABLE models ADD COLUMN fallback INTEGER NOT NULL DEFAULT 0;"
       "ALTER TABLE models ADD COLUMN exact_family INTEGER NOT NULL DEFAULT 0;",
    # the sensor's levels (256 for 8-bit, 65536 for 16-bit images), so synthesis keeps the depth
    5: "ALTER TABLE captures ADD COLUMN levels INTEGER NOT NULL DEFAULT 256;",
    # the camera settings, reference level and brackets of a capture
    6: _CAMERA,
    # the robot's incarnation: unique by (robot, incarnation, sequence). A table constraint
    # changes only by a new table; foreign keys are off meanwhile (`connect`), so the
    # models, masks, dependence and camera rows keep pointing at the same ids.
    7: _CAPTURES.format(name="captures_new")
       + f"INSERT INTO captures_new ({_BEFORE_INCARNATIONS}) SELECT {_BEFORE_INCARNATIONS} FROM captures;"
       "DROP TABLE captures; ALTER TABLE captures_new RENAME TO captures;"
       "CREATE INDEX captures_by_source ON captures (robot, source);",
    # the packets the station could not use, kept raw
    8: _REJECTED,
    # the file a replayed frame came from
    9: _CAMERA_SOURCE,
    # a region's observed levels and its grain on the 2-D window; the older rows kept as they are
    10: f"CREATE TABLE dependence_new ({_DEPENDENCE_COLUMNS});"
       "INSERT INTO dependence_new (capture, label, corr, dx, dy) SELECT capture, label, corr, dx, dy FROM dependence;"
       "DROP TABLE dependence; ALTER TABLE dependence_new RENAME TO dependence;",
    # the feature spaces chosen automatically
    11: _SPACE_CHOICES,
}


class CorruptDatabase(Exception):
    """The file is damaged or is not a btfscout database; it has not been touched."""


class StoreUnavailable(CorruptDatabase):
    """The file could not be opened for a reason outside it (a full disk, an I/O error)."""


def _failure(p: Path, exc: sqlite3.DatabaseError, doing: str) -> CorruptDatabase:
    name = getattr(exc, "sqlite_errorname", "") or ""
    if isinstance(exc, sqlite3.OperationalError) and not name.startswith(("SQLITE_CORRUPT", "SQLITE_NOTADB")):
        return StoreUnavailable(f"database {p}: cannot {doing} ({exc})")
    return CorruptDatabase(f"database {p}: damaged ({exc}); left untouched")


def connect(p: Path, create: bool = True) -> sqlite3.Connection:
    """A connection to the database at `p`: created when absent (and `create`), upgraded in
    place when older; CorruptDatabase, the file untouched, when it is not ours or is damaged."""
    if p.exists() and not p.is_file():
        raise CorruptDatabase(f"database {p}: not a regular file")
    fresh = not p.exists() or p.stat().st_size == 0
    if not fresh:
        try:
            with open(p, "rb") as fh:
                magic = fh.read(16)
        except OSError as exc:
            raise CorruptDatabase(f"database {p}: cannot read ({exc.strerror})") from None
        if magic != _SQLITE_MAGIC:
            raise CorruptDatabase(f"database {p}: not an SQLite file; left untouched")
    elif not create:
        if p.exists():  # a 0-byte file: what a failed copy, or a typo in a redirection, leaves
            raise CorruptDatabase(f"database {p}: an empty file, not a btfscout database; give the one station, "
                                  "listen, fit, ingest or demo wrote")
        raise CorruptDatabase(f"database {p}: no such database; give the one station, listen, fit, ingest or "
                              "demo wrote")
    if not p.parent.exists():
        raise CorruptDatabase(f"database {p}: directory {p.parent} does not exist")
    try:
        conn = sqlite3.connect(str(p), isolation_level=None)
    except sqlite3.Error as exc:
        raise CorruptDatabase(f"database {p}: cannot open ({exc})") from None
    try:
        conn.execute("PRAGMA foreign_keys = ON")
        app_id = conn.execute("PRAGMA application_id").fetchone()[0]
        version = conn.execute("PRAGMA user_version").fetchone()[0]
        tables = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        if app_id == 0 and version == 0 and not tables:
            conn.executescript("BEGIN;" + _SCHEMA + f"PRAGMA user_version = {SCHEMA_VERSION};"
                               f"PRAGMA application_id = {APPLICATION_ID}; COMMIT;")
        elif app_id != APPLICATION_ID or not _TABLES <= tables:
            raise CorruptDatabase(f"database {p}: not a btfscout database; left untouched")
        elif version < SCHEMA_VERSION and all(v in _MIGRATIONS for v in range(version, SCHEMA_VERSION)):
            script = "".join(_MIGRATIONS[v] for v in range(version, SCHEMA_VERSION))
            conn.execute("PRAGMA foreign_keys = OFF")  # a rebuilt table must not cascade its deletes
            conn.executescript(f"BEGIN;{script}PRAGMA user_version = {SCHEMA_VERSION}; COMMIT;")
            conn.execute("PRAGMA foreign_keys = ON")
        elif version != SCHEMA_VERSION:
            raise CorruptDatabase(
                f"database {p}: schema version {version}, this tool reads {SCHEMA_VERSION}; left untouched"
            )
        else:
            check = conn.execute("PRAGMA quick_check").fetchone()[0]
            if check != "ok":
                raise CorruptDatabase(f"database {p}: damaged ({check}); left untouched")
    except sqlite3.DatabaseError as exc:
        conn.close()
        raise _failure(p, exc, "open") from None
    except CorruptDatabase:
        conn.close()
        raise
    # Only once the file is known to be ours. A capture is acknowledged once its commit
    # returns and the robot then deletes its copy, so a commit must be on stable storage:
    # FULL fsyncs the WAL at every commit (NORMAL only at checkpoints, and a power cut
    # would lose what was acknowledged). The station groups a turn's packets in one commit.
    try:
        conn.execute("PRAGMA journal_mode = WAL")
        conn.execute("PRAGMA synchronous = FULL")
    except sqlite3.DatabaseError as exc:
        conn.close()
        raise _failure(p, exc, "open for writing") from None
    return conn
