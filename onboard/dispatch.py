"""Command dispatch: each COMMAND from the base runs its handler once and gets one answer.

The command table (`radio.packets.commands`) says which commands move the arm (refused while a pose
is being measured), which interrupt the pose, and which are queries (answered even in
failsafe). A handler returns the ACK's extras, or a `Refusal` with its NACK reason; what it
produces (a capture's packets, a new sweep) goes into an `Effect`, committed with the reply
and remembered by command id in the same transaction, so a command the base re-sends after a
restart is answered from memory and never run twice. (A hardware action cannot share the
transaction: a kill between it and the commit repeats GOTO, ABORT and the like, which are
harmless to repeat.)
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Any, Callable

from hal.arm import Arm
from hal.controls import describe
from hal.interfaces import DeviceGone, ServoBus, ViewAngles
from onboard import config as config_mod
from onboard.capture.filing import Captures
from onboard.capture.pipeline import Pipeline, PoseSkipped
from onboard.capture.segmentation import Segmentation
from onboard.config import ConfigError
from onboard.failsafe import Failsafe
from onboard.link import bodies as wire
from onboard.link.outbox import Outbox, OutboxFull, Reply
from onboard.link.service import LinkService
from onboard.link.status import Status, sweep_report
from onboard.state import Interrupted, RuntimeState
from onboard.sweep.control import SweepControl
from onboard.sweep.plan import SweepPlan
from radio import FrameError
from radio import packets as pk
from radio.packets.commands import COMMANDS, CommandName

log = logging.getLogger("btf.robot")
C = CommandName
SETTABLE = {
    "sweep": ("start", "stop", "step", "azimuths", "settle_timeout_s", "retries", "pose_tolerance_deg"),
    "skip": ("min_pixels", "percentile_precision", "unchanged_tolerance", "skip_measured_pose"),
    "camera": ("exposure", "gain", "white_balance", "allow_auto", "reference_label", "bracket_limit",
               "bracket_max", "bracket_min_ratio", "calibrate_margin"),
}


@dataclass(frozen=True, slots=True)
class Refusal:
    """A command refused: the NACK's reason and sentence."""

    reason: pk.Reason
    text: str


@dataclass
class Effect:
    """What a command produced: committed with its reply, then `done` (or `undo` if it failed)."""

    packets: list[tuple[int, bytes]] = field(default_factory=list)
    state: dict[str, str] = field(default_factory=dict)
    reserve: int = 0
    done: Callable[[], None] = lambda: None
    undo: Callable[[], None] = lambda: None


Result = dict | pk.StatusReport | Refusal


# What the operator can do about each refusal, said in the NACK itself.
RECOVERY = {
    pk.Reason.HARDWARE: "status lists the faults; reboot-servo --servo-id ID clears a servo's alert, "
                        "torque-on powers released servos",
    pk.Reason.OUTBOX_FULL: "the base must acknowledge what is queued: is a station receiving?",
    pk.Reason.INTERNAL: "see the robot's log; status lists its errors",
}
TORQUE_IS_OFF = "torque is off (torque-off released the servos): send torque-on, then this command again"


def refusal(exc: Exception) -> Refusal:
    """The NACK for a handler that raised, with what the operator can do about it."""
    if isinstance(exc, (PoseSkipped, DeviceGone)):
        reason, text = pk.Reason.HARDWARE, exc.reason if isinstance(exc, PoseSkipped) else str(exc)
    elif isinstance(exc, Interrupted):
        return Refusal(pk.Reason.BUSY, f"interrupted by {exc}")
    elif isinstance(exc, OutboxFull):
        reason, text = pk.Reason.OUTBOX_FULL, str(exc)
    elif isinstance(exc, (ConfigError, KeyError, ValueError)):  # their messages are written for a person
        return Refusal(pk.Reason.BAD_ARGUMENT, str(exc.args[0]) if isinstance(exc, KeyError) and exc.args else str(exc))
    else:
        reason, text = pk.Reason.INTERNAL, f"{type(exc).__name__}: {exc}"
    return Refusal(reason, f"{text} ({RECOVERY[reason]})")


def _args_text(args: dict) -> str:
    """` key=value ...` for a log line (floats short, long lists cut)."""
    def short(v: Any) -> str:
        if isinstance(v, float):
            return f"{v:.6g}"
        if isinstance(v, (list, tuple)):
            return "[" + ",".join(short(x) for x in v[:8]) + (",..." if len(v) > 8 else "") + "]"
        return str(v)
    text = "".join(f" {k}={wire.iso_time(v) if k == 'time' else short(v)}" for k, v in args.items())
    return text if len(text) <= 160 else text[:157] + "..."


class Dispatcher:
    """Runs the base's commands on the robot's parts: each is given here, none reached through
    another."""

    def __init__(self, state: RuntimeState, outbox: Outbox, link: LinkService, failsafe: Failsafe,
                 status: Status, pipeline: Pipeline, captures: Captures, sweep: SweepControl, arm: Arm,
                 servo_bus: ServoBus, segmenter: Segmentation, wall: Callable[[], float]) -> None:
        self.state, self.outbox, self.link, self.failsafe = state, outbox, link, failsafe
        self.status_report, self.pipeline, self.captures, self.sweep_control = status, pipeline, captures, sweep
        self.arm, self.servo_bus, self.segmenter, self.wall = arm, servo_bus, segmenter, wall
        self.handlers: dict[CommandName, Callable[[dict, Effect], Result]] = {
            C.PING: self.ping, C.STATUS: self.status, C.GOTO: self.goto, C.CAPTURE: self.capture,
            C.SWEEP: self.sweep, C.ABORT: self.abort, C.SET: self.set, C.TORQUE_OFF: self.torque_off,
            C.REBOOT_SERVO: self.reboot_servo, C.SEND_MASK: self.send_mask, C.TORQUE_ON: self.torque_on,
        }
        missing = set(COMMANDS) - set(self.handlers)
        if missing:
            raise RuntimeError(f"commands without a handler: {sorted(c.name for c in missing)}")

    def on_body(self, body: bytes) -> None:
        """A message from the base: a command is answered (once), anything else ignored."""
        try:
            cmd = pk.decode(body)
        except FrameError as exc:
            self.state.errors.append(f"bad packet from base: {exc}")
            return
        if not isinstance(cmd, pk.CommandPacket):
            return  # not a command (e.g. the base's own status): nothing to answer
        said = f"command {cmd.command_id} {cmd.name.name}{_args_text(cmd.args)}"
        known = self.outbox.remembered(cmd.command_id)
        if known is not None:  # run before: answer again, unless that answer is still queued
            if self.outbox.kind_of(known.msg_id) is None:
                self.link.queue(known.kind, known.body)
            log.info("%s: sent again, answered from memory", said)
            return
        effect = Effect()
        result = self.run(cmd.name, dict(cmd.args), effect)
        if isinstance(result, Refusal):
            answer = wire.reply_body(cmd.command_id, False, result.text, reason=result.reason)
            effect = Effect()  # a refused command produced nothing
            log.info("%s: NACK %s: %s", said, result.reason.name, result.text)
        else:
            answer = wire.reply_body(cmd.command_id, True, cmd.name.name, result)
            # a query's answer is the robot's state, which STATUS carries: the line stays short
            log.info("%s: ACK%s", said, "" if COMMANDS[cmd.name].query else _args_text(result))
        stands = self._answer(cmd.command_id, answer, effect, COMMANDS[cmd.name].query)
        if stands and not isinstance(result, Refusal) and COMMANDS[cmd.name].interrupts:
            self.state.interrupt_work(cmd.name.name)  # the pose being measured ends at the next service

    def run(self, name: CommandName, args: dict, effect: Effect | None = None) -> Result:
        """Run one command: the ACK's extras, or a Refusal. What it produces goes into `effect`."""
        effect = Effect() if effect is None else effect
        spec, state = COMMANDS[name], self.state
        if not spec.query and self.failsafe.active:
            return Refusal(pk.Reason.BUSY, "failsafe active: the link was lost; it clears when the link is back up")
        if spec.moves_arm and state.busy:
            return Refusal(pk.Reason.BUSY, "busy: the arm is measuring a pose; send it again, or ABORT first")
        if name in (C.GOTO, C.SWEEP) and not state.torque:
            return Refusal(pk.Reason.TORQUE_OFF, TORQUE_IS_OFF)
        try:
            return self.handlers[name](args, effect)
        except Exception as exc:  # a command that fails is answered, never fatal
            return refusal(exc)

    def _answer(self, command_id: int, answer: tuple[int, bytes], effect: Effect, query: bool = False) -> bool:
        """Commit a reply with its command's effect, remembered by id; whether the effect stands."""
        try:
            self.outbox.commit(effect.packets, effect.state, reserve=effect.reserve,
                             reply=Reply(command_id, *answer))
        except OutboxFull as exc:
            effect.undo()
            if not (effect.packets or effect.state):
                if query:  # a query is harmless to answer again: straight on the link
                    self.link.send_direct(*answer)
                else:
                    self.state.paused_reason = str(exc)  # not even the reply fits: a retry finds room later
                return False
            # What the command produced does not fit: refuse it instead, and say why.
            nack = wire.reply_body(command_id, False, str(exc), reason=pk.Reason.OUTBOX_FULL)
            try:
                self.outbox.commit(reply=Reply(command_id, *nack))
            except OutboxFull as full:
                self.state.paused_reason = str(full)
            return False
        self.state.paused_reason = ""
        effect.done()
        return True

    # -- the handlers, one per command -----------------------------------------------------
    def ping(self, args: dict, effect: Effect) -> Result:
        return {"time": self.wall()}

    def status(self, args: dict, effect: Effect) -> Result:
        return self.status_report.report()

    def goto(self, args: dict, effect: Effect) -> Result:
        view = ViewAngles(float(args["elevation"]), float(args.get("azimuth", 0.0)))
        pipeline = self.pipeline
        with self.state.arm_work():
            pipeline.move(view)
            m = pipeline.measure_view()
        return {"elevation": m.elevation, "azimuth": m.azimuth}

    def capture(self, args: dict, effect: Effect) -> Result:
        with self.state.arm_work():
            measured = self.pipeline.measure_view()
            cap = self.pipeline.shoot(measured, measured)
        seq, effect.packets, effect.state = self.captures.packets(cap)
        effect.reserve = self.sweep_control.reserve
        effect.done = lambda: self.captures.filed(cap, seq)
        effect.undo = lambda: self.pipeline.rollback(cap)
        return {"seq": seq, "models": len(cap.results)}

    def sweep(self, args: dict, effect: Effect) -> Result:
        # The packet decoder has checked every argument's type and range.
        sweep = self.sweep_control
        azs = tuple(float(a) for a in args.get("azimuths", self.state.cfg.sweep.azimuths))
        if "elevations" in args:
            els = tuple(float(e) for e in args["elevations"])
            plan = SweepPlan(els[0], els[-1], 1.0, azs, els)
        else:  # SweepPlan bounds the pose count before any list is built
            plan = SweepPlan(float(args["start"]), float(args["stop"]), float(args["step"]), azs)
        p = sweep.sweeps.next_sweep(plan)
        effect.state = sweep.sweeps.entry(p)  # saved with the reply, in one commit
        effect.done = lambda: sweep.begin(p)
        return {"sweep": p.sweep_id, "poses": p.plan.count}

    def abort(self, args: dict, effect: Effect) -> Result:
        self.sweep_control.stop()
        self.arm.stop_and_hold()
        return {"aborted": True}

    def set(self, args: dict, effect: Effect) -> Result:
        camera = str(args["key"]).startswith("camera.") and self.pipeline.lock is not None
        if camera and self.state.busy:  # the pose's frames are being taken, in the worker
            return Refusal(pk.Reason.BUSY, "busy: the camera is taking a pose's frames; send it again")
        self.set_keys({args["key"]: args["value"]})
        if camera:
            granted = self.pipeline.lock_camera()  # now, so the answer says what the camera took
            return {"set": args["key"], "camera": describe(granted), "locked": granted.locked}
        return {"set": args["key"]}

    def torque_off(self, args: dict, effect: Effect) -> Result:
        p = self.state.progress
        running = p is not None and p.active and not p.done
        self.sweep_control.stop()
        self.state.torque = False  # even if the bus fails below: the servos may be limp
        self.arm.torque_off()
        if running:  # said, or an operator reads a sweep that ended for no reason
            text = (f"torque-off ended sweep {p.sweep_id} at pose {p.next_index + 1} of {p.plan.count}; "
                    "after torque-on, sweep starts a new one")
            log.info("%s", text)
            self.status_report.send(text, pk.StatusReport(sweep=sweep_report(p, active=False)))
        return {"torque": False}

    def torque_on(self, args: dict, effect: Effect) -> Result:
        self.pipeline.retry("torque on", self.arm.enable)
        self.state.torque = True
        return {"torque": True}

    def reboot_servo(self, args: dict, effect: Effect) -> Result:
        sid = int(args["servo_id"])
        self.servo_bus.reboot(sid)
        return {"rebooted": sid}

    def send_mask(self, args: dict, effect: Effect) -> Result:
        """The label map of capture `seq`: the robot keeps its last capture's only (the host
        stores every MASK sent); the next capture's is sent with it."""
        caps, seq = self.captures, int(args["seq"])
        if seq == caps.seq.peek() and caps.last_labels is None:
            self.segmenter.force_send()
            return {"queued": False, "next_capture": True}
        packet = caps.mask_packet(seq) if seq == caps.last_seq else None
        if packet is None:
            kept = (f"its last capture's only (seq {caps.last_seq})" if caps.last_labels is not None
                    else f"none since it started; the next capture is seq {caps.seq.peek()}")
            return Refusal(pk.Reason.NOT_FOUND, f"capture {seq}'s label map is not kept: the robot keeps "
                           f"{kept}; the host stores every MASK it received under capture-SEQ")
        effect.packets = [packet]
        return {"queued": True, "seq": seq}

    def set_keys(self, settings: dict[str, Any]) -> None:
        """SET section.key = value for the keys that may change at run time."""
        state = self.state
        cfg = state.cfg
        for dotted, value in settings.items():
            section, _, key = str(dotted).partition(".")
            if key not in SETTABLE.get(section, ()):
                allowed = ", ".join(f"{s}.{k}" for s, ks in SETTABLE.items() for k in ks)
                raise ConfigError(f"{dotted} cannot be set at run time (settable: {allowed})")
            cfg = config_mod.with_value(cfg, str(dotted), value)
        config_mod.check(cfg)
        state.cfg = cfg  # the one configuration in force: the pipeline reads it from here
