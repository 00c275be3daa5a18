"""The database's BTF as Apache Parquet (or CSV) files a researcher opens in pandas, DuckDB or
Dask without our SQLite schema (docs/export.md): one row per capture x region x band,
partitioned hive-style by robot and scene (`robot=<r>/scene=<s>/part-<first>-<last>.parquet`,
the values percent-encoded, the capture ids each file holds in its name).

A file appears only whole: it is written under a hidden temporary name and renamed when
complete, so a reader never sees half of one and a failure (a damaged row, a full disk) leaves
none. A new export is built in a hidden sibling directory and renamed into place. Exporting
again into an export of the same database adds, per partition, only the captures stored since
(ids above those its files hold); `replace` rebuilds the whole export the same way.
"""
from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterator
from urllib.parse import quote

import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from tools.analysis.btf_view import moments
from tools.data.ingest import DATASET_PREFIX

FORMATS = ("parquet", "csv")
MANIFEST = "_btfscout_export.json"  # leading "_": readers of the directory skip it
EXPORT_VERSION = "2"  # 2: observed levels, the grain on the 2-D window instead of lags along rows and columns
BATCH_CAPTURES = 512  # captures per row group: bounded memory for any database
_PART = re.compile(r"^part-(\d+)-(\d+)\.(parquet|csv)$")

_F, _S, _I, _B, _L = pa.float64(), pa.string(), pa.int64(), pa.bool_(), pa.list_(pa.float64())
SCHEMA = pa.schema([
    ("capture_id", _I), ("incarnation", _S), ("sequence", _I), ("time", _F), ("space", _S), ("levels", _I),
    ("label", _I), ("band", _I), ("band_name", _S),
    ("elevation", _F), ("azimuth", _F), ("light_elevation", _F), ("light_azimuth", _F),
    ("commanded_elevation", _F), ("commanded_azimuth", _F), ("dataset", _S), ("source_file", _S),
    ("family", _S), ("gamma", _F), ("delta", _F), ("xi", _F), ("lam", _F),
    ("p0", _F), ("p1", _F), ("p2", _F), ("p3", _F), ("z", _F), ("shift", _F),
    ("censored_low", _F), ("censored_high", _F), ("fallback", _B), ("exact_family", _B),
    ("pixels", _I), ("beta1", _F), ("beta2", _F), ("mean", _F), ("sd", _F), ("skewness", _F), ("kurtosis", _F),
    ("exposure_us", _F), ("fitted_exposure_us", _F), ("gain", _F), ("wb_kelvin", _F), ("wb_red", _F),
    ("wb_blue", _F), ("sensor_c", _F), ("unlocked", _B), ("reference", _L), ("reference_clipped", _F),
    ("brackets", _L), ("level_lo", _I), ("level_hi", _I),
    ("dependence_corr", _L), ("dependence_radius", _I), ("dependence_acf", _L),
], metadata={"btfscout.dependence_window": "half-plane: (0, 1..R), then (dy, -R..R) for dy = 1..R",
             "btfscout.export": EXPORT_VERSION})
LISTS = [f.name for f in SCHEMA if pa.types.is_list(f.type)]
# CSV has no lists: they are JSON text there
CSV_SCHEMA = pa.schema([pa.field(f.name, _S if f.name in LISTS else f.type) for f in SCHEMA])


class ExportError(ValueError):
    """The output cannot be written as asked; the message says why and what to do."""


@dataclass(frozen=True, slots=True)
class ExportReport:
    out: Path
    rows: int  # written now
    files: int  # written now
    partitions: int  # in the database
    fresh: bool  # a new export (not added to an earlier one)


def partition_dir(robot: str, scene: str) -> str:
    return f"robot={quote(robot, safe='')}/scene={quote(scene, safe='')}"


def capture_rows(store: Any, c: Any) -> list[dict]:
    """One row per model of capture `c`, as stored (moments of the stored model's level probabilities)."""
    cam, dep = c.camera, store.dependence(c.id)
    dataset = c.robot[len(DATASET_PREFIX):] if c.robot.startswith(DATASET_PREFIX) else None
    rows = []
    for (label, band), r in store.models(c.id).items():
        m, mo = r.model, moments(r.model.level_probabilities(c.levels))
        d = dep.get(label)
        rows.append({
            "capture_id": c.id, "incarnation": c.incarnation, "sequence": c.sequence, "time": c.time,
            "space": c.space, "levels": c.levels, "label": label, "band": band,
            "band_name": c.band_names[band] if band < len(c.band_names) else None,
            "elevation": c.measured[0], "azimuth": c.measured[1], "light_elevation": c.illumination[0],
            "light_azimuth": c.illumination[1], "commanded_elevation": c.commanded[0],
            "commanded_azimuth": c.commanded[1], "dataset": dataset, "source_file": c.source,
            "family": m.family.value, "gamma": m.gamma, "delta": m.delta, "xi": m.xi, "lam": m.lam,
            **dict(zip(("p0", "p1", "p2", "p3"), r.percentiles)), "z": r.z, "shift": r.shift,
            "censored_low": r.censored_low, "censored_high": r.censored_high, "fallback": r.fallback,
            "exact_family": r.exact_family, "pixels": r.count, "beta1": r.beta1, "beta2": r.beta2,
            **mo.as_dict(), **_camera(cam, label),
            **_dependence(d, band)})
    return rows


def _dependence(d: Any, band: int) -> dict:
    """A band's columns of its region's record: observed levels, and the grain (its own row)."""
    if d is None:
        return {}
    seen = d.levels(band) if d.lo else (None, None)
    grain = ({"dependence_corr": list(d.corr), "dependence_radius": d.radius,
              "dependence_acf": d.acf_rows()[band if d.per_band else 0]} if d.measured else {})
    return {"level_lo": seen[0], "level_hi": seen[1], **grain}


def _camera(s: Any, label: int) -> dict:
    if s is None:
        return {}
    red, blue = s.white_balance_gains or (None, None)
    return {"exposure_us": s.exposure_us, "fitted_exposure_us": s.exposure_of(label) if s.exposure_us else None,
            "gain": s.gain, "wb_kelvin": s.white_balance_kelvin, "wb_red": red, "wb_blue": blue,
            "sensor_c": s.sensor_temperature_c, "unlocked": s.unlocked,
            "reference": None if s.reference is None else list(s.reference),
            "reference_clipped": s.reference_clipped, "brackets": list(s.brackets)}


def _table(rows: list[dict], fmt: str) -> pa.Table:
    if fmt == "csv":
        rows = [{**r, **{k: None if r.get(k) is None else json.dumps(r[k]) for k in LISTS}} for r in rows]
        return pa.Table.from_pylist(rows, schema=CSV_SCHEMA)
    return pa.Table.from_pylist(rows, schema=SCHEMA)


def _batches(store: Any, captures: list) -> Iterator[list[dict]]:
    for k in range(0, len(captures), BATCH_CAPTURES):
        rows = [row for c in captures[k:k + BATCH_CAPTURES] for row in capture_rows(store, c)]
        if rows:
            yield rows


def write_part(store: Any, captures: list, folder: Path, fmt: str) -> int:
    """One file of `captures` in `folder`, complete or absent: rows written."""
    folder.mkdir(parents=True, exist_ok=True)
    final = folder / f"part-{captures[0].id:012d}-{captures[-1].id:012d}.{fmt}"
    temp = folder / f".{final.name}.tmp-{os.getpid()}"
    rows = 0
    try:
        with open(temp, "wb") as fh:
            writer = pq.ParquetWriter(fh, SCHEMA) if fmt == "parquet" else pacsv.CSVWriter(fh, CSV_SCHEMA)
            try:
                for batch in _batches(store, captures):
                    writer.write_table(_table(batch, fmt))
                    rows += len(batch)
            except BaseException:
                with contextlib.suppress(Exception):  # the first error is the one to tell
                    writer.close()
                raise
            writer.close()
            fh.flush()
            os.fsync(fh.fileno())
        if rows:
            os.replace(temp, final)
            _sync_dir(folder)
    finally:
        temp.unlink(missing_ok=True)
    return rows


def _sync_dir(folder: Path) -> None:
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def exported_up_to(folder: Path) -> int:
    """The highest capture id the partition's files hold (0: none)."""
    if not folder.is_dir():
        return 0
    found = [_PART.match(p.name) for p in folder.iterdir()]
    return max((int(m.group(2)) for m in found if m), default=0)


def _identity(store: Any, fmt: str) -> dict:
    """What ties an export to its database: the format and the first capture stored."""
    first = min(store.captures(), key=lambda c: c.id, default=None)
    return {"format": fmt, "schema": EXPORT_VERSION, "first_capture": None if first is None else
            [first.id, first.robot, first.incarnation, first.sequence, first.time]}


def _same_export(out: Path, identity: dict) -> bool:
    try:
        return json.loads((out / MANIFEST).read_text()) == identity
    except (OSError, ValueError):
        return False


def _not_export(out: Path) -> list[str]:
    """The names in `out` that no export writes (its manifest, its robot=... partitions)."""
    return sorted(p.name for p in out.iterdir()
                  if not (p.name == MANIFEST or (p.name.startswith("robot=") and p.is_dir())))


def _fill(store: Any, root: Path, fmt: str) -> tuple[int, int, int]:
    """Adds what `root` lacks, partition by partition: (rows, files, partitions)."""
    rows = files = 0
    pairs = sorted({(c.robot, c.scene) for c in store.captures()})
    for robot, scene in pairs:
        folder = root / partition_dir(robot, scene)
        done = exported_up_to(folder)
        new = sorted((c for c in store.captures(robot=robot, scene=scene) if c.id > done), key=lambda c: c.id)
        if new:
            n = write_part(store, new, folder, fmt)
            rows, files = rows + n, files + (n > 0)
    return rows, files, len(pairs)


def export(store: Any, out: str | Path, fmt: str = "parquet", replace: bool = False) -> ExportReport:
    """Writes or brings up to date the export of `store` at `out` (ExportError: why not)."""
    if fmt not in FORMATS:
        raise ExportError(f"format {fmt!r}: expected {' or '.join(FORMATS)}")
    out = Path(out)
    identity = _identity(store, fmt)
    if out.exists() and not out.is_dir():
        raise ExportError(f"--out {out} is a file; give a directory")
    if out.is_dir():
        foreign = _not_export(out)
        if foreign:  # --force replaces the whole directory: only ever an export's own files
            shown = ", ".join(foreign[:3]) + (f" and {len(foreign) - 3} more" if len(foreign) > 3 else "")
            raise ExportError(f"--out {out} holds {shown}, not an export; give a new or empty directory "
                              "(--force replaces only an earlier export)")
        if not replace and (out / MANIFEST).exists():
            if not _same_export(out, identity):
                raise ExportError(f"--out {out} is not a {fmt} export of this database; pass --force to replace it")
            rows, files, parts = _fill(store, out, fmt)
            return ExportReport(out, rows, files, parts, False)
    if not out.parent.is_dir():
        raise ExportError(f"--out {out}: directory {out.parent} does not exist")
    temp = out.parent / f".{out.name}.tmp-{os.getpid()}"
    shutil.rmtree(temp, ignore_errors=True)
    try:
        temp.mkdir()
        rows, files, parts = _fill(store, temp, fmt)
        (temp / MANIFEST).write_text(json.dumps(identity))
        _swap(temp, out)
    finally:
        shutil.rmtree(temp, ignore_errors=True)
    return ExportReport(out, rows, files, parts, True)


def _swap(new: Path, out: Path) -> None:
    """`new` renamed to `out`; an earlier `out` moved aside first, removed after."""
    old = out.parent / f".{out.name}.old-{os.getpid()}"
    if out.exists():
        os.replace(out, old)
    os.replace(new, out)
    shutil.rmtree(old, ignore_errors=True)
