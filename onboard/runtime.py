"""The robot's main loop: sweeps, remote-control commands, the outbox and the failsafe.

One thread turns `step()`: service the link, answer commands, check the failsafe,
measure the next pose of an active sweep, and hand outbox rows to the link. Every
packet goes through the outbox first and leaves it only when the base acknowledged it.
Faults become retries, then a skipped pose with its reason; no exception ends the loop.

Failsafe: once the link has been up, a LinkDown (no heartbeat from the base for
`link.failsafe_s`) stops the arm where it is and pauses the sweep; when the link
returns the robot sends a STATUS reporting the failsafe and resumes what it was doing.
Before the base was ever heard, an autonomous sweep runs and its packets wait in the outbox.

Exactly once: a pose's packets, the sweep progress that marks it done and the next
capture sequence are one outbox transaction (`Outbox.commit`), so a kill at any instant
leaves the pose queued and done, or neither; the host drops re-sent rows by (robot, seq).
A command's reply is committed with what it produced (a capture's packets, a new sweep)
and remembered by command id in the same transaction, so a command the base re-sends
after a restart is answered from memory and never run twice. (A hardware action cannot
share the transaction: a kill between it and the commit repeats GOTO, ABORT and the like,
which are harmless to repeat.)
"""
from __future__ import annotations

import copy
import enum
import json
import time
from collections import deque
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

from hal.interfaces import ViewAngles
from onboard import capture as wire
from onboard import config as config_mod
from onboard.capture import Capture, Pipeline, PoseSkipped
from onboard.config import Config, ConfigError
from onboard.outbox import Outbox, OutboxFull, Reply
from onboard.sweep import Boot, SweepPlan, SweepProgress, SweepStore
from onboard.transport import Transport
from onboard.watchdog import Notifier
from radio import FrameError
from radio import packet as pk
from radio.link import Acked, Delivered, LinkDown, LinkUp, QueueFull

# -- the runtime -----------------------------------------------------------------------


class Mode(enum.StrEnum):
    IDLE = "idle"
    SWEEPING = "sweeping"
    FAILSAFE = "failsafe"


PCA_KEY = "pca"  # the scene's basis, in the outbox state with the packet that carries it
SETTABLE = {
    "sweep": ("start", "stop", "step", "azimuths", "settle_timeout_s", "retries", "pose_tolerance_deg"),
    "skip": ("min_pixels", "percentile_precision", "unchanged_tolerance", "skip_measured_pose"),
}


class Interrupted(Exception):
    """ABORT, TORQUE_OFF, a new SWEEP or the failsafe took the arm while it was working."""


@dataclass
class Effect:
    """What a command produced: committed with its reply, then `done` (or `undo` if it failed)."""

    packets: list[tuple[int, bytes]] = field(default_factory=list)
    state: dict[str, str] = field(default_factory=dict)
    reserve: int = 0
    done: Callable[[], None] = lambda: None
    undo: Callable[[], None] = lambda: None


ARM_COMMANDS = ("GOTO", "CAPTURE", "REBOOT_SERVO")  # refused while a pose is being measured
INTERRUPTING = ("ABORT", "TORQUE_OFF", "SWEEP")  # end the pose being measured


class Runtime:
    def __init__(
        self,
        cfg: Config,
        hal: Any,
        transport: Transport,
        segmenter: Callable,
        outbox: Outbox | None = None,
        clock: Callable[[], float] = time.monotonic,
        wall: Callable[[], float] = time.time,
        sleep: Callable[[float], None] = time.sleep,
        notifier: Notifier | None = None,
        new_sweep: bool = False,
    ) -> None:
        self.cfg = cfg
        self.hal = hal
        self.transport = transport
        self.clock, self.wall, self.sleep = clock, wall, sleep
        cfg.state_dir.mkdir(parents=True, exist_ok=True)
        # `is None`, not `or`: an empty outbox is falsy (it has a length).
        self.outbox = outbox if outbox is not None else Outbox(cfg.state_dir / "outbox.sqlite",
                                                               cfg.outbox_quota_bytes)
        self.sweeps = SweepStore(self.outbox, legacy_dir=cfg.state_dir)
        self.new_sweep = new_sweep
        self.pipeline = Pipeline(cfg, hal, segmenter, pump=self._pump, sleep=sleep)
        self.pipeline.pca = _read_pca(self.outbox.state(PCA_KEY), cfg.state_dir / "pca.json")
        self.notifier = notifier if notifier is not None else Notifier(address="")
        self.mode = Mode.IDLE
        self.progress: SweepProgress | None = None
        self.link_up = False
        self.ever_up = False
        self.failsafe_events: list[dict] = []
        self._resume_mode = Mode.IDLE
        self._in_flight: set[int] = set()
        self._last_sent = 0
        self._seq = wire.SeqCounter(self.outbox, legacy=cfg.state_dir / "seq")
        self._full_until_ack = False  # a commit hit the quota: measure again after an ACK
        self._last_labels = None
        self._last_models: dict[tuple[int, int], int] = {}  # pose -> seq of its last MODELS
        self.pose: ViewAngles | None = None
        self.errors: deque[str] = deque(maxlen=16)
        self.paused_reason = ""
        # Commands are answered while the arm works (the pipeline pumps the link), so an
        # interrupting command or the failsafe must end that work, not be undone by it.
        self._busy = False
        self._interrupt = ""
        # Captures stop short of the quota, so replies and STATUS still fit when they do.
        self._reserve = self.outbox.quota_bytes // 8

    # -- plumbing --------------------------------------------------------------------

    def queue(self, kind: int, body: bytes) -> int | None:
        """Store a packet in the outbox (before any send); None when the outbox is full."""
        try:
            msg_id = self.outbox.put(kind, body)
            self.paused_reason = ""
            return msg_id
        except OutboxFull as exc:
            self.paused_reason = str(exc)
            return None

    def service(self) -> None:
        """Read link events, answer commands, feed the link from the outbox."""
        now = self.clock()
        for event in self.transport.read(now):
            if isinstance(event, Acked):
                self._in_flight.discard(event.msg_id)
                if self.outbox.ack(event.msg_id):
                    self._full_until_ack = False
            elif isinstance(event, (LinkUp, LinkDown)):
                self._link_changed(isinstance(event, LinkUp))
            elif isinstance(event, Delivered):
                self._on_body(event.payload)
        self._flush(now)
        self.transport.write(now)  # after the replies were queued: they leave with the acks
        self.notifier.kick()

    def _flush(self, now: float) -> None:
        room = self.cfg.link.window - len(self._in_flight)
        if room <= 0:
            return
        for msg_id, body in self.outbox.pending(limit=room, after=self._last_sent):
            try:
                self.transport.send(body, msg_id=msg_id, now=now)
            except QueueFull:  # the link holds enough already: offer the rest later
                return
            self._in_flight.add(msg_id)
            self._last_sent = msg_id

    def _link_changed(self, up: bool) -> None:
        if up == self.link_up:
            return
        self.link_up = up
        if up:
            self.ever_up = True
            # Nothing to re-offer: the link holds every message until it is acknowledged,
            # across link loss (a new session re-sends it). Offering one twice was an error.
            if self.mode is Mode.FAILSAFE:
                event = self.failsafe_events[-1]
                event["until"] = self.wall()
                self.mode = self._resume_mode
                self.send_status("failsafe: link lost, arm held", {"failsafe_since": event["since"], "failsafe_until": event["until"]})
        elif self.ever_up and self.mode is not Mode.FAILSAFE:
            self._failsafe()

    def _pump(self) -> None:
        """Service the link while the arm works; end that work when it was interrupted."""
        try:
            self.service()
        except Exception as exc:  # a link fault is not the pose's fault
            self.errors.append(f"{type(exc).__name__}: {exc}")
        if self._interrupt:
            raise Interrupted(self._interrupt)

    @contextmanager
    def _arm_work(self):
        self._busy, self._interrupt = True, ""
        try:
            yield
        finally:
            self._busy, self._interrupt = False, ""

    def _failsafe(self) -> None:
        self._resume_mode = self.mode
        self.mode = Mode.FAILSAFE
        if self._busy:
            self._interrupt = "failsafe"
        self.failsafe_events.append({"since": self.wall(), "until": None})
        del self.failsafe_events[:-8]
        try:
            self.hal.arm.stop_and_hold()
        except Exception as exc:  # the arm must not end the loop; say why in STATUS
            self.errors.append(f"failsafe hold: {type(exc).__name__}: {exc}")

    # -- status ----------------------------------------------------------------------

    def status(self) -> dict:
        p = self.progress
        return {
            "mode": self.mode.value,
            "sweep": None if p is None else {
                "id": p.sweep_id, "next": p.next_index, "poses": p.plan.count, "active": p.active,
                "skipped": [[s.index, s.commanded.elevation, s.commanded.azimuth, s.reason]
                            for s in p.skipped[-16:]],
            },
            "outbox": len(self.outbox),
            "paused": self.paused_reason,
            "failsafe": self.failsafe_events[-4:],
            "faults": self.pipeline.faults[-8:],
            "errors": list(self.errors)[-8:],
        }

    def state(self) -> pk.RobotState:
        if self.mode is Mode.FAILSAFE or self.paused_reason:
            return pk.RobotState.PAUSED
        return pk.RobotState.SWEEPING if self.mode is Mode.SWEEPING else pk.RobotState.IDLE

    def status_packet(self, text: str, extras: dict | None = None,
                      state: pk.RobotState | None = None) -> tuple[int, bytes]:
        return wire.status_body(self.cfg.robot_id, self.wall(), state or self.state(), self.pose,
                                len(self.outbox), self.outbox.bytes_used, self._seq.last, text, extras)

    def send_status(self, text: str, extras: dict | None = None) -> None:
        self.queue(*self.status_packet(text, extras))
        self.notifier.status(text)

    # -- sweeps ----------------------------------------------------------------------

    def plan(self) -> SweepPlan:
        s = self.cfg.sweep
        return SweepPlan(s.start, s.stop, s.step, s.azimuths)

    def start_sweep(self, plan: SweepPlan | None = None) -> SweepProgress:
        """A new sweep (of the config's plan unless one is given), saved before it begins."""
        self.progress = self.sweeps.start(self.plan() if plan is None else plan)
        self.mode = Mode.SWEEPING
        return self.progress

    def autostart(self) -> Boot:
        """At boot: resume an interrupted sweep; never restart a finished one on its own."""
        self.progress, boot = self.sweeps.autostart(self.plan(), new=self.new_sweep)
        self.new_sweep = False
        if boot in (Boot.STARTED, Boot.RESUMED):
            self.mode = Mode.SWEEPING
        return boot

    def stop_sweep(self) -> None:
        if self.progress is not None:
            self.progress.active = False
            self.sweeps.save(self.progress)
        if self.mode is Mode.SWEEPING:
            self.mode = Mode.IDLE

    def sweep_step(self) -> str:
        """Measure the next pose of the sweep; returns what happened.

        The pose's packets and the progress past it are committed together; when the
        outbox cannot take them, nothing changes and the pose is measured again later."""
        p = self.progress
        if p is None or p.done:
            return "done"
        if self.outbox.full_for(self._reserve) or self._full_until_ack:
            self.paused_reason = "outbox full: acquisition paused until the host acknowledges"
            return "paused"
        commanded = p.current()
        nxt = copy.deepcopy(p)
        cap = None
        try:
            with self._arm_work():
                self.pipeline.move(commanded)
                measured = self.pipeline.measure_view()
                if self.cfg.skip.skip_measured_pose and p.already_measured(measured, self.cfg.sweep.pose_tolerance_deg):
                    raise PoseSkipped(f"already measured in this sweep (measured {measured.elevation:.1f}°, "
                                      f"{measured.azimuth:.1f}°)")
                frame = self.pipeline.frame()
                cap = self.pipeline.process(frame, commanded, measured)
        except Interrupted:  # the command or failsafe that interrupted has set the state
            return "interrupted"
        except Exception as exc:
            # A fault the pipeline did not foresee skips the pose with its reason
            # instead of failing the same pose forever.
            reason = exc.reason if isinstance(exc, PoseSkipped) else f"internal: {type(exc).__name__}: {exc}"
            skipped = nxt.record_skipped(reason)
            packets = [self.status_packet(f"skipped pose: {skipped.reason}", {
                "sweep": p.sweep_id, "skipped_index": skipped.index,
                "skipped_elevation": skipped.commanded.elevation,
                "skipped_azimuth": skipped.commanded.azimuth})]
            state: dict[str, str] = {}
            result = "skipped"
        else:
            seq, packets, state = self.capture_packets(cap)
            nxt.record_measured(measured)
            result = "measured"
        if nxt.done:
            nxt.active = False
            packets.append(self.status_packet("sweep done", {
                "sweep": p.sweep_id, "measured": len(nxt.measured), "skipped": len(nxt.skipped)},
                pk.RobotState.IDLE))
        try:
            self.outbox.commit(packets, {**state, **self.sweeps.entry(nxt)}, reserve=self._reserve)
        except OutboxFull as exc:
            if cap is not None:
                self.pipeline.rollback(cap)
            self.paused_reason, self._full_until_ack = str(exc), True
            return "paused"
        self.paused_reason = ""
        self.progress = nxt
        if cap is not None:
            self.captured(cap, seq)
        self.notifier.status(f"sweep {nxt.sweep_id}: {result} pose {nxt.next_index} of {nxt.plan.count}")
        if nxt.done:
            self.mode = Mode.IDLE
            self.notifier.status(f"sweep {nxt.sweep_id} done: {len(nxt.measured)} measured, "
                                 f"{len(nxt.skipped)} skipped")
        return result

    def capture_packets(self, cap: Capture) -> tuple[int, list[tuple[int, bytes]], dict[str, str]]:
        """The packets of one capture and the state entries to commit with them."""
        seq = self._seq.peek()
        state = self._seq.entry(seq)
        if cap.pca is not None:  # the scene's basis survives restarts with the packet carrying it
            state[PCA_KEY] = json.dumps(cap.pca.to_record())
        packets = []
        if cap.mask_changed:
            packets.append(wire.mask_body(self.cfg.robot_id, seq, cap.labels))
        ref = self._last_models.get(wire.skip.pose_key(cap.commanded))
        if cap.unchanged and ref is not None:
            packets.append(wire.unchanged_body(self.cfg.robot_id, seq, ref, self.wall(), cap))
        else:
            packets.append(wire.models_body(self.cfg.robot_id, seq, self.wall(), self.cfg.features.space, cap))
        return seq, packets, state

    def captured(self, cap: Capture, seq: int) -> None:
        """`cap` was committed under `seq`."""
        self._seq.taken(seq)
        self.pose = cap.measured
        self._last_labels = cap.labels
        key = wire.skip.pose_key(cap.commanded)
        if not (cap.unchanged and key in self._last_models):
            wire.remember(self._last_models, key, seq)

    # -- commands --------------------------------------------------------------------

    def _on_body(self, body: bytes) -> None:
        try:
            cmd = pk.decode(body)
        except FrameError as exc:
            self.errors.append(f"bad packet from base: {exc}")
            return
        if not isinstance(cmd, pk.CommandPacket):
            return  # not a command (e.g. the base's own status): nothing to answer
        known = self.outbox.remembered(cmd.command_id)
        if known is not None:  # run before: answer again, unless that answer is still queued
            if self.outbox.kind_of(known.msg_id) is None:
                self.queue(known.kind, known.body)
            return
        reason = pk.Reason.INTERNAL
        effect = Effect()
        try:
            ok, result = self.handle(cmd.name.name, dict(cmd.args), effect)
        except PoseSkipped as exc:
            ok, result, reason = False, exc.reason, pk.Reason.HARDWARE
        except Interrupted as exc:
            ok, result, reason = False, f"interrupted by {exc}", pk.Reason.BUSY
        except OutboxFull as exc:
            ok, result, reason = False, str(exc), pk.Reason.OUTBOX_FULL
        except (ConfigError, KeyError, ValueError) as exc:
            ok, result, reason = False, f"{type(exc).__name__}: {exc}", pk.Reason.BAD_ARGUMENT
        except Exception as exc:  # a command that fails is answered, never fatal
            ok, result = False, f"{type(exc).__name__}: {exc}"
        if ok:
            extras = result if isinstance(result, dict) else {}
            answer = wire.reply_body(cmd.command_id, True, cmd.name.name, extras)
        else:
            effect = Effect()  # a refused command produced nothing
            if isinstance(result, str) and result.startswith("unknown command"):
                reason = pk.Reason.UNKNOWN_COMMAND
            elif isinstance(result, str) and result.startswith(("failsafe", "busy")):
                reason = pk.Reason.BUSY
            answer = wire.reply_body(cmd.command_id, False, str(result), reason=reason)
        if self._answer(cmd.command_id, answer, effect) and ok and self._busy and cmd.name.name in INTERRUPTING:
            self._interrupt = cmd.name.name  # the pose being measured ends at the next link service

    def _answer(self, command_id: int, answer: tuple[int, bytes], effect: Effect) -> bool:
        """Commit a reply with its command's effect, remembered by id; whether the effect stands."""
        try:
            self.outbox.commit(effect.packets, effect.state, reserve=effect.reserve,
                               reply=Reply(command_id, *answer))
        except OutboxFull as exc:
            effect.undo()
            if not (effect.packets or effect.state):
                self.paused_reason = str(exc)  # not even the reply fits: a retry finds room later
                return False
            # What the command produced does not fit: refuse it instead, and say why.
            nack = wire.reply_body(command_id, False, str(exc), reason=pk.Reason.OUTBOX_FULL)
            try:
                self.outbox.commit(reply=Reply(command_id, *nack))
            except OutboxFull as full:
                self.paused_reason = str(full)
            return False
        self.paused_reason = ""
        effect.done()
        return True

    def handle(self, name: str, args: dict, effect: Effect | None = None) -> tuple[bool, Any]:
        """Run one command; (True, result) or (False, reason).

        What it produces goes into `effect`, for the caller to commit with the reply."""
        effect = Effect() if effect is None else effect
        arm = self.hal.arm
        if name == "PING":
            return True, {"time": self.wall()}
        if name == "STATUS":
            return True, _flat_status(self.status())
        if self.mode is Mode.FAILSAFE:
            return False, "failsafe active: the link was lost; it clears when the link is back up"
        if name in ARM_COMMANDS and self._busy:
            return False, "busy: the arm is measuring a pose; send it again, or ABORT first"
        if name == "GOTO":
            view = ViewAngles(float(args["elevation"]), float(args.get("azimuth", 0.0)))
            with self._arm_work():
                self.pipeline.move(view)
                m = self.pipeline.measure_view()
            return True, {"elevation": m.elevation, "azimuth": m.azimuth}
        if name == "CAPTURE":
            with self._arm_work():
                measured = self.pipeline.measure_view()
                cap = self.pipeline.process(self.pipeline.frame(), measured, measured)
            seq, effect.packets, effect.state = self.capture_packets(cap)
            effect.reserve = self._reserve
            effect.done = lambda: self.captured(cap, seq)
            effect.undo = lambda: self.pipeline.rollback(cap)
            return True, {"seq": seq, "models": len(cap.results)}
        if name == "SWEEP":
            # The packet decoder has checked every argument's type and range.
            azs = tuple(float(a) for a in args.get("azimuths", self.cfg.sweep.azimuths))
            if "elevations" in args:
                els = tuple(float(e) for e in args["elevations"])
                plan = SweepPlan(els[0], els[-1], 1.0, azs, els)
            else:  # SweepPlan bounds the pose count before any list is built
                plan = SweepPlan(float(args["start"]), float(args["stop"]), float(args["step"]), azs)
            p = self.sweeps.next_sweep(plan)
            effect.state = self.sweeps.entry(p)  # saved with the reply, in one commit

            def started() -> None:
                self.progress, self.mode = p, Mode.SWEEPING
            effect.done = started
            return True, {"sweep": p.sweep_id, "poses": p.plan.count}
        if name == "ABORT":
            self.stop_sweep()
            arm.stop_and_hold()
            return True, {"aborted": True}
        if name == "SET":
            self.set_keys({args["key"]: args["value"]})
            return True, {"set": args["key"]}
        if name == "TORQUE_OFF":
            self.stop_sweep()
            arm.torque_off()
            return True, {"torque": False}
        if name == "REBOOT_SERVO":
            sid = int(args["servo_id"])
            self.hal.servo_bus.reboot(sid)
            return True, {"rebooted": sid}
        if name == "SEND_MASK":
            if self._last_labels is None:  # none yet: the next capture sends its map
                getattr(self.pipeline.segmenter, "force_send", lambda: None)()
                return True, {"queued": False, "next_capture": True}
            effect.packets = [wire.mask_body(self.cfg.robot_id, int(args.get("seq", self._seq.last or 0)),
                                             self._last_labels)]
            return True, {"queued": True}
        return False, f"unknown command {name!r}"

    def set_keys(self, args: dict) -> None:
        """SET section.key = value for the keys that may change at run time."""
        cfg = self.cfg
        for dotted, value in args.items():
            section, _, key = str(dotted).partition(".")
            if key not in SETTABLE.get(section, ()):
                allowed = ", ".join(f"{s}.{k}" for s, ks in SETTABLE.items() for k in ks)
                raise ConfigError(f"{dotted} cannot be set at run time (settable: {allowed})")
            part = getattr(cfg, section)
            kind = config_mod._TYPES[type(part)][key]
            new = config_mod._convert(dotted, value, kind, cfg.state_dir)
            cfg = replace(cfg, **{section: replace(part, **{key: new})})
        config_mod.check(cfg)
        self.cfg = cfg
        self.pipeline.cfg = cfg

    # -- the loop --------------------------------------------------------------------

    def boot(self) -> None:
        try:
            self.pipeline._retry("torque on", self.hal.arm.enable)
        except PoseSkipped as exc:
            self.errors.append(exc.reason)
        extras = {"mode": self.mode.value}
        if self.cfg.sweep.autostart or self.new_sweep:
            boot = self.autostart()
            extras = {"mode": self.mode.value, "sweep": self.progress.sweep_id, "sweep_state": boot.value}
        self.notifier.ready(f"btf-robot running: {self.mode.value}")
        self.send_status("boot", extras)

    def step(self) -> str:
        """One turn of the loop; what the sweep did ("" when nothing). Never raises."""
        try:
            self.service()
            if self.mode is Mode.SWEEPING:
                result = self.sweep_step()
                self.service()
                return result
        except Exception as exc:
            self.errors.append(f"{type(exc).__name__}: {exc}")
        return ""

    def idle(self) -> bool:
        """Nothing to do: no active sweep and every packet acknowledged."""
        return self.mode is not Mode.SWEEPING and len(self.outbox) == 0

    def run(self, stop: Callable[["Runtime"], bool] = lambda rt: False, tick_s: float = 0.01) -> int:
        self.boot()
        while not stop(self):
            # Rest unless a pose was just done: a paused sweep (outbox full) must not spin.
            if self.step() not in ("measured", "skipped"):
                self.sleep(tick_s)
        return 0


def _read_pca(text: str | None, legacy: Path) -> Any:
    """The scene's PCA basis saved before a restart (None if none or unreadable: refit)."""
    from onboard.features import PcaBasis

    try:
        if text is None and legacy.exists():
            text = legacy.read_text()  # where the basis lived before it moved into the outbox
        return None if text is None else PcaBasis.from_record(json.loads(text))
    except (OSError, ValueError, TypeError, AttributeError, KeyError):
        return None


def _flat_status(st: dict) -> dict:
    """STATUS as packet extras: scalars and short lists only."""
    sweep = st.get("sweep") or {}
    out = {"mode": st["mode"], "outbox": st["outbox"], "paused": st["paused"]}
    if sweep:
        out.update(sweep_id=sweep["id"], next=sweep["next"], poses=sweep["poses"])
        out["skipped"] = [f"{i}@{e:.1f}/{a:.1f}: {r}" for i, e, a, r in sweep["skipped"]]
    out["failsafe"] = [f"{e['since']:.1f}-{e['until'] or 0:.1f}" for e in st["failsafe"]]
    out["faults"] = list(st["faults"])
    out["errors"] = list(st["errors"])
    return out
