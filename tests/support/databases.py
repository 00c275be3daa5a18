"""Databases as older releases wrote them."""
import sqlite3
from pathlib import Path

from tools.store.database import Store

# The first released schema, verbatim: what a version-1 database on disk holds.
SCHEMA_1 = """
CREATE TABLE captures (id INTEGER PRIMARY KEY, robot TEXT NOT NULL, sequence INTEGER NOT NULL,
    time REAL NOT NULL, cmd_elevation REAL, cmd_azimuth REAL, elevation REAL NOT NULL,
    azimuth REAL NOT NULL, space TEXT NOT NULL, bands TEXT NOT NULL, scene TEXT NOT NULL DEFAULT '',
    UNIQUE (robot, sequence));
CREATE TABLE models (capture INTEGER NOT NULL REFERENCES captures(id) ON DELETE CASCADE,
    label INTEGER NOT NULL, band INTEGER NOT NULL, family TEXT NOT NULL,
    gamma REAL NOT NULL, delta REAL NOT NULL, xi REAL NOT NULL, lam REAL NOT NULL,
    p0 REAL, p1 REAL, p2 REAL, p3 REAL, z REAL, count INTEGER NOT NULL, beta1 REAL, beta2 REAL,
    censored_low INTEGER NOT NULL DEFAULT 0, censored_high INTEGER NOT NULL DEFAULT 0,
    PRIMARY KEY (capture, label, band));
CREATE INDEX models_by_region ON models (label, band);
CREATE TABLE masks (id INTEGER PRIMARY KEY, robot TEXT NOT NULL DEFAULT '', key TEXT NOT NULL,
    height INTEGER NOT NULL, width INTEGER NOT NULL, encoding TEXT NOT NULL, data BLOB NOT NULL,
    UNIQUE (robot, key));
"""


def older_database(path: Path, version: int, undo: str, *capture, **stored) -> Path:
    """A database holding one capture (`Store.add_capture(*capture, **stored)`; an RGB one of robot
    "1" by default) as schema `version` left it: today's, with `undo` taking back what came since."""
    with Store.open(path) as s:
        s.add_capture(*(capture or ("1", 1, 1.0, (90.0, 0.0), (90.0, 0.0), "rgb", ("R", "G", "B"), {})), **stored)
    con = sqlite3.connect(path)
    try:
        con.executescript(f"{undo} PRAGMA user_version = {version};")
    finally:
        con.close()
    return path
