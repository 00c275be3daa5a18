"""The Dynamixel X-series control table (Protocol 2.0): addresses, sizes, access and units.

One table for the driver (`hal.dynamixel`) and the servo emulator (`hal.emulators.dxl`).
Written from the e-Manual's XL430-W250 / XM430 control table; `tests/test_dynamixel.py` pins
every entry to those datasheet numbers, so a wrong address fails there instead of the driver
and the emulator agreeing on it.
"""
from __future__ import annotations

from enum import IntEnum


class Reg(IntEnum):
    """Control table addresses used by the driver or the emulator."""

    MODEL_NUMBER = 0
    ID = 7
    TORQUE_ENABLE = 64
    HARDWARE_ERROR_STATUS = 70
    PROFILE_VELOCITY = 112
    GOAL_POSITION = 116
    MOVING = 122
    PRESENT_POSITION = 132


# Bytes per register (little-endian; the 4-byte ones are signed).
SIZE: dict[Reg, int] = {
    Reg.MODEL_NUMBER: 2,
    Reg.ID: 1,
    Reg.TORQUE_ENABLE: 1,
    Reg.HARDWARE_ERROR_STATUS: 1,
    Reg.PROFILE_VELOCITY: 4,
    Reg.GOAL_POSITION: 4,
    Reg.MOVING: 1,
    Reg.PRESENT_POSITION: 4,
}
TABLE_SIZE = 147  # addresses 0..146
# Read-only addresses the emulator refuses to write: the datasheet's R entries at the model and
# firmware bytes, the error and moving status and the present values (not its tick counters).
READ_ONLY = frozenset({*range(0, 7), Reg.HARDWARE_ERROR_STATUS, Reg.MOVING, *range(124, TABLE_SIZE)})

TICKS_PER_TURN = 4096  # position unit: 0.088 degrees
CENTER_TICKS = 2048  # 0 degrees at the interface
VELOCITY_UNIT_RPM = 0.229  # profile velocity unit; 0 means "as fast as possible"
ALERT = 0x80  # status packet error byte: the servo has a hardware error (read HARDWARE_ERROR_STATUS)
