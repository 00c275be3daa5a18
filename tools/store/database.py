"""The base station's SQLite database of captures, fitted models and masks.

One capture is one view of one robot: (robot, incarnation, sequence) is unique, so a packet
received twice is stored once, and a robot whose state was wiped (a new incarnation, numbering
from 1 again) has its new captures kept. Every write runs in a transaction; `with store.batch():`
groups many writes in one. A file that is not a btfscout database (or is damaged)
raises `CorruptDatabase` and is never rewritten (`tools.store.schema` opens and upgrades
the file; `tools.store.rows` checks every row read back).
"""
from __future__ import annotations

import json
import os
import sqlite3
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterable, Iterator, Mapping

import numpy as np

from btf.capture_settings import CaptureSettings
from btf.dependence import Dependence
from btf.fit.features import PcaBasis
from btf.fit.png import decode_png, encode_png
from btf.johnson import Johnson
from btf.record import FittedModel
from tools.analysis.radiometry import sweep_models
from tools.store.rows import (
    CAMERA_COLUMNS,
    RejectedPacket,
    StoredCapture,
    capture_from_row,
    mask_png,
    model_from_row,
    rejected_from_row,
)
from tools.store.schema import SCHEMA_VERSION, CorruptDatabase, StoreUnavailable, connect

__all__ = ["Store", "CorruptDatabase", "StoreUnavailable", "StoredCapture", "RejectedPacket", "SCHEMA_VERSION",
           "disk_free"]

REJECTED_KEPT = 1000  # rejected packets kept for a person; older ones are deleted


def disk_free(path: str | Path) -> str:
    """The room left on the disk holding `path`, for a line saying why a write failed."""
    try:
        st = os.statvfs(os.path.dirname(os.path.abspath(path)))
    except OSError:
        return "unknown bytes"
    return f"{st.f_bavail * st.f_frsize} bytes"


class _Undo(Exception):
    """Drops the current write (e.g. a capture that was already stored)."""


def _angles(value: Any) -> tuple[float | None, float | None]:
    """(elevation, azimuth) from a ViewAngles-like object, a pair, a number or None."""
    if value is None:
        return (None, None)
    if hasattr(value, "elevation"):
        return (float(value.elevation), float(getattr(value, "azimuth", 0.0)))
    if isinstance(value, (int, float)):
        return (float(value), 0.0)
    elev, az = value
    return (float(elev), float(az))


def _opt(value: float | None) -> float | None:
    return None if value is None else float(value)


def _family_name(family: Any) -> str:
    return family.name if hasattr(family, "name") else str(family)


class Store:
    """Open with `Store.open(path)`; use as a context manager to close it."""

    def __init__(self, conn: sqlite3.Connection, path: Path) -> None:
        self._conn = conn
        self.path = path

    # -- opening ---------------------------------------------------------
    @classmethod
    def open(cls, path: str | Path, create: bool = True) -> "Store":
        """The database at `path`, created when absent (and `create`), upgraded when older;
        CorruptDatabase, with the file untouched, when it is not ours or is damaged."""
        p = Path(path)
        return cls(connect(p, create), p)

    def close(self) -> None:
        self._conn.close()

    def __enter__(self) -> "Store":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- writing ---------------------------------------------------------
    @contextmanager
    def batch(self) -> Iterator["Store"]:
        """One transaction around many writes: committed together at the end, all rolled
        back if the block raises. Writes inside keep their own all-or-nothing meaning."""
        if self._conn.in_transaction:  # nested: the outer batch commits
            yield self
            return
        self._conn.execute("BEGIN IMMEDIATE")
        try:
            yield self
        except BaseException:
            self._conn.execute("ROLLBACK")
            raise
        self._conn.execute("COMMIT")

    @contextmanager
    def _write(self) -> Iterator[None]:
        """One write's transaction, or a savepoint inside a batch; raise _Undo to drop it."""
        outer = self._conn.in_transaction
        self._conn.execute("SAVEPOINT write" if outer else "BEGIN IMMEDIATE")
        try:
            yield
        except BaseException as exc:
            if outer:
                self._conn.execute("ROLLBACK TO write")
                self._conn.execute("RELEASE write")
            elif self._conn.in_transaction:
                self._conn.execute("ROLLBACK")
            if not isinstance(exc, _Undo):
                raise
            return
        self._conn.execute("RELEASE write" if outer else "COMMIT")

    def add_capture(
        self,
        robot_id: str,
        sequence: int,
        time: float,
        commanded: Any,
        measured: Any,
        space: str,
        band_names: Iterable[str],
        results: Mapping[tuple[int, int], FittedModel],
        scene: str = "",
        illumination: Any = None,
        source: str | None = None,
        dependence: Mapping[int, Dependence] | None = None,
        pca: PcaBasis | None = None,
        levels: int = 256,
        camera: CaptureSettings | None = None,
        incarnation: str = "",
    ) -> bool:
        """Stores one capture with its models; False if (robot, incarnation, sequence) was already
        there (`incarnation`: the robot state's id its link session named, "" for none).
        `illumination` is the light's (elevation, azimuth) when known; `source` the image file;
        `pca` the basis the capture arrived with (later captures of the robot inherit it);
        `levels` the sensor's levels (256 for 8-bit pixels, 65536 for 16-bit); `camera` what it
        was taken with."""
        if type(levels) is not int or not 2 <= levels <= 65536:
            raise ValueError(f"levels {levels!r}: expected an integer in 2..65536")
        cmd = _angles(commanded)
        meas = _angles(measured)
        light = _angles(illumination)
        if meas[0] is None:
            raise ValueError("a capture needs its measured angle")
        rows = []
        for (label, band), r in sorted(results.items()):
            m = r.model
            pct = [float(v) for v in r.percentiles]
            rows.append((
                int(label), int(band), _family_name(m.family),
                float(m.gamma), float(m.delta), float(m.xi), float(m.lam),
                *pct, float(r.z), int(r.count), _opt(r.beta1), _opt(r.beta2),
                float(r.censored_low), float(r.censored_high), float(r.shift), int(r.fallback),
                int(r.exact_family),
            ))
        stored = False
        with self._write():
            cur = self._conn.execute(
                "INSERT OR IGNORE INTO captures (robot, sequence, time, cmd_elevation, cmd_azimuth,"
                " elevation, azimuth, space, bands, scene, light_elevation, light_azimuth, source, levels,"
                " incarnation) VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)",
                (str(robot_id), int(sequence), float(time), cmd[0], cmd[1], meas[0], meas[1],
                 str(space), json.dumps(list(band_names)), str(scene), light[0], light[1],
                 None if source is None else str(source), levels, str(incarnation)),
            )
            if cur.rowcount == 0:
                raise _Undo
            cid = cur.lastrowid
            self._conn.executemany(
                "INSERT INTO models (capture, label, band, family, gamma, delta, xi, lam,"
                " p0, p1, p2, p3, z, count, beta1, beta2, censored_low, censored_high, shift, fallback,"
                " exact_family) VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?,?)",
                [(cid, *row) for row in rows],
            )
            self._conn.executemany(
                "INSERT INTO dependence (capture, label, corr, acf, radius, lo, hi) VALUES (?,?,?,?,?,?,?)",
                [(cid, int(lab), *_dependence_row(d)) for lab, d in sorted((dependence or {}).items())],
            )
            if pca is not None:
                self._conn.execute("INSERT INTO pca_bases (capture, record) VALUES (?, ?)",
                                   (cid, json.dumps(pca.to_record())))
            if camera is not None:
                self._add_camera(cid, camera)
            stored = True
        return stored

    def _add_camera(self, cid: int, s: CaptureSettings) -> None:
        red, blue = s.white_balance_gains or (None, None)
        self._conn.execute(
            f"INSERT INTO capture_camera (capture, {', '.join(CAMERA_COLUMNS)}) VALUES (?,?,?,?,?,?,?,?,?,?,?,?,?)",
            (cid, s.exposure_us, s.gain, s.white_balance_kelvin, red, blue, s.sensor_temperature_c, int(s.unlocked),
             None if s.reference is None else json.dumps(list(s.reference)), float(s.reference_clipped),
             json.dumps(list(s.brackets)), json.dumps({str(k): v for k, v in sorted(s.bracketed.items())}), s.source))

    def next_sequence(self, robot_id: str) -> int:
        row = self._conn.execute("SELECT MAX(sequence) FROM captures WHERE robot = ?", (robot_id,)).fetchone()
        return 0 if row[0] is None else int(row[0]) + 1

    def add_mask(self, key: str, labels: np.ndarray, robot_id: str = "") -> bool:
        """Stores a mask under (robot, key) as PNG bytes; False if one was already there."""
        lab = np.asarray(labels)
        # A single statement: its own transaction, or part of the caller's batch.
        cur = self._conn.execute(
            "INSERT OR IGNORE INTO masks (robot, key, height, width, encoding, data)"
            " VALUES (?,?,?,?,?,?)",
            (robot_id, key, int(lab.shape[0]), int(lab.shape[1]), "png", encode_png(lab.astype(np.uint8, copy=False))),
        )
        return cur.rowcount == 1

    def add_rejected(self, received: float, sender: int | None, incarnation: str, msg_id: int | None,
                     reason: str, body: bytes) -> int:
        """Keep a packet the station could not use, raw, for a person (the newest REJECTED_KEPT);
        its row id."""
        with self._write():
            cur = self._conn.execute(
                "INSERT INTO rejected_packets (received, sender, incarnation, msg_id, reason, body)"
                " VALUES (?,?,?,?,?,?)", (float(received), sender, str(incarnation),
                                           msg_id if msg_id is None or msg_id <= 2**63 - 1 else None,
                                           str(reason), bytes(body)))
            rid = int(cur.lastrowid)
            self._conn.execute("DELETE FROM rejected_packets WHERE id <= ?", (rid - REJECTED_KEPT,))
        return rid

    def rejected(self, limit: int = 100) -> list[RejectedPacket]:
        """The newest rejected packets, newest first."""
        rows = self._conn.execute("SELECT id, received, sender, incarnation, msg_id, reason, body"
                                  " FROM rejected_packets ORDER BY id DESC LIMIT ?", (int(limit),)).fetchall()
        return [self._checked(rejected_from_row, r, f"rejected packet {r[0]!r}") for r in rows]

    def mask(self, key: str, robot_id: str = "") -> np.ndarray | None:
        row = self._conn.execute(
            "SELECT height, width, data FROM masks WHERE robot = ? AND key = ?", (robot_id, key)
        ).fetchone()
        if row is None:
            return None
        shape, png = self._checked(lambda r: mask_png(*r), row, f"mask {key!r}")
        arr = self._checked(lambda b: decode_png(b).pixels, png, f"mask {key!r}")
        if arr.shape != shape:
            raise CorruptDatabase(f"database {self.path}: mask {key!r} does not match its stored size")
        return arr

    # -- reading ---------------------------------------------------------
    def _capture_filter(self, robot: str | None, space: str | None, scene: str | None) -> tuple[str, list]:
        where, args = [], []
        for col, val in (("robot", robot), ("space", space), ("scene", scene)):
            if val is not None:
                where.append(f"{col} = ?")
                args.append(val)
        return (" WHERE " + " AND ".join(where)) if where else "", args

    def captures(self, robot: str | None = None, space: str | None = None,
                 scene: str | None = None) -> list[StoredCapture]:
        sql, args = self._capture_filter(robot, space, scene)
        return self._select_captures(sql, args)

    def capture_by_id(self, capture_id: int) -> StoredCapture | None:
        found = self._select_captures(" WHERE captures.id = ?", [int(capture_id)])
        return found[0] if found else None

    def captures_after(self, capture_id: int) -> list[StoredCapture]:
        """The captures stored after the one with id `capture_id` (0: all), by elevation."""
        return self._select_captures(" WHERE captures.id > ?", [int(capture_id)])

    def _select_captures(self, where: str, args: list) -> list[StoredCapture]:
        camera = ", ".join(f"k.{c}" for c in CAMERA_COLUMNS)
        rows = self._conn.execute(
            "SELECT id, robot, sequence, time, cmd_elevation, cmd_azimuth, elevation, azimuth,"
            " space, bands, scene, light_elevation, light_azimuth, captures.source, levels, incarnation, " + camera
            + " FROM captures LEFT JOIN capture_camera k ON k.capture = captures.id"
            + where + " ORDER BY elevation, id", args
        ).fetchall()
        return [self._checked(capture_from_row, r, f"capture row {r[0]!r}") for r in rows]

    def _checked(self, build: Any, row: tuple, what: str) -> Any:
        """build(row), or CorruptDatabase naming the row when a value in it is not one we write."""
        try:
            return build(row)
        except ValueError as exc:  # ImageError too
            raise CorruptDatabase(f"database {self.path}: {what}: {exc}; left untouched") from None

    def add_space_choice(self, robot: str, sequence: int, reason: str, incarnation: str = "") -> None:
        """Records that capture (robot, incarnation, sequence) resolved its feature space
        automatically, and why."""
        self._conn.execute("INSERT OR REPLACE INTO space_choices (capture, reason) SELECT id, ? FROM captures"
                           " WHERE robot = ? AND incarnation = ? AND sequence = ?",
                           (reason, robot, incarnation, int(sequence)))

    def space_choice(self, capture: int) -> str | None:
        """Why a capture's feature space was chosen automatically: the choice it recorded, or for
        a robot's capture (one with a commanded pose) the one an earlier capture of its scene
        recorded (same incarnation and space); None when the space was configured."""
        row = self._conn.execute(
            "SELECT s.reason FROM space_choices s JOIN captures c ON c.id = s.capture"
            " JOIN captures me ON me.id = ? WHERE c.id = me.id OR (me.cmd_elevation IS NOT NULL"
            " AND c.robot = me.robot AND c.incarnation = me.incarnation AND c.scene = me.scene"
            " AND c.space = me.space AND c.sequence <= me.sequence) ORDER BY c.sequence DESC LIMIT 1",
            (capture,)).fetchone()
        return None if row is None else str(row[0])

    def capture_by_seq(self, robot: str, sequence: int, incarnation: str = "") -> StoredCapture | None:
        """The capture (robot, incarnation, sequence), or None when it is not stored."""
        sql, args = self._capture_filter(robot, None, None)
        found = self._select_captures(sql + " AND incarnation = ? AND sequence = ?",
                                      [*args, str(incarnation), int(sequence)])
        return found[0] if found else None

    def pca_basis(self, capture: int) -> PcaBasis | None:
        """The PCA basis in effect for a capture: the one it arrived with, else the newest one
        its robot (in the same incarnation) sent with an earlier sequence; None when there is none."""
        row = self._conn.execute(
            "SELECT b.record FROM pca_bases b JOIN captures c ON c.id = b.capture"
            " JOIN captures me ON me.id = ? WHERE c.robot = me.robot AND c.incarnation = me.incarnation"
            " AND c.sequence <= me.sequence ORDER BY c.sequence DESC LIMIT 1", (capture,)).fetchone()
        if row is None:
            return None
        try:
            return PcaBasis.from_record(json.loads(row[0]))
        except ValueError as exc:
            raise CorruptDatabase(f"database {self.path}: bad PCA basis for capture {capture}: {exc}") from None

    def pca_by_angle(self, robot: str | None = None, space: str | None = None,
                     scene: str | None = None) -> dict[float, PcaBasis | None]:
        """For every measured elevation, the PCA basis of the capture models_by_angle uses."""
        return {a: self.pca_basis(c.id) for a, c in self._latest(robot, space, scene).items()}

    def sources(self, robot: str) -> set[str]:
        """Source file names already stored for `robot` (what a resumed ingest skips)."""
        rows = self._conn.execute(
            "SELECT source FROM captures WHERE robot = ? AND source IS NOT NULL", (robot,))
        return {r[0] for r in rows}

    def angles(self, robot: str | None = None, space: str | None = None,
               scene: str | None = None) -> list[float]:
        """Distinct measured elevations, ascending."""
        return sorted({c.elevation for c in self.captures(robot, space, scene)})

    def models(self, capture: int, label: int | None = None,
               band: int | None = None) -> dict[tuple[int, int], FittedModel]:
        """A capture's records by (label, band), as add_capture took them."""
        sql = ("SELECT capture, label, band, family, gamma, delta, xi, lam, p0, p1, p2, p3, z, count,"
               " beta1, beta2, censored_low, censored_high, shift, fallback, exact_family"
               " FROM models WHERE capture = ?")
        args: list = [capture]
        if label is not None:
            sql += " AND label = ?"
            args.append(label)
        if band is not None:
            sql += " AND band = ?"
            args.append(band)
        return dict(self._checked(model_from_row, r, f"capture {r[0]!r}")
                    for r in self._conn.execute(sql + " ORDER BY label, band", args))

    def _latest(self, robot: str | None, space: str | None, scene: str | None) -> dict[float, StoredCapture]:
        latest: dict[float, StoredCapture] = {}
        for c in self.captures(robot, space, scene):
            if c.elevation not in latest or c.id > latest[c.elevation].id:
                latest[c.elevation] = c
        return dict(sorted(latest.items()))

    def latest_by_angle(self, robot: str | None = None, space: str | None = None,
                        scene: str | None = None) -> dict[float, StoredCapture]:
        """For every measured elevation, its latest capture."""
        return self._latest(robot, space, scene)

    def models_by_angle(self, robot: str | None = None, space: str | None = None,
                        scene: str | None = None) -> dict[float, dict[tuple[int, int], Johnson]]:
        """For every measured elevation, the models of its latest capture, each region at the
        capture's exposure (a bracketed region's models scaled back, `tools.analysis.radiometry`)."""
        return sweep_models(self, self._latest(robot, space, scene))

    def levels(self, robot: str | None = None, space: str | None = None, scene: str | None = None) -> int:
        """The sensor levels of the captures models_by_angle uses (the deepest, when they differ;
        256 when there are none)."""
        return max((c.levels for c in self._latest(robot, space, scene).values()), default=256)

    def dependence(self, capture: int) -> dict[int, Dependence]:
        """The per-region records stored with a capture: observed levels and, when measured,
        grain and band correlation ({} when it carried none)."""
        out = {}
        for label, *row in self._conn.execute(
                "SELECT label, corr, dx, dy, acf, radius, lo, hi FROM dependence WHERE capture = ? ORDER BY label",
                (capture,)):
            try:
                out[int(label)] = _dependence_of(*row)
            except (ValueError, TypeError) as exc:
                raise CorruptDatabase(f"database {self.path}: bad dependence for capture {capture}: {exc}") from None
        return out

    def dependence_by_angle(self, robot: str | None = None, space: str | None = None,
                            scene: str | None = None) -> dict[float, dict[int, Dependence]]:
        """For every measured elevation, the dependence of the capture models_by_angle uses."""
        return {a: self.dependence(c.id) for a, c in self._latest(robot, space, scene).items()}

    def models_at(self, angle: float, robot: str | None = None, space: str | None = None,
                  scene: str | None = None, tolerance: float = 0.5) -> dict[tuple[int, int], Johnson]:
        """Models of the capture measured within `tolerance` degrees of `angle` (nearest), or {}."""
        by_angle = self.models_by_angle(robot, space, scene)
        near = [a for a in by_angle if abs(a - angle) <= tolerance]
        if not near:
            return {}
        return by_angle[min(near, key=lambda a: abs(a - angle))]

    def labels(self) -> list[int]:
        return [r[0] for r in self._conn.execute("SELECT DISTINCT label FROM models ORDER BY label")]


def _dependence_row(d: Dependence) -> tuple:
    """(corr, acf, radius, lo, hi) columns of a record (JSON lists, null at a lag not measured;
    NULL what it lacks)."""
    grain = (json.dumps(list(d.corr)), json.dumps(d.acf_rows()), d.radius) if d.measured else (None,) * 3
    return (*grain, json.dumps(list(d.lo)) if d.lo else None, json.dumps(list(d.hi)) if d.hi else None)


def _dependence_of(corr, dx, dy, acf, radius, lo, hi) -> Dependence:
    """A stored record: the 2-D window, or the older layout's lags along rows and columns."""
    seen = (tuple(json.loads(lo)), tuple(json.loads(hi))) if lo is not None else ((), ())
    if acf is not None:
        return Dependence.from_rows(json.loads(corr), json.loads(acf), int(radius), *seen)
    if dx is not None:
        return Dependence.from_lags(*(tuple(json.loads(x)) for x in (corr, dx, dy)), *seen)
    return Dependence.observed(*seen)
