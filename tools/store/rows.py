"""The records `tools.store.database` reads back, and the checks that build them from database rows.

SQLite types are per value, not per column, and a database may have been edited by hand or
written by another program, so every value a record is built from is checked: a NaN or
infinite parameter, text in a number column, a broken band list or a mask whose PNG claims
another size raises ValueError naming the column, which the store turns into one
`CorruptDatabase` line. Sizes are bounded by `radio.packets.base` before anything is decoded.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Any

from btf.capture_settings import MAX_BRACKETS, CaptureSettings
from btf.johnson import Family, Johnson
from btf.record import FittedModel
from radio.packets.base import MAX_BANDS, MAX_FRAME_SIDE, MAX_LABELS

MAX_ROW_INT = 2**63 - 1
# A dataset's captures are stored under the robot id `dataset:<its absolute folder>`, each with
# its file name inside that folder as `source` (tools.data.ingest).
DATASET_PREFIX = "dataset:"


@dataclass(frozen=True, slots=True)
class StoredCapture:
    """A capture row as the database holds it (its models are read separately: Store.models)."""

    id: int
    robot: str
    sequence: int
    time: float
    commanded: tuple[float | None, float | None]
    measured: tuple[float, float]
    space: str
    band_names: tuple[str, ...]
    scene: str
    illumination: tuple[float | None, float | None] = (None, None)
    source: str | None = None
    levels: int = 256  # the sensor's levels: 256 for 8-bit pixels, 65536 for 16-bit
    camera: CaptureSettings | None = None  # what it was taken with (None: not recorded)
    incarnation: str = ""  # the robot state that numbered it ("" for none): tools.station.receiver

    @property
    def elevation(self) -> float:
        return self.measured[0]

    @property
    def dataset(self) -> str | None:
        """The folder of the dataset an ingest fitted this capture from (None: not a dataset's)."""
        return self.robot[len(DATASET_PREFIX):] if self.robot.startswith(DATASET_PREFIX) else None

    @property
    def source_file(self) -> str | None:
        """The image file this capture was fitted from, where the database says (a dataset's item)."""
        if self.source is None:
            return None
        return f"{self.dataset.rstrip('/')}/{self.source}" if self.dataset else self.source


def capture_from_row(r: tuple) -> StoredCapture:
    """(id, robot, sequence, time, cmd_elevation, cmd_azimuth, elevation, azimuth, space,
    bands, scene, light_elevation, light_azimuth, source, levels[, incarnation[, the capture_camera
    columns]]) -> StoredCapture."""
    n = [number(v, name, nullable) for v, name, nullable in (
        (r[3], "time", False), (r[4], "commanded elevation", True), (r[5], "commanded azimuth", True),
        (r[6], "elevation", False), (r[7], "azimuth", False),
        (r[11], "light elevation", True), (r[12], "light azimuth", True))]
    return StoredCapture(integer(r[0], "id"), text(r[1], "robot"), integer(r[2], "sequence"), n[0],
                   (n[1], n[2]), (n[3], n[4]), text(r[8], "space"), band_names(r[9]),
                   text(r[10], "scene"), (n[5], n[6]), None if r[13] is None else text(r[13], "source"),
                   integer(r[14], "levels", 2, 65536), camera_from_row(r[16:]) if len(r) > 16 else None,
                   text(r[15], "incarnation") if len(r) > 15 else "")


CAMERA_COLUMNS = ("exposure_us", "gain", "wb_kelvin", "wb_red", "wb_blue", "sensor_c", "unlocked", "reference",
                  "reference_clipped", "brackets", "bracketed", "source")


def camera_from_row(r: tuple) -> CaptureSettings | None:
    """The capture_camera columns (`CAMERA_COLUMNS`, all None: no row) -> CaptureSettings."""
    if all(v is None for v in r):
        return None
    exposure, gain, kelvin, red, blue, sensor = (number(v, f"camera {n}", True)
                                                 for v, n in zip(r[:6], CAMERA_COLUMNS))
    try:
        reference = None if r[7] is None else json.loads(text(r[7], "camera reference"))
        brackets, bracketed = json.loads(text(r[9], "camera brackets")), json.loads(text(r[10], "camera bracketed"))
    except json.JSONDecodeError as exc:
        raise ValueError(f"camera settings hold broken JSON ({exc})") from None
    if reference is not None and (type(reference) is not list or len(reference) > MAX_BANDS):
        raise ValueError(f"camera reference is {_shown(reference)}, not a list of levels")
    if type(brackets) is not list or len(brackets) > MAX_BRACKETS or type(bracketed) is not dict:
        raise ValueError("camera brackets are not a list of exposures with a map of labels")
    try:
        return CaptureSettings(
            exposure, gain, kelvin, None if red is None or blue is None else (red, blue), sensor,
            bool(integer(r[6], "camera unlocked", 0, 1)),
            None if reference is None else tuple(number(v, "camera reference level") for v in reference),
            number(r[8], "camera reference_clipped"),
            tuple(number(v, "camera bracket exposure") for v in brackets),
            {integer(int(k) if str(k).isdigit() else k, "bracketed label", 0, MAX_LABELS - 1):
             integer(v, "bracket index", 1, MAX_BRACKETS) for k, v in bracketed.items()},
            None if r[11] is None else text(r[11], "camera source"))
    except ValueError as exc:
        raise ValueError(f"camera settings: {exc}") from None


def model_from_row(r: tuple) -> tuple[tuple[int, int], FittedModel]:
    """(capture, label, band, family, gamma, delta, xi, lam, p0..p3, z, count, beta1, beta2,
    censored_low, censored_high, shift, fallback, exact_family) -> ((label, band), record)."""
    label = integer(r[1], "label", 0, MAX_LABELS - 1)
    band = integer(r[2], "band", 0, MAX_BANDS - 1)
    try:
        opt = [number(v, name, True) for v, name in zip(
            (*r[8:13], r[14], r[15]), ("p0", "p1", "p2", "p3", "z", "beta1", "beta2"))]
        low, high, shift = (number(v, name) for v, name in zip(r[16:19], ("censored_low", "censored_high", "shift")))
        if not (0.0 <= low <= 1.0 and 0.0 <= high <= 1.0):
            raise ValueError(f"censored fractions {low}, {high} outside [0, 1]")
        fallback, exact = (bool(integer(v, name, 0, 1)) for v, name in zip(r[19:21], ("fallback", "exact_family")))
        return (label, band), FittedModel(johnson(*r[3:8]), integer(r[13], "count"), opt[4], tuple(opt[:4]),
                                          opt[5], opt[6], shift, low, high, fallback, exact)
    except ValueError as exc:
        raise ValueError(f"model (label {label}, band {band}): {exc}") from None


def mask_png(height: Any, width: Any, data: Any) -> tuple[tuple[int, int], bytes]:
    """((height, width), PNG bytes) of a masks row, its size checked against the PNG's own
    header before anything is decoded."""
    shape = (integer(height, "height", 1, MAX_FRAME_SIDE), integer(width, "width", 1, MAX_FRAME_SIDE))
    png = data if type(data) is bytes else b""
    if png[12:16] != b"IHDR" or (int.from_bytes(png[20:24], "big"), int.from_bytes(png[16:20], "big")) != shape:
        raise ValueError("its data is not a PNG of its stored size")
    return shape, png


def number(v: Any, name: str, nullable: bool = False) -> float | None:
    """A finite float from a REAL column (ints are numbers too); None only when `nullable`."""
    if v is None and nullable:
        return None
    if type(v) not in (int, float):
        raise ValueError(f"{name} is {_shown(v)}, not a number")
    if not math.isfinite(v):
        raise ValueError(f"{name} is {v}, not a finite number")
    return float(v)


def integer(v: Any, name: str, lo: int = 0, hi: int = MAX_ROW_INT) -> int:
    if type(v) is not int:
        raise ValueError(f"{name} is {_shown(v)}, not an integer")
    if not lo <= v <= hi:
        raise ValueError(f"{name} = {v} outside [{lo}, {hi}]")
    return v


def text(v: Any, name: str) -> str:
    if type(v) is not str:
        raise ValueError(f"{name} is {_shown(v)}, not text")
    return v


def band_names(v: Any) -> tuple[str, ...]:
    """The JSON list of band names a capture row holds."""
    try:
        names = json.loads(text(v, "bands"))
    except json.JSONDecodeError:
        names = None
    if type(names) is not list or not names or not all(type(n) is str for n in names):
        raise ValueError(f"bands is {_shown(v)}, not a JSON list of names")
    return tuple(names)


def johnson(family: Any, gamma: Any, delta: Any, xi: Any, lam: Any) -> Johnson:
    """The model of a models row: a known family and parameters it accepts."""
    try:
        fam = Family[text(family, "family")]
    except KeyError:
        raise ValueError(f"unknown family {family!r}") from None
    values = [number(v, n) for v, n in ((gamma, "gamma"), (delta, "delta"), (xi, "xi"), (lam, "lam"))]
    return Johnson(fam, *values)  # its own checks (delta > 0, lam's sign) raise ValueError


def _shown(v: Any) -> str:
    s = repr(v)
    return s if len(s) <= 40 else s[:37] + "..."


@dataclass(frozen=True, slots=True)
class RejectedPacket:
    """A packet the station could not use, as it arrived (`Store.add_rejected`)."""

    id: int
    received: float
    sender: int | None
    incarnation: str
    msg_id: int | None
    reason: str
    body: bytes


def rejected_from_row(row: tuple) -> RejectedPacket:
    rid, received, sender, incarnation, msg_id, reason, body = row
    for name, v in (("id", rid), ("sender", sender), ("msg_id", msg_id)):
        if v is not None and type(v) is not int:
            raise ValueError(f"{name} is {v!r}, not an integer")
    if type(received) not in (int, float) or not math.isfinite(received):
        raise ValueError(f"received is {received!r}, not a time")
    if type(reason) is not str or type(incarnation) is not str or type(body) is not bytes:
        raise ValueError("reason, incarnation or body of the wrong type")
    return RejectedPacket(rid, float(received), sender, incarnation, msg_id, reason, body)
