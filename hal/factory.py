"""The one place that picks a body for every device: real, emulated or fake.

The body comes from the config mapping's `body` (the keys of `onboard.config.HalConfig`)
or else from `BTF_HAL`; with neither, `build_hal` refuses: a robot must never run on
fakes by accident. The drivers that need OpenCV or dynamixel-sdk are imported only when
their body is chosen, so a machine without a camera stack can still build the fakes. What it builds is a `hal.Hal`.
"""
from __future__ import annotations

import dataclasses
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any, Callable, Mapping

from hal.arm import Arm, ArmCalibration, JointCalibration, load_arm_fit
from hal.bno055 import AxisRemap, BNO055Tracker
from hal.devices import Hal
from hal.emulators.bno055 import EmulatedSMBus
from hal.emulators.dxl import DxlEmulator
from hal.fakes import Faults
from hal.fakes.camera import FORMATS as FAKE_FORMATS
from hal.fakes.camera import FakeCamera
from hal.fakes.servo import FakeServoBus
from hal.fakes.tracker import FakeTracker
from hal.interfaces import Body, Camera, HalError, Orientation, ViewAngles
from hal.orientation import MOUNTS
from hal.scene import SCENES, render

ENV_VAR = "BTF_HAL"
REPLAY = "replay:"  # hal.camera = "replay:DIR_OR_GLOB": frames from image files (hal.replay)
# Views the emulated camera's image sequence is rendered at (it replays them in order).
SEQUENCE_VIEWS = (ViewAngles(90.0), ViewAngles(60.0), ViewAngles(30.0))


class HalConfigError(HalError):
    """The HAL cannot be built from this configuration; the message says which key."""


def _options(config: Mapping[str, Any] | Any | None) -> dict[str, Any]:
    if config is None:
        return {}
    if dataclasses.is_dataclass(config) and not isinstance(config, type):
        return {f.name: getattr(config, f.name) for f in dataclasses.fields(config)}
    if isinstance(config, Mapping):
        return dict(config)
    raise HalConfigError(f"HAL configuration must be a mapping, got {type(config).__name__}")


def choose_body(config: Mapping[str, Any] | None, env: Mapping[str, str]) -> Body:
    value = (config or {}).get("body") or env.get(ENV_VAR, "")
    if not value:
        raise HalConfigError(f"no HAL body chosen: set hal.body in the config or {ENV_VAR}=real|emulated|fake")
    try:
        return Body(str(value).strip().lower())
    except ValueError:
        raise HalConfigError(f"unknown HAL body {value!r}; choose real, emulated or fake") from None


def arm_calibration(options: Mapping[str, Any]) -> ArmCalibration:
    """`arm = {yaw = {servo_id, min_deg, max_deg, offset_deg, sign, corrections}, tilt = {...}}`."""
    raw = options.get("arm")
    if not raw:
        return ArmCalibration()
    try:
        joints = {}
        for name in ("yaw", "tilt"):
            j = dict(raw[name])
            j["corrections"] = tuple((float(a), float(b)) for a, b in j.get("corrections", ()))
            joints[name] = JointCalibration(**j)
        extra = {k: float(raw[k]) for k in ("tolerance_deg", "poll_s") if k in raw}
        return ArmCalibration(joints["yaw"], joints["tilt"], **extra)
    except (KeyError, TypeError, ValueError) as exc:
        raise HalConfigError(f"bad arm calibration in the HAL config: {exc}") from None


JOINTS = ("yaw", "tilt")
# Options that build a deliberately faulty fake world; a real robot has its faults already.
FAKE_WORLD = ("fake_joint_offsets", "fake_joint_reversed", "fake_tracker_mount", "fake_tracker_bias_deg",
              "camera_honours_lock")


def tracker_remap(options: Mapping[str, Any]) -> AxisRemap | None:
    """`tracker_remap = "P4"` or `"0x24/0x03"`: the BNO055 axis remap to write at start."""
    text = str(options.get("tracker_remap") or "")
    try:
        return AxisRemap.parse(text) if text else None
    except ValueError as exc:
        raise HalConfigError(f"hal tracker_remap: {exc}") from None


def world_calibration(cal: ArmCalibration, options: Mapping[str, Any]) -> ArmCalibration:
    """How the fake or emulated arm is really built: the configured joints with the
    deliberate faults `fake_joint_offsets` ({joint: degrees}) and `fake_joint_reversed` ([joint])."""
    offsets = dict(options.get("fake_joint_offsets") or {})
    reversed_ = set(options.get("fake_joint_reversed") or ())
    unknown = (set(offsets) | reversed_) - set(JOINTS)
    if unknown:
        raise HalConfigError(f"unknown joint {sorted(unknown)[0]!r} in the fake world; the joints are yaw and tilt")
    joints = {}
    for name in JOINTS:
        j = getattr(cal, name)
        try:
            extra = float(offsets.get(name, 0.0))
        except (TypeError, ValueError):
            raise HalConfigError(f"fake_joint_offsets.{name} must be degrees, got {offsets[name]!r}") from None
        joints[name] = dataclasses.replace(j, offset_deg=j.offset_deg + extra,
                                           sign=-j.sign if name in reversed_ else j.sign)
    return dataclasses.replace(cal, **joints)


def world_view(world: ArmCalibration, servo_deg: Mapping[int, float]) -> ViewAngles:
    """Where the camera really looks with the servos at these angles; a tilt past straight
    down looks from the other side."""
    yaw = world.yaw.joint_deg(servo_deg[world.yaw.servo_id])
    tilt = world.tilt.joint_deg(servo_deg[world.tilt.servo_id])
    if tilt < 0.0:
        return ViewAngles(elevation=90.0 + tilt, azimuth=(yaw + 180.0) % 360.0)
    return ViewAngles(elevation=90.0 - tilt, azimuth=yaw % 360.0)


def _tracker_mount(options: Mapping[str, Any]) -> Any:
    name = str(options.get("fake_tracker_mount") or "upright")
    if name in MOUNTS:
        return None if name == "upright" else MOUNTS[name]
    try:  # a placement name: mounted the way that placement would correct
        return AxisRemap.parse(name).matrix
    except ValueError:
        raise HalConfigError(f"unknown fake_tracker_mount {name!r}; choose from {', '.join(MOUNTS)} "
                             "or a placement P0..P7") from None


def build_hal(config: Mapping[str, Any] | Any | None = None, env: Mapping[str, str] | None = None,
              state_dir: str | Path | None = None) -> Hal:
    """Build every device for the chosen body. Keys (all optional except the body):
    body, scene, size, fault_rate, fault_seed, servo_port, servo_baud, tracker_bus,
    camera, seed, arm, servo_latency_ms, tracker_remap, reference (the fake scenes hold the
    grey reference card), and for fake and emulated bodies the deliberate faults in
    `FAKE_WORLD` and `camera = "replay:DIR_OR_GLOB"` with `replay_loop` (`hal.replay`).
    With `state_dir`, the arm calibration stored there is applied."""
    options = _options(config)
    body = choose_body(options, os.environ if env is None else env)
    size = tuple(int(v) for v in options.get("size", (120, 160)))
    if len(size) != 2 or min(size) < 8:
        raise HalConfigError(f"hal size must be (height, width), each at least 8, got {size}")
    calibration = arm_calibration(options)
    world = world_calibration(calibration, options)  # the arm as built: a calibration does not move it
    if state_dir is not None:
        try:
            fit = load_arm_fit(state_dir)
        except HalError as exc:
            raise HalConfigError(str(exc)) from None
        if fit is not None:
            calibration = calibration.with_fit(fit)
    tracker_remap(options)
    if body is Body.REAL and any(options.get(k) is not None for k in FAKE_WORLD):
        raise HalConfigError(f"{', '.join(k for k in FAKE_WORLD if options.get(k) is not None)}: "
                             "only fake and emulated bodies take deliberate faults")
    if body is Body.REAL and str(options.get("camera") or "").startswith(REPLAY):
        raise HalConfigError("hal.camera replay: plays files under the fake and emulated bodies only "
                             "(a real arm would file recorded frames under its live poses)")
    replay = _replay(options, size)
    fmt = pixel_format(options, body, replay is not None)
    if body is not Body.REAL:
        if options.get("scene", "black") not in SCENES:
            raise HalConfigError(f"unknown scene {options['scene']!r}; choose from {', '.join(SCENES)}")
    builder = {Body.FAKE: _fake, Body.EMULATED: _emulated, Body.REAL: _real}[body]
    try:
        return dataclasses.replace(builder(options, calibration, size, world, replay), pixel_format=fmt)
    except (TypeError, ValueError) as exc:  # a device constructor refused an option
        raise HalConfigError(f"{body.value} HAL: {exc}") from None


def pixel_format(options: Mapping[str, Any], body: Body, replay: bool) -> str:
    """`pixel_format`: the four-character code the camera opens in ("" is BGR3), checked against
    what the body's camera can give; a real device answers for itself when it opens."""
    text = str(options.get("pixel_format") or "")
    if not text:
        return "BGR3"
    if len(text) != 4 or not text.isascii():
        raise HalConfigError(f"hal.pixel_format must be a four-character code such as 'BGR3', 'Y16 ' or 'MSP6', "
                             f"got {text!r}")
    if replay:
        raise HalConfigError(f"hal.pixel_format {text!r}: the replay camera plays its files' own bands; "
                             "leave pixel_format unset")
    if body is Body.FAKE:
        known = [f for formats in FAKE_FORMATS.values() for f in formats]
        if text not in known:
            raise HalConfigError(f"hal.pixel_format {text!r}: the fake camera gives {', '.join(known)} "
                                 "(MSP6: five spectral bands and thermal, 16-bit)")
    elif body is Body.EMULATED and text != "BGR3":
        raise HalConfigError(f"hal.pixel_format {text!r}: the emulated camera replays 8-bit RGB renders (BGR3); "
                             "the fake body's camera gives MSP6")
    return text


def _replay(options: Mapping[str, Any], size: tuple[int, int]) -> Camera | None:
    """The camera `camera = "replay:DIR_OR_GLOB"` asks for, its files checked; None for another camera."""
    text = str(options.get("camera") or "")
    if not text.startswith(REPLAY):
        return None
    from hal.replay import ReplayCamera, replay_files  # OpenCV reads the files: loaded only for them

    loop = options.get("replay_loop", False)
    if not isinstance(loop, bool):
        raise HalConfigError(f"hal.replay_loop must be true or false, got {loop!r}")
    try:
        camera = ReplayCamera(replay_files(text[len(REPLAY):].strip()), loop=loop)
    except (HalError, ValueError) as exc:
        raise HalConfigError(f"hal.camera {text!r}: {exc}") from None
    if camera.size != size:
        h, w = camera.size
        raise HalConfigError(f"hal.camera {text!r}: the files are {w}x{h} (first: {camera.files[0].name}), "
                             f"hal.size is {list(size)}; set hal.size = [{h}, {w}] (frames are played at "
                             "their own size)")
    return camera


def _faults(options: Mapping[str, Any], kinds: frozenset[str] = frozenset()) -> Faults:
    try:
        return Faults(rate=float(options.get("fault_rate", 0.0)), seed=int(options.get("fault_seed", 0)), kinds=kinds)
    except ValueError as exc:
        raise HalConfigError(f"hal fault_rate: {exc}") from None


def _fake(options: Mapping[str, Any], cal: ArmCalibration, size: tuple[int, int], world: ArmCalibration,
          replay: Camera | None) -> Hal:
    seed = int(options.get("seed", 0))
    start = cal.tilt.servo_deg(0.0)  # parked looking straight down
    bus = FakeServoBus(tuple(cal.servo_ids), faults=_faults(options), start_deg={cal.tilt.servo_id: start,
                                                                                 cal.yaw.servo_id: cal.yaw.servo_deg(0.0)})
    arm = Arm(bus, cal)

    def true_view() -> ViewAngles:
        return world_view(world, bus.true_positions())

    try:
        bias = float(options.get("fake_tracker_bias_deg", 0.5))
    except (TypeError, ValueError):
        raise HalConfigError(f"fake_tracker_bias_deg must be degrees, got {options['fake_tracker_bias_deg']!r}") from None
    tracker = FakeTracker(true_view, faults=_faults(options), seed=seed, bias_deg=bias,
                          mount=_tracker_mount(options), remap=tracker_remap(options))
    if replay is not None:  # frames from files: no scene, so no ground truth
        return Hal(Body.FAKE, bus, arm, tracker, replay, size)
    fmt = pixel_format(options, Body.FAKE, False)
    bands = next(name for name, formats in FAKE_FORMATS.items() if fmt in formats)
    camera = FakeCamera(str(options.get("scene", "black")), true_view, seed=seed, size=size, bands=bands,
                        faults=_faults(options), reference=bool(options.get("reference", False)),
                        honours_lock=bool(options.get("camera_honours_lock", True)))
    return Hal(Body.FAKE, bus, arm, tracker, camera, size, ground_truth=camera)


def _emulated(options: Mapping[str, Any], cal: ArmCalibration, size: tuple[int, int],
              world: ArmCalibration, replay: Camera | None) -> Hal:
    from hal.dynamixel import DynamixelServoBus  # dynamixel-sdk: only for the bodies that use it

    mount = _tracker_mount(options)
    emulator = DxlEmulator(tuple(cal.servo_ids), faults=_faults(options, frozenset({"drop", "corrupt"})))
    for sid in cal.servo_ids:  # park as the fake does: straight down
        joint = cal.tilt if sid == cal.tilt.servo_id else cal.yaw
        emulator.servos[sid].position = 2048.0 + joint.servo_deg(0.0) * 4096.0 / 360.0
    cleanup: list[Callable[[], None]] = [emulator.close]
    try:
        bus = DynamixelServoBus(emulator.port, latency_ms=float(options.get("servo_latency_ms", 16.0)))
        arm = Arm(bus, cal)

        def orientation() -> Orientation:
            view = world_view(world, {sid: emulator.position_deg(sid) for sid in cal.servo_ids})
            return Orientation(heading=view.azimuth, roll=0.0, pitch=-view.elevation)

        tracker = BNO055Tracker(EmulatedSMBus(orientation_source=orientation, seed=int(options.get("fault_seed", 0)),
                                              nack_rate=float(options.get("fault_rate", 0.0)), mount=mount),
                                remap=tracker_remap(options))
        camera = replay or _sequence_camera(options, size, cleanup)
    except BaseException:
        for closer in reversed(cleanup):
            closer()
        raise
    return Hal(Body.EMULATED, bus, arm, tracker, camera, size, tuple(cleanup))


def _sequence_camera(options: Mapping[str, Any], size: tuple[int, int], cleanup: list[Callable[[], None]]) -> Camera:
    """OpenCV replaying the scene's renders through emulated V4L2 controls; its folder goes at close."""
    from hal.emulators.camera import SequenceCamera, V4L2Controls  # OpenCV: only for the emulated body

    frames = Path(tempfile.mkdtemp(prefix="btf-frames-"))
    cleanup.append(lambda: shutil.rmtree(frames, ignore_errors=True))
    _write_sequence(frames, str(options.get("scene", "black")), size, int(options.get("seed", 0)),
                    bool(options.get("reference", False)))
    honours_lock = bool(options.get("camera_honours_lock", True))
    return SequenceCamera(str(frames), controls=V4L2Controls(honours_lock=honours_lock))


def _write_sequence(directory: Path, scene: str, size: tuple[int, int], seed: int, reference: bool) -> None:
    """Frames the scene renderer draws, saved as an image sequence for OpenCV to replay."""
    from hal.emulators.camera import write_sequence  # OpenCV: only for the emulated body

    write_sequence(directory, (render(scene, view, size=size, seed=seed, reference=reference).image
                               for view in SEQUENCE_VIEWS))


def _real(options: Mapping[str, Any], cal: ArmCalibration, size: tuple[int, int], world: ArmCalibration,
          replay: Camera | None = None) -> Hal:  # `replay` is None: build_hal refuses files on the real body
    from hal.dynamixel import DynamixelServoBus  # dynamixel-sdk: only for the bodies that use it

    port = str(options.get("servo_port", ""))
    if not port:
        raise HalConfigError("hal servo_port is required for the real body (e.g. /dev/ttyUSB0)")
    bus = DynamixelServoBus(port, int(options.get("servo_baud", 1_000_000)),
                            latency_ms=float(options.get("servo_latency_ms", 16.0)))
    try:
        tracker = BNO055Tracker.open(int(options.get("tracker_bus", 1)), 0x28, remap=tracker_remap(options))
        camera = _real_camera(str(options.get("camera", "")), pixel_format(options, Body.REAL, False))
    except BaseException:
        bus.close()
        raise
    return Hal(Body.REAL, bus, Arm(bus, cal), tracker, camera, size)


def _real_camera(device: str, fmt: str = "BGR3") -> Camera:
    """`camera = "picamera2"`, a V4L2 index or path; unset: picamera2 when importable, else device 0.
    A format picamera2 cannot give is refused here: at open it would read as a camera not there yet."""
    from hal.camera import PICAMERA2_FORMATS, OpenCVCamera, PiCamera2Camera  # OpenCV: only for the real body

    if device == "picamera2" or (not device and _picamera2_importable()):
        if fmt not in PICAMERA2_FORMATS:
            raise HalConfigError(f"hal.pixel_format {fmt!r}: picamera2 gives {', '.join(PICAMERA2_FORMATS)}; "
                                 "a V4L2 camera (hal.camera = its device) takes other formats")
        return PiCamera2Camera()
    return OpenCVCamera(int(device) if device.isdigit() else (device or 0))


def _picamera2_importable() -> bool:
    try:
        import picamera2  # noqa: F401 - only the Raspberry Pi camera stack has it
    except ImportError:
        return False
    return True
