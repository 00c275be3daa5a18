"""The robot's TOML configuration, read once at start into frozen dataclasses.

Every problem (missing file, bad TOML, unknown key, wrong type, a number outside what the
robot can use (`BOUNDS`, in `onboard.config.limits`), missing key file) raises `ConfigError`
with one line naming the key and the file; the runtime stops with exit status 2 before it
creates anything. Relative paths are resolved against the config file's directory.
"""
from __future__ import annotations

import math
import os
import tomllib
import types
import typing
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Mapping

from btf.capture_settings import LINEAR_SPACES
from hal.bno055 import AxisRemap
from hal.controls import AUTO, FALLBACK_LOCK, hold, parse_controls
from hal.interfaces import CameraControls, CameraSettings
from onboard.config.limits import BOUNDS, CHOICES, choices_said
from onboard.sweep.plan import SweepPlan
from radio.packets.base import band_names_problem

# A camera control: a number, "auto" (the camera's automatic) or "hold" (locked at what the
# camera stands at when the robot starts). TOML gives it as a number or a string.
CameraValue = typing.NewType("CameraValue", str)


class ConfigError(ValueError):
    """The configuration cannot be used; the message is one line naming the problem."""


@dataclass(frozen=True, slots=True)
class HalConfig:
    body: str = ""  # fake | emulated | real; empty: BTF_HAL decides, or the runtime refuses
    scene: str = "black"
    size: tuple[int, int] = (120, 160)  # camera frame (height, width)
    fault_rate: float = 0.0
    fault_seed: int = 0
    servo_port: str = ""
    servo_baud: int = 1_000_000
    tracker_bus: int = 1
    # real camera: device index or path, or "picamera2"; unset: picamera2 if installed, else 0.
    # Fake and emulated bodies: "replay:DIR_OR_GLOB" plays PNG/JPEG files as the frames (hal.replay),
    # at their own size (hal.size must match them); a relative path is against the config file
    camera: str = ""
    seed: int = 0
    tracker_remap: str = ""  # BNO055 axis remap, P0..P7 or "0x24/0x03"; `btf-robot calibrate tracker` names it
    reference: bool = False  # fake and emulated scenes: lay the grey reference card (label 7) in the plate
    replay_loop: bool = False  # replay camera: start over after the last file; false: the poses after it are skipped
    # the camera's pixel format, a V4L2 four-character code: "Y16 " a 16-bit thermal camera, "MSP6" the
    # fake body's multi-spectral camera (five spectral bands and thermal); "": the camera's own (BGR3)
    pixel_format: str = ""


@dataclass(frozen=True, slots=True)
class LinkConfig:
    url: str = "loop://"
    key_file: Path = Path("robot.key")
    baud: int = 115_200
    node_id: int = 1
    peer_id: int = 2
    link_id: int = 1
    mtu: int = 100
    heartbeat_s: float = 1.0
    failsafe_s: float = 5.0  # silence from the base after which the arm stops and holds
    window: int = 8  # packets in flight from the outbox
    # rtc: the wall clock is right from boot (a real-time clock, or NTP before the robot starts),
    # so a lost counters file restarts the link counters from it; none: it is not, and a lost
    # counters file stops the robot until the key is rotated (radio.auth)
    clock: str = "rtc"


@dataclass(frozen=True, slots=True)
class SweepConfig:
    start: float = 90.0
    stop: float = 30.0
    step: float = 10.0
    azimuths: tuple[float, ...] = (0.0,)
    autostart: bool = True
    settle_timeout_s: float = 10.0
    retries: int = 2  # extra attempts per device step before the pose is skipped
    pose_tolerance_deg: float = 1.0  # measured pose already in this sweep: not measured again
    retry_skipped: int = 2  # after the plan: more tries of each pose a device fault skipped


@dataclass(frozen=True, slots=True)
class FeatureConfig:
    space: str = "rgb"  # rgb | hsv | gray | pca | raw | auto (resolved per scene: onboard.capture.space_auto)
    bands: tuple[str, ...] = ()  # empty: every band of the space
    bins_16bit: int = 4096  # histogram bins over 0..65535 for 16-bit sensors (memory: labels x bands x bins)
    # space raw: the camera's bands by name, in frame order (a view draws those named red, green and
    # blue as colour); empty: B0..Bn-1
    band_names: tuple[str, ...] = ()
    # also send grain and band correlation per region (btf.fit.dependence): on, it costs no more
    # than the fit and 87 bytes an RGB region (RESULTS.md "dependence"); without it the host
    # cannot reproduce grain or colour (each region's observed levels travel either way)
    dependence: bool = True


@dataclass(frozen=True, slots=True)
class SegmentConfig:
    method: str = "isodata"  # isodata | mask | scene (the fake camera's ground truth)
    mask: Path | None = None
    n_labels: int = 16
    k: int = 4
    min_samples: int = 50
    split_std: float = 20.0
    merge_distance: float = 15.0
    max_merges: int = 2
    iterations: int = 10
    subsample: int = 20_000
    refit_drift: float = 0.25  # refit ISODATA centres when their fit degrades by this fraction; 0: every frame


@dataclass(frozen=True, slots=True)
class SkipConfig:
    min_pixels: int = 64  # labels under this count are neither fitted nor sent
    percentile_precision: float = 0.0  # >0: subsample large regions to this probability precision
    unchanged_tolerance: float = 0.0  # >0: UNCHANGED marker when every percentile moved less
    skip_measured_pose: bool = True


@dataclass(frozen=True, slots=True)
class CameraConfig:
    exposure: CameraValue = CameraValue("hold")  # µs
    gain: CameraValue = CameraValue("hold")  # a multiple (picamera2, fakes) or the V4L2 driver's units
    white_balance: CameraValue = CameraValue("hold")  # "5500K" or "RED,BLUE" gains
    allow_auto: bool = False  # measure even when the camera does not hold the lock (captures flagged)
    reference_label: int = -1  # the mask label of the grey reference card; -1: none
    bracket_limit: float = 0.0  # a region censored past this share gets a shorter exposure; 0: never
    bracket_max: int = 2  # shorter exposures per capture
    bracket_min_ratio: float = 0.0625  # the shortest bracket, as a share of the capture's exposure
    calibrate_margin: float = 0.15  # calibrate exposure: the brightest view's top level below (1 - margin) of full

    def controls(self, standing: CameraSettings | None) -> CameraControls:
        """The controls this asks the camera for; `hold` takes the value from `standing` (None:
        only check the text). ValueError names a value that does not parse."""
        held = hold(standing) if standing is not None else FALLBACK_LOCK
        exposure = held.exposure_us if _is_hold(self.exposure) else self.exposure
        gain = held.gain if _is_hold(self.gain) else self.gain
        if _is_hold(self.white_balance):
            wb: str | float = (f"{held.white_balance_gains[0]!r},{held.white_balance_gains[1]!r}"
                               if held.white_balance_gains is not None else repr(held.white_balance_kelvin))
        else:
            wb = self.white_balance
        return parse_controls(AUTO if exposure is None else exposure, AUTO if gain is None else gain, wb)


def _is_hold(value: str) -> bool:
    return str(value).strip().lower() == "hold"


@dataclass(frozen=True, slots=True)
class Config:
    robot_id: int = 1
    state_dir: Path = Path("state")
    outbox_quota_bytes: int = 64 * 1024 * 1024
    disk_min_free_bytes: int = 16 * 1024 * 1024  # fewer free under state_dir: acquisition pauses
    disk_reserve_bytes: int = 1024 * 1024  # held in state_dir, released for acks and replies on a full disk
    hal: HalConfig = field(default_factory=HalConfig)
    link: LinkConfig = field(default_factory=LinkConfig)
    sweep: SweepConfig = field(default_factory=SweepConfig)
    features: FeatureConfig = field(default_factory=FeatureConfig)
    segment: SegmentConfig = field(default_factory=SegmentConfig)
    skip: SkipConfig = field(default_factory=SkipConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    source: Path | None = None

    @property
    def fake_hal(self) -> HalConfig | None:
        """`hal` when the body is the fake one: the host draws such a robot's frames from it."""
        return self.hal if self.hal.body == "fake" else None


_SECTIONS: dict[str, type] = {"hal": HalConfig, "link": LinkConfig, "sweep": SweepConfig, "features": FeatureConfig,
                               "segment": SegmentConfig, "skip": SkipConfig, "camera": CameraConfig}


def _kind(annotation: Any) -> Any:
    """How `_convert` reads a field of this type: the type, or (item type, length or None) for a tuple."""
    if typing.get_origin(annotation) is tuple:
        args = typing.get_args(annotation)
        return (args[0], None) if args[-1] is Ellipsis else (args[0], len(args))
    if typing.get_origin(annotation) in (types.UnionType, typing.Union):  # `Path | None`: a Path
        (inner,) = [a for a in typing.get_args(annotation) if a is not type(None)]
        return _kind(inner)
    return annotation


def field_types(cls: type) -> dict[str, Any]:
    """Each field's kind, read from the dataclass's own annotations (stated nowhere else)."""
    hints = typing.get_type_hints(cls)
    return {f.name: _kind(hints[f.name]) for f in fields(cls)}


_TYPES: dict[type, dict[str, Any]] = {cls: field_types(cls) for cls in _SECTIONS.values()}
_TOP = {k: v for k, v in field_types(Config).items() if k not in _SECTIONS and k != "source"}


def keys() -> dict[str, Any]:
    """Every key a config file may hold, dotted ("robot_id", "hal.size"), with how it is read: a
    type, or (item type, length or None) for a list."""
    return {**_TOP, **{f"{name}.{k}": kind for name, cls in _SECTIONS.items() for k, kind in _TYPES[cls].items()}}


MAX_FILE = 1 << 20  # a robot's config is a few kilobytes; a file past this is not one


def _convert(name: str, value: Any, kind: Any, base: Path) -> Any:
    if isinstance(kind, tuple):
        item, length = kind
        if not isinstance(value, (list, tuple)):  # a tuple: a list as a packet decodes it (SET)
            raise ConfigError(f"{name} must be a list, got {type(value).__name__}")
        if length is not None and len(value) != length:
            raise ConfigError(f"{name} must have {length} items, got {len(value)}")
        return tuple(_convert(f"{name}[{i}]", v, item, base) for i, v in enumerate(value))
    if kind is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{name} must be true or false, got {_shown(value)}")
        return value
    if kind is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{name} must be an integer, got {_shown(value)}")
        return _within(name, value)
    if kind is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{name} must be a number, got {_shown(value)}")
        if not math.isfinite(value):
            raise ConfigError(f"{name} must be finite, got {value!r}")
        return _within(name, float(value))
    if kind is CameraValue and isinstance(value, (int, float)) and not isinstance(value, bool):
        if not math.isfinite(value):
            raise ConfigError(f"{name} must be finite, got {value!r}")
        return CameraValue(str(value))
    if not isinstance(value, str):
        raise ConfigError(f"{name} must be a string, got {_shown(value)}")
    if kind is Path:
        if "\0" in value:
            raise ConfigError(f"{name} must be a path, without NUL characters")
        path = Path(value).expanduser()
        return path if path.is_absolute() else base / path
    return value


def _within(name: str, value: float) -> Any:
    """`value`, when it lies in the key's BOUNDS (a list's items by the list's key)."""
    lo, hi = BOUNDS.get(name.partition("[")[0], (-math.inf, math.inf))
    if not lo <= value <= hi:
        raise ConfigError(f"{name} must lie in {lo:g}..{hi:g}, got {value:g}" if isinstance(value, float) else
                          f"{name} must lie in {lo}..{hi}, got {value}")
    return value


def _shown(value: Any, key: bool = False) -> str:
    """A value (`key`: a key, unquoted) as one short printable line; a table or a list by its size."""
    if isinstance(value, (dict, list)):
        return f"a table of {len(value)} keys" if isinstance(value, dict) else f"a list of {len(value)} items"
    text = value if key and value.isprintable() else repr(value)
    return text if len(text) <= 60 else f"{text[:57]}..."


def _section(cls: type, table: Any, prefix: str, base: Path) -> Any:
    if not isinstance(table, dict):
        raise ConfigError(f"[{prefix}] must be a table")
    types = _TYPES[cls]
    values = {}
    for key, raw in table.items():
        name = f"{prefix}.{key}"
        if key not in types:
            raise ConfigError(f"unknown key {_shown(name, True)} (known: {', '.join(types)})")
        value = _convert(name, raw, types[key], base)
        if name in CHOICES and value not in CHOICES[name]:
            raise ConfigError(f"{name} must be one of {choices_said(name)}, got {value!r}")
        values[key] = value
    obj = cls(**values)
    # Paths left at their defaults are relative to the config file as well.
    for f in fields(cls):
        if types.get(f.name) is Path and f.name not in values:
            default = getattr(obj, f.name)
            if default is not None and not default.is_absolute():
                obj = replace(obj, **{f.name: base / default})
    return obj


def _replay_against(hal: HalConfig, base: Path) -> HalConfig:
    """A replay camera's relative folder or glob, resolved against the config file's directory."""
    kind, colon, where = hal.camera.partition(":")
    if kind != "replay" or not colon or not where.strip() or Path(where.strip()).expanduser().is_absolute():
        return hal
    return replace(hal, camera=f"replay:{os.path.normpath(base / where.strip())}")


def from_mapping(data: Mapping[str, Any], base: Path = Path(".")) -> Config:
    """Build and check a `Config` from parsed TOML; raises ConfigError on any problem."""
    top: dict[str, Any] = {}
    for key, raw in data.items():
        if key in _SECTIONS:
            top[key] = _section(_SECTIONS[key], raw, key, base)
        elif key in _TOP:
            top[key] = _convert(key, raw, _TOP[key], base)
        else:
            known = ", ".join([*_TOP, *(f"[{s}]" for s in _SECTIONS)])
            raise ConfigError(f"unknown key {_shown(key, True)} (known: {known})")
    for key, cls in _SECTIONS.items():
        if key not in top:  # absent sections still resolve their default paths against base
            top[key] = _section(cls, {}, key, base)
    top["hal"] = _replay_against(top["hal"], base)
    top.setdefault("state_dir", base / "state")
    cfg = Config(**top)
    check(cfg)
    return cfg


def check(cfg: Config) -> None:
    """Every key within its BOUNDS and the keys that depend on each other agreeing; ConfigError
    naming the first that does not (a config built in code passes here what a file passes)."""
    for dotted in BOUNDS:
        section, _, key = dotted.rpartition(".")
        value = getattr(getattr(cfg, section) if section else cfg, key)
        for i, v in enumerate(value) if isinstance(value, tuple) else ((None, value),):
            _within(dotted if i is None else f"{dotted}[{i}]", v)
    s = cfg.sweep
    if not s.azimuths:
        raise ConfigError("sweep.azimuths must name at least one azimuth")
    try:
        SweepPlan(s.start, s.stop, s.step, s.azimuths)
    except ValueError as exc:
        raise ConfigError(f"[sweep]: {exc}") from None
    ln = cfg.link
    if ln.failsafe_s <= ln.heartbeat_s:
        raise ConfigError(f"link.failsafe_s ({ln.failsafe_s:g}) must exceed link.heartbeat_s ({ln.heartbeat_s:g})")
    if ln.node_id == ln.peer_id:
        raise ConfigError(f"link.node_id and link.peer_id must differ, both are {ln.node_id}")
    if not 0.0 <= cfg.skip.percentile_precision < 0.5:
        raise ConfigError(f"skip.percentile_precision must lie in [0, 0.5), got {cfg.skip.percentile_precision:g}")
    if cfg.hal.tracker_remap:
        try:
            AxisRemap.parse(cfg.hal.tracker_remap)
        except ValueError as exc:
            raise ConfigError(f"hal.tracker_remap: {exc}") from None
    sg = cfg.segment
    if sg.method == "mask":
        if sg.mask is None:
            raise ConfigError("segment.method = 'mask' needs segment.mask (a PNG or .npy label file)")
        if not sg.mask.is_file():
            raise ConfigError(f"segment.mask: no such file {sg.mask}")
    if sg.method == "scene" and (cfg.hal.body or os.environ.get("BTF_HAL", "")) != "fake":
        raise ConfigError("segment.method = 'scene' needs hal.body = 'fake' (ground truth)")
    if sg.method == "scene" and cfg.hal.camera.startswith("replay:"):
        raise ConfigError("segment.method = 'scene' needs the fake scene camera; a replay camera has no "
                          "ground truth (use isodata or mask)")
    if cfg.features.space == "auto" and cfg.features.bands:
        raise ConfigError("features.bands names bands of one space; with features.space = 'auto' leave it empty "
                          "(every band of the space chosen)")
    check_band_names(cfg)
    check_camera(cfg)


def check_band_names(cfg: Config) -> None:
    """features.band_names: a raw camera's bands, each a distinct name the MODELS packet can carry."""
    f = cfg.features
    if not f.band_names:
        return
    if f.space not in ("raw", "auto"):
        raise ConfigError(f"features.band_names names a raw camera's bands; with features.space = '{f.space}' "
                          "leave it empty (or set space = 'raw')")
    problem = band_names_problem(f.band_names)
    if problem:
        raise ConfigError(f"features.band_names: {problem}")
    unknown = [b for b in f.bands if b not in f.band_names]
    if unknown:
        raise ConfigError(f"features.bands {unknown} not among features.band_names {list(f.band_names)}")


def check_camera(cfg: Config) -> None:
    c = cfg.camera
    try:
        c.controls(None)
    except ValueError as exc:
        raise ConfigError(f"[camera]: {exc}") from None
    if not 0.0 <= c.bracket_limit < 1.0:
        raise ConfigError(f"camera.bracket_limit must lie in [0, 1), got {c.bracket_limit}")
    if not 0.0 < c.bracket_min_ratio < 1.0:
        raise ConfigError(f"camera.bracket_min_ratio must lie in (0, 1), got {c.bracket_min_ratio:g}")
    if c.bracket_limit and cfg.features.space not in LINEAR_SPACES:
        raise ConfigError(f"camera.bracket_limit needs features.space {' or '.join(LINEAR_SPACES)} (levels that "
                          f"scale with exposure), got {cfg.features.space}")
    if not 0.0 <= c.calibrate_margin < 1.0:
        raise ConfigError(f"camera.calibrate_margin must lie in [0, 1), got {c.calibrate_margin}")
    if c.reference_label >= 0 and cfg.segment.method == "isodata":
        raise ConfigError("camera.reference_label needs segment.method = 'mask' or 'scene' (a label that means "
                          "the card; ISODATA's classes do not)")
    if c.reference_label >= cfg.segment.n_labels:
        raise ConfigError(f"camera.reference_label must be -1 (none) or a label below segment.n_labels, "
                          f"got {c.reference_label}")


def with_value(cfg: Config, dotted: str, value: Any) -> Config:
    """`cfg` with `section.key` set to `value`, read as the config file's value would be
    (paths against the state directory); ConfigError naming the key otherwise."""
    section, _, key = dotted.partition(".")
    cls = _SECTIONS.get(section)
    if cls is None or key not in _TYPES[cls]:
        raise ConfigError(f"unknown key {_shown(dotted, True)}")
    new = _convert(dotted, value, _TYPES[cls][key], cfg.state_dir)
    if dotted in CHOICES and new not in CHOICES[dotted]:
        raise ConfigError(f"{dotted} must be one of {choices_said(dotted)}, got {new!r}")
    part = getattr(cfg, section)
    return replace(cfg, **{section: replace(part, **{key: new})})


def check_key_file(cfg: Config) -> None:
    """The link key must exist before anything moves: no key, no link."""
    path = cfg.link.key_file
    if not path.is_file():
        raise ConfigError(f"link.key_file: no such file {path} (create one with btf-host keygen)")


def load(path: str | Path) -> Config:
    """Read and check the config file; every problem is one ConfigError line."""
    p = Path(path)
    try:
        with p.open("rb") as f:
            raw = f.read(MAX_FILE + 1)
        if len(raw) > MAX_FILE:
            raise ConfigError(f"config file {p} is longer than {MAX_FILE} bytes: not a robot config")
        text = raw.decode("utf-8")
    except FileNotFoundError:
        raise ConfigError(f"config file not found: {p}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read config file {p}: {exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: bad TOML: {' '.join(str(exc).split())}") from None
    except RecursionError:  # tomllib parses nested arrays and tables by recursion
        raise ConfigError(f"{p}: bad TOML: arrays or tables nested too deeply") from None
    if not data:  # a truncated file would run a robot on every default, its link looped to itself
        raise ConfigError(f"{p}: the file sets nothing (empty, or comments only); copy examples/robot.toml "
                          "and edit it")
    try:
        return replace(from_mapping(data, p.resolve().parent), source=p)
    except ConfigError as exc:
        raise ConfigError(f"{p}: {exc}") from None
