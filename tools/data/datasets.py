"""Image folders of historical BTF collections and the angles of every image.

Three layouts:
- curet: an angle table (CUReT style) maps image numbers to view and illumination
  polar angles in radians: one line per image, `number theta_v phi_v theta_i phi_i`
  (`#` comments); the image number is the last group of digits in the file name
  (`01-017.bmp` is image 17). Default table: `angles.txt` in the folder.
- utia: angles in the file name, `tl{theta_i}_pl{phi_i}_tv{theta_v}_pv{phi_v}.ext`,
  polar angles in degrees (UTIA/Bonn style).
- folder: a CSV sidecar `file,elevation,azimuth[,light_elevation,light_azimuth]` in
  degrees (elevation above the horizon, as the robot measures it), or no sidecar at all.

Polar angles (from the surface normal) become elevations, 90 - theta, the convention of the
rest of btfscout; azimuths are kept and wrapped into [0, 360).
"""
from __future__ import annotations

import csv
import enum
import math
import re
from dataclasses import astuple, dataclass
from pathlib import Path

from hal.interfaces import ViewAngles
from hal.scene import SUN, LightAngles, render
from tools.data.images import write_image, write_mask

IMAGE_EXTENSIONS = frozenset({".png", ".bmp", ".jpg", ".jpeg", ".tif", ".tiff", ".ppm", ".pgm"})
DEFAULT_TABLES = {"curet": "angles.txt", "folder": "angles.csv"}
_UTIA = re.compile(r"tl(?P<ti>\d+(?:\.\d+)?)_pl(?P<pi>\d+(?:\.\d+)?)"
                   r"_tv(?P<tv>\d+(?:\.\d+)?)_pv(?P<pv>\d+(?:\.\d+)?)", re.IGNORECASE)
_DIGITS = re.compile(r"\d+")


class Layout(enum.StrEnum):
    CURET = "curet"
    UTIA = "utia"
    FOLDER = "folder"


class DatasetError(ValueError):
    """A dataset that cannot be read; the message names the file and the problem."""


@dataclass(frozen=True, slots=True)
class Angles:
    """View (and, when known, illumination) direction in degrees: elevation above the horizon."""

    elevation: float
    azimuth: float
    light_elevation: float | None = None
    light_azimuth: float | None = None

    @property
    def has_light(self) -> bool:
        return self.light_elevation is not None


@dataclass(frozen=True, slots=True)
class DatasetImage:
    name: str  # file name inside the dataset folder: the resume key
    path: Path
    angles: Angles | None  # None: a folder without a sidecar


def _check_elevation(value: float, where: str) -> float:
    if not (math.isfinite(value) and 0.0 <= value <= 90.0):
        raise DatasetError(f"{where}: elevation {value:g} outside 0..90 degrees")
    return value


def _direction(elevation: float, azimuth: float, where: str) -> tuple[float, float]:
    if not math.isfinite(azimuth):
        raise DatasetError(f"{where}: azimuth {azimuth} is not finite")
    return _check_elevation(elevation, where), azimuth % 360.0


def from_polar(theta_v: float, phi_v: float, theta_i: float | None = None,
               phi_i: float | None = None, where: str = "angles") -> Angles:
    """Angles from polar (zenith) angles in degrees."""
    el, az = _direction(90.0 - theta_v, phi_v, where)
    if theta_i is None or phi_i is None:
        return Angles(el, az)
    lel, laz = _direction(90.0 - theta_i, phi_i, where + " (illumination)")
    return Angles(el, az, lel, laz)


def image_files(root: Path) -> list[Path]:
    """Image files directly inside `root`, sorted by name."""
    return sorted((p for p in root.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS),
                  key=lambda p: p.name)


def parse_utia_name(name: str) -> Angles:
    """Angles of a UTIA file name `tl{ti}_pl{pi}_tv{tv}_pv{pv}.ext`; DatasetError otherwise."""
    m = _UTIA.fullmatch(Path(name).stem)
    if m is None:
        raise DatasetError(f"image {name}: file name does not read as tl{{θi}}_pl{{φi}}_tv{{θv}}_pv{{φv}}")
    return from_polar(float(m["tv"]), float(m["pv"]), float(m["ti"]), float(m["pi"]), f"image {name}")


def read_curet_table(path: Path) -> dict[int, Angles]:
    """Image number -> Angles from a CUReT angle table (polar angles in radians)."""
    if not path.is_file():
        raise DatasetError(f"angle table {path}: no such file")
    table: dict[int, Angles] = {}
    for lineno, line in enumerate(path.read_text(errors="replace").splitlines(), 1):
        fields = line.split("#", 1)[0].replace(",", " ").split()
        if not fields:
            continue
        where = f"angle table {path}, line {lineno}"
        if len(fields) != 5:
            raise DatasetError(f"{where}: expected 'number theta_v phi_v theta_i phi_i', got {len(fields)} fields")
        try:
            number = int(fields[0])
            rad = [float(v) for v in fields[1:]]
        except ValueError:
            raise DatasetError(f"{where}: not numbers: {line.strip()!r}") from None
        if any(not math.isfinite(v) or abs(v) > 2.0 * math.pi + 1e-9 for v in rad):
            raise DatasetError(f"{where}: angles must be radians within ±2π (CUReT tables are in radians)")
        if number in table:
            raise DatasetError(f"{where}: image {number} listed twice")
        # rounded to a micro-degree: radians in a text table carry no more than that
        table[number] = from_polar(*(round(math.degrees(v), 6) for v in rad), where=where)
    if not table:
        raise DatasetError(f"angle table {path}: no rows")
    return table


def read_sidecar(path: Path) -> dict[str, Angles]:
    """File name -> Angles from a folder's CSV sidecar (degrees, elevation above the horizon)."""
    if not path.is_file():
        raise DatasetError(f"angle table {path}: no such file")
    # utf-8-sig: spreadsheets write a byte-order mark before the header; spaces after commas are read past
    with open(path, newline="", encoding="utf-8-sig", errors="replace") as fh:
        reader = csv.DictReader(fh, skipinitialspace=True)
        rows = list(reader)
        fields = {(name or "").strip() for name in reader.fieldnames or ()}
    need = {"file", "elevation", "azimuth"}
    if not need <= fields:
        found = ", ".join(sorted(f for f in fields if f)) or "none"
        raise DatasetError(f"angle table {path}: needs columns {', '.join(sorted(need))} (found: {found})")
    if not rows:
        raise DatasetError(f"angle table {path}: no rows below its header")
    light = {"light_elevation", "light_azimuth"} <= fields
    out: dict[str, Angles] = {}
    for lineno, raw in enumerate(rows, 2):
        row = {(k or "").strip(): v.strip() if isinstance(v, str) else ("" if v is None else v) for k, v in raw.items()}
        where = f"angle table {path}, line {lineno}"
        if row["file"] in out:
            raise DatasetError(f"{where}: {row['file']} listed twice")
        try:
            el, az = _direction(float(row["elevation"]), float(row["azimuth"]), where)
            lel = laz = None
            if light and (row["light_elevation"] or row["light_azimuth"]):
                if not (row["light_elevation"] and row["light_azimuth"]):
                    raise DatasetError(f"{where}: a light direction needs both light_elevation and light_azimuth")
                lel, laz = _direction(float(row["light_elevation"]), float(row["light_azimuth"]),
                                      where + " (illumination)")
        except (TypeError, ValueError) as exc:
            if isinstance(exc, DatasetError):
                raise
            raise DatasetError(f"{where}: angles are not numbers") from None
        out[row["file"]] = Angles(el, az, lel, laz)
    return out


def scan(root: str | Path, layout: str | Layout, table: str | Path | None = None) -> list[DatasetImage]:
    """Every image of the dataset at `root` with its angles, sorted by file name."""
    root = Path(root)
    try:
        layout = Layout(layout)
    except ValueError:
        raise DatasetError(f"layout {layout!r}: expected one of {', '.join(m.value for m in Layout)}") from None
    if not root.is_dir():
        raise DatasetError(f"dataset {root}: no such directory")
    files = image_files(root)
    if not files:
        raise DatasetError(f"dataset {root}: no image files ({', '.join(sorted(IMAGE_EXTENSIONS))})")
    table_path = Path(table) if table is not None else None
    if layout is Layout.UTIA:
        return [DatasetImage(p.name, p, parse_utia_name(p.name)) for p in files]
    if layout is Layout.CURET:
        angles = read_curet_table(table_path or root / DEFAULT_TABLES["curet"])
        out = []
        for p in files:
            digits = _DIGITS.findall(p.stem)
            if not digits:
                raise DatasetError(f"image {p.name}: no image number in the file name")
            number = int(digits[-1])
            if number not in angles:
                raise DatasetError(f"image {p.name}: image number {number} is not in the angle table")
            out.append(DatasetImage(p.name, p, angles[number]))
        return out
    sidecar = table_path or root / DEFAULT_TABLES["folder"]
    if table_path is None and not sidecar.exists():
        return [DatasetImage(p.name, p, None) for p in files]
    angles_by_name = read_sidecar(sidecar)
    missing = [p.name for p in files if p.name not in angles_by_name]
    if missing:
        raise DatasetError(f"angle table {sidecar}: no row for {missing[0]}"
                           + (f" and {len(missing) - 1} more" if len(missing) > 1 else ""))
    return [DatasetImage(p.name, p, angles_by_name[p.name]) for p in files]


# --- small datasets in every layout, rendered by the scene model (tests, benchmarks) ---------
RENDER_SUN = Angles(45.0, 225.0)  # hal.scene.SUN, the renderer's default light


def _num(v: float) -> str:
    return f"{v:03.0f}" if float(v).is_integer() else f"{v:g}"


def rendered_name(layout: Layout, index: int, angles: Angles) -> str:
    if layout is Layout.UTIA:
        light = angles if angles.has_light else RENDER_SUN
        lel, laz = (light.light_elevation, light.light_azimuth) if angles.has_light else (light.elevation,
                                                                                         light.azimuth)
        return (f"tl{_num(90.0 - lel)}_pl{_num(laz)}_tv{_num(90.0 - angles.elevation)}"
                f"_pv{_num(angles.azimuth)}.png")
    if layout is Layout.CURET:
        return f"01-{index + 1:03d}.png"
    return f"view_{index:03d}.png"


def write_rendered(root: str | Path, layout: str | Layout, views: list[Angles], scene: str = "mixed",
                   size: tuple[int, int] = (48, 64), seed: int = 0, masks: bool = True) -> list[Path]:
    """Render `views` of `scene` into `root` in `layout` (with its angle table), masks in root/masks.

    A view's illumination direction lights the scene (shading and cast shadows); a view
    without one is lit by the renderer's sun, `RENDER_SUN`. All views share one grain layout.
    """
    layout, root = Layout(layout), Path(root)
    root.mkdir(parents=True, exist_ok=True)
    if masks:
        (root / "masks").mkdir(exist_ok=True)
    lights = [LightAngles(a.light_elevation, a.light_azimuth) if a.has_light else None for a in views]
    names = [rendered_name(layout, k, a) for k, a in enumerate(views)]
    # grouped by light: the renderer shades its surface once per light direction
    for k in sorted(range(len(views)), key=lambda k: astuple(lights[k] or SUN)):
        a = views[k]
        try:
            view = render(scene, ViewAngles(a.elevation, a.azimuth), size, seed, light=lights[k])
        except ValueError as exc:
            raise DatasetError(f"rendered view {k} ({names[k]}): {exc}") from None
        write_image(root / names[k], view.image)
        if masks:
            write_mask(root / "masks" / (Path(names[k]).stem + ".png"), view.mask)
    paths = [root / name for name in names]
    table = [(k + 1, name, a) for k, (name, a) in enumerate(zip(names, views))]
    if layout is Layout.CURET:
        lines = ["# number theta_v phi_v theta_i phi_i (radians)"]
        for number, _, a in table:
            light = a if a.has_light else Angles(0, 0, RENDER_SUN.elevation, RENDER_SUN.azimuth)
            lines.append(" ".join(f"{math.radians(v):.15g}" for v in (
                90.0 - a.elevation, a.azimuth, 90.0 - light.light_elevation, light.light_azimuth)).join(
                (f"{number} ", "")))
        (root / DEFAULT_TABLES["curet"]).write_text("\n".join(lines) + "\n")
    elif layout is Layout.FOLDER:
        rows = ["file,elevation,azimuth,light_elevation,light_azimuth"]
        rows += [f"{n},{a.elevation:g},{a.azimuth:g},{'' if a.light_elevation is None else f'{a.light_elevation:g}'},"
                 f"{'' if a.light_azimuth is None else f'{a.light_azimuth:g}'}" for _, n, a in table]
        (root / DEFAULT_TABLES["folder"]).write_text("\n".join(rows) + "\n")
    return paths
