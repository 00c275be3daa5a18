"""The command table: declared once in radio.packets.commands, read by the packet schema, the robot's
dispatch and `btf-host cmd`."""
import pytest

from onboard.capture.pipeline import PoseSkipped
from onboard.config import ConfigError
from onboard.dispatch import Refusal, refusal
from onboard.link.outbox import OutboxFull
from onboard.state import Interrupted
from radio import packets as pk
from radio.packets.commands import COMMANDS, CommandName
from tests.support.robots import IDLE, SMALL, robot_toml
from tools.cli import build_parser
from tools.cli.cmd import command_of

C = CommandName
# Each subcommand as a user types it, and the arguments the robot then receives.
TYPED = {
    C.PING: (["ping"], {}),
    C.STATUS: (["status"], {}),
    C.GOTO: (["goto", "--elevation", "45"], {"elevation": 45.0, "azimuth": 0.0}),
    C.CAPTURE: (["capture"], {}),
    C.SWEEP: (["sweep", "--elevations", "90,60"], {"elevations": [90.0, 60.0]}),
    C.ABORT: (["abort"], {}),
    C.SET: (["set", "skip.min_pixels", "32"], {"key": "skip.min_pixels", "value": 32}),
    C.TORQUE_OFF: (["torque-off"], {}),
    C.REBOOT_SERVO: (["reboot-servo", "--servo-id", "2"], {"servo_id": 2}),
    C.SEND_MASK: (["send-mask", "--seq", "7"], {"seq": 7}),
    C.TORQUE_ON: (["torque-on"], {}),
}


def test_every_command_has_a_cli_form_and_help_from_the_table():
    assert set(COMMANDS) == set(CommandName) == set(TYPED)
    sub = next(a for a in build_parser()._subparsers._group_actions[0].choices["cmd"]._actions
               if a.dest == "what")
    assert set(sub.choices) == {c.cli for c in COMMANDS.values()}
    helps = {a.dest: a.help for a in sub._choices_actions}
    assert all(helps[c.cli] == c.help and c.help for c in COMMANDS.values())


@pytest.mark.parametrize("name", list(CommandName))
def test_what_the_user_types_is_what_the_robot_checks(name):
    argv, want = TYPED[name]
    got_name, args = command_of(build_parser().parse_args(["cmd", "--port", "x", "--key", "k", *argv]))
    assert (got_name, args) == (name, want)
    decoded = pk.decode(pk.encode(pk.CommandPacket(1, name, args))).args
    assert {k: list(v) if isinstance(v, tuple) else v for k, v in decoded.items()} == want


def test_the_flags_say_which_commands_move_or_free_the_arm():
    assert {c for c, s in COMMANDS.items() if s.moves_arm} == {C.GOTO, C.CAPTURE, C.REBOOT_SERVO, C.TORQUE_ON}
    assert {c for c, s in COMMANDS.items() if s.interrupts} == {C.ABORT, C.TORQUE_OFF, C.SWEEP}
    assert {c for c, s in COMMANDS.items() if s.query} == {C.PING, C.STATUS}


def test_the_robot_has_a_handler_for_every_command(fake_robot):
    rt, _ = fake_robot(robot_toml(SMALL))
    assert set(rt.dispatch.handlers) == set(COMMANDS)


def test_refusals_are_values_with_their_reason():
    hardware = refusal(PoseSkipped("move failed"))
    assert hardware.reason is pk.Reason.HARDWARE and hardware.text.startswith("move failed (")
    assert "reboot-servo --servo-id" in hardware.text and "torque-on" in hardware.text  # how to recover
    assert refusal(Interrupted("ABORT")) == Refusal(pk.Reason.BUSY, "interrupted by ABORT")
    full = refusal(OutboxFull("full"))
    assert full.reason is pk.Reason.OUTBOX_FULL and "station" in full.text
    assert refusal(ConfigError("x")) == Refusal(pk.Reason.BAD_ARGUMENT, "x")  # no class name for a person
    assert refusal(KeyError("no key y")) == Refusal(pk.Reason.BAD_ARGUMENT, "no key y")
    internal = refusal(RuntimeError("y"))
    assert internal.reason is pk.Reason.INTERNAL and internal.text.startswith("RuntimeError: y (see the robot's log")


def test_a_handler_refusal_reaches_the_nack_unchanged(fake_robot):
    rt, _ = fake_robot(robot_toml(SMALL, IDLE))
    rt.failsafe.link_changed(True)
    rt.failsafe.link_changed(False)
    got = rt.dispatch.run(C.GOTO, {"elevation": 40.0, "azimuth": 0.0})
    assert isinstance(got, Refusal) and got.reason is pk.Reason.BUSY and got.text.startswith("failsafe")
    assert rt.dispatch.run(C.PING, {})["time"] > 0  # a query is answered in failsafe
