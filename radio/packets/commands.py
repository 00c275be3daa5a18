"""The remote-control commands, declared once: each one's name, argument schema, answer
schema, what it does to the arm, its `btf-host cmd` form and help.

The packet decoder checks a COMMAND's arguments against `COMMANDS` (`check_args`) and an ACK's
answer (`check_answer`), the robot dispatches on it (`onboard.dispatch`: `moves_arm`,
`interrupts`, `query`), and `btf-host cmd` builds its subcommands and help from it (`tools.cli.cmd`).
"""
from __future__ import annotations

import enum
import json
from dataclasses import dataclass
from typing import Any, Callable

from radio import FrameError
from radio.packets.base import MAX_ANGLES, MAX_TIME, UINT32, check_extras, want_float, want_int, want_str
from radio.packets.schema import Field, Flag, Float, Int, Maybe, Text


class CommandName(enum.IntEnum):
    PING = 1
    STATUS = 2
    GOTO = 3
    CAPTURE = 4
    SWEEP = 5
    ABORT = 6
    SET = 7
    TORQUE_OFF = 8
    REBOOT_SERVO = 9
    SEND_MASK = 10
    TORQUE_ON = 11


@dataclass(frozen=True, slots=True)
class Arg:
    """One argument: its wire check (untrusted value -> value, FrameError naming it) and its
    command-line form (`--flag`, or a positional name), parser and help."""

    key: str
    check: Callable[[Any], Any]
    cli: str
    parse: Callable[[str], Any] = float
    help: str = ""
    default: Any = None  # given on the command line when the option is left out
    metavar: str | None = None
    limits: tuple[float, float] | None = None  # the range `check` accepts (each value of a list), for a person
    unit: str = ""


@dataclass(frozen=True, slots=True)
class Command:
    name: CommandName
    cli: str  # the `btf-host cmd` subcommand
    help: str
    args: tuple[Arg, ...] = ()
    forms: tuple[frozenset[str], ...] = ()  # accepted key sets; default: every arg
    optional: frozenset[str] = frozenset()  # keys any form may add
    moves_arm: bool = False  # refused while a pose is being measured
    interrupts: bool = False  # ends the pose being measured
    query: bool = False  # reads state only: answered even in failsafe
    answer: tuple[Field, ...] = ()  # the ACK's values (a Maybe one may be left out)
    example: str = ""  # its arguments in a `btf-host cmd` example

    def key_sets(self) -> tuple[frozenset[str], ...]:
        return self.forms or (frozenset(a.key for a in self.args) - self.optional,)

    def arg(self, key: str) -> Arg:
        return next(a for a in self.args if a.key == key)


def floats(text: str) -> list[float]:
    """`90,80,70` on the command line."""
    parts = text.split(",")
    if any(not v.strip() for v in parts[:-1]):  # `80,,60`: a value lost in typing, not skipped
        raise ValueError("an empty value between commas; expected comma-separated numbers")
    try:
        return [float(v) for v in parts if v.strip()]
    except ValueError:
        raise ValueError("expected comma-separated numbers") from None


def json_or_text(text: str) -> Any:
    """A SET value: JSON if it parses (`32`, `true`, `[0, 90]`), else the string itself."""
    try:
        return json.loads(text)
    except ValueError:
        return text


def _angle_list(v: Any, name: str, lo: float, hi: float) -> tuple[float, ...]:
    if type(v) is not list or not 1 <= len(v) <= MAX_ANGLES:
        raise FrameError(f"{name} must be a list of 1..{MAX_ANGLES} angles")
    return tuple(want_float(x, name, lo, hi, allow_int=True) for x in v)


def _angle(key: str, name: str, lo: float, hi: float, help: str, default: Any = None) -> Arg:
    return Arg(key, lambda v: want_float(v, name, lo, hi, allow_int=True), f"--{key}", help=help, default=default,
               limits=(lo, hi), unit="degrees")


def _angles(key: str, lo: float, hi: float, help: str, default: Any = None) -> Arg:
    return Arg(key, lambda v: _angle_list(v, key, lo, hi), f"--{key}", floats, help, default=default,
               limits=(lo, hi), unit="degrees")


C = CommandName
COMMANDS: dict[CommandName, Command] = {c.name: c for c in (
    Command(C.PING, "ping", "check the robot answers (its clock in the reply)", query=True,
            answer=(Field("time", Float(0.0, MAX_TIME), "the robot's clock, seconds since 1970"),)),
    Command(C.STATUS, "status", "the robot's state", query=True),
    Command(C.GOTO, "goto", "move the arm; the reply holds the measured angle", (
        _angle("elevation", "elevation", -90.0, 90.0, "degrees above the horizon, -90..90"),
        _angle("azimuth", "azimuth", -360.0, 360.0, "degrees, -360..360", default=0.0),
    ), moves_arm=True, example="--elevation 60 --azimuth 90",
        answer=(Field("elevation", Float(-90.0, 90.0), "the measured elevation"),
                Field("azimuth", Float(-720.0, 720.0), "the measured azimuth"))),
    Command(C.CAPTURE, "capture", "capture at the current pose", moves_arm=True, answer=(
        Field("seq", Int(0, UINT32), "the capture's number"),
        Field("models", Int(0, 256 * 16), "models it holds"))),
    Command(C.SWEEP, "sweep", "start a sweep: --start/--stop/--step or --elevations", (
        _angle("start", "sweep start", -90.0, 90.0, "first elevation, e.g. 90"),
        _angle("stop", "sweep stop", -90.0, 90.0, "last elevation, e.g. 30"),
        _angle("step", "sweep step", 0.1, 180.0, "elevation step, e.g. 10"),
        _angles("elevations", -90.0, 90.0, "explicit elevations, e.g. 90,80,70"),
        _angles("azimuths", -360.0, 360.0, "e.g. 0,90; left out, the robot's sweep.azimuths"),
    ), forms=(frozenset({"start", "stop", "step"}), frozenset({"elevations"})),
        optional=frozenset({"azimuths"}), interrupts=True, example="--start 90 --stop 30 --step 10 --azimuths 0,90",
        answer=(Field("sweep", Int(0, UINT32), "the new sweep's number"), Field("poses", Int(1, 4096), "its poses"))),
    Command(C.ABORT, "abort", "stop the sweep and hold the arm", interrupts=True,
            answer=(Field("aborted", Flag(), "always true"),)),
    Command(C.SET, "set", "change a run-time setting", (
        Arg("key", lambda v: want_str(v, "setting key", 64, allow_empty=False), "setting", str,
            "section.key, e.g. skip.min_pixels"),
        Arg("value", lambda v: check_extras({"value": v}, "setting")["value"], "value", json_or_text,
            "the value (JSON if it parses, else a string)"),
    ), example="skip.min_pixels 50",
        answer=(Field("set", Text(64), "the key set"),
                Field("camera", Maybe(Text(300)), "what the camera took, for a camera key"),
                Field("locked", Maybe(Flag()), "whether the camera holds its settings, for a camera key"))),
    Command(C.TORQUE_OFF, "torque-off", "stop and release the servos (torque-on brings them back)",
            interrupts=True, answer=(Field("torque", Flag(), "false: released"),)),
    Command(C.TORQUE_ON, "torque-on", "power the servos and hold the arm where it stands", moves_arm=True,
            answer=(Field("torque", Flag(), "true: holding"),)),
    Command(C.REBOOT_SERVO, "reboot-servo", "reboot one servo (clears its alert)", (
        Arg("servo_id", lambda v: want_int(v, "servo id", 0, 252), "--servo-id", int, "the servo's bus id, 0..252",
            limits=(0, 252)),
    ), moves_arm=True, example="--servo-id 2", answer=(Field("rebooted", Int(0, 252), "the servo rebooted"),)),
    Command(C.SEND_MASK, "send-mask", "re-send the label map of a capture", (
        Arg("seq", lambda v: want_int(v, "capture seq", 0, UINT32), "--seq", int, "capture sequence number",
            limits=(0, UINT32)),
    ), example="--seq 12", answer=(Field("queued", Flag(), "whether the map is on its way now"),
                                   Field("seq", Maybe(Int(0, UINT32)), "the capture whose map was queued"),
                                   Field("next_capture", Maybe(Flag()), "the next capture's map will be sent with it"))),
)}


def check_args(name: CommandName, args: dict) -> dict[str, Any]:
    """The command's arguments, each checked; FrameError for a missing, extra or bad one."""
    cmd = COMMANDS[name]
    if any(type(k) is not str for k in args):
        raise FrameError(f"{name.name} argument names must be strings")
    given = set(args)
    forms = cmd.key_sets()
    if not any(given - cmd.optional == form for form in forms):
        extra = f" (+ optional {sorted(cmd.optional)})" if cmd.optional else ""
        want = " or ".join(str(sorted(f)) + extra for f in forms)
        raise FrameError(f"{name.name} takes arguments {want}, got {sorted(given)}")
    return {a.key: a.check(args[a.key]) for a in cmd.args if a.key in given}


def check_answer(name: CommandName, answer: dict) -> dict[str, Any]:
    """An ACK's values for command `name`, each checked; FrameError for a missing, extra or bad one."""
    fields = {f.name: f for f in COMMANDS[name].answer}
    extra = sorted(set(answer) - set(fields))
    if extra:
        raise FrameError(f"the answer to {name.name} has no {', '.join(map(str, extra))}")
    for f in fields.values():
        if f.name not in answer and not isinstance(f.type, Maybe):
            raise FrameError(f"the answer to {name.name} lacks its {f.label}")
    return {k: fields[k].type.check(v, f"{name.name} answer {k}") for k, v in answer.items()}


def fit_answer(name: CommandName, answer: dict) -> dict[str, Any]:
    """An answer as the robot sends it: each declared value fitted into its bounds (a long text cut
    visibly), undeclared ones left for the encoder to refuse."""
    fields = {f.name: f for f in COMMANDS[name].answer}
    return {k: fields[k].type.fit(v) if k in fields else v for k, v in answer.items()}
