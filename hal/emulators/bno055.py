"""The BNO055 register map behind smbus2's call surface, so the real driver runs in tests.

Models what the driver depends on: chip id, the operating-mode state machine (config
registers take writes only in CONFIG mode; Euler registers hold zero until a fusion mode
has run), Euler angles following a commanded orientation plus noise, calibration status,
the Euler unit (UNIT_SEL: 1/16 degree or 1/900 radian; read as degrees, radians come out
1.8% small, silently), the axis remap registers, a chip mounted other than upright on the
camera (`mount`, a rotation from hal.orientation.MOUNTS), and NACKs (OSError 121) injected
at a seeded rate or on demand. The orientation source gives the camera's orientation; the
chip reports it through its mounting and remap, so a wrong remap reads wrong. `unplug()` takes
the chip off the bus (every transaction fails with EIO) until `replug()`, which by default
brings it back as from power-on: CONFIG mode, the default axes and units, Euler registers zero.
"""
from __future__ import annotations

import errno
import math
import random
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from hal.bno055 import CHIP_ID, DEFAULT_ADDRESS, EULER_RADIANS, AxisRemap, Mode, Reg
from hal.interfaces import Orientation
from hal.orientation import euler_angles, euler_matrix

FUSION_MODES = frozenset(range(0x08, 0x0D))  # IMU, COMPASS, M4G, NDOF_FMC_OFF, NDOF
# Registers writable in any mode (datasheet 3.3: the rest only in CONFIG mode).
ANY_MODE_WRITABLE = frozenset({Reg.PAGE_ID, Reg.OPR_MODE, Reg.PWR_MODE, Reg.SYS_TRIGGER})


@dataclass(frozen=True, slots=True)
class Access:
    """One bus transaction: op is "read", "write" or "block"; ok False when it was NACKed."""

    op: str
    address: int
    register: int
    value: int | None
    ok: bool


class EmulatedSMBus:
    def __init__(self, orientation_source: Callable[[], Orientation] | None = None, nack_rate: float = 0.0,
                 seed: int = 0, noise_deg: float = 0.0, address: int = DEFAULT_ADDRESS,
                 chip_id: int = CHIP_ID, calibration: int = 0xFF, mount: np.ndarray | None = None) -> None:
        if not 0.0 <= nack_rate <= 1.0:
            raise ValueError(f"nack_rate must lie in [0, 1], got {nack_rate}")
        self.source = orientation_source or (lambda: Orientation(0.0, 0.0, -90.0))
        self.nack_rate = nack_rate
        self.noise_deg = noise_deg
        self.address = address
        self.chip_id, self.calibration = chip_id, calibration  # what it reports from power-on
        self.regs = bytearray(0x80)
        self._power_on()
        self.mount = None if mount is None else np.asarray(mount, float)
        self.nack_next = 0  # force this many NACKs before anything else
        self.history: list[Access] = []
        self.closed = False
        self.unplugged = False
        self._rng = random.Random(seed)

    def _power_on(self) -> None:
        """The registers as the chip starts: CONFIG mode, its own axes, Euler at zero."""
        self.regs[:] = bytes(len(self.regs))
        self.regs[Reg.CHIP_ID] = self.chip_id
        self.regs[Reg.CALIB_STAT] = self.calibration
        self.regs[Reg.AXIS_MAP_CONFIG], self.regs[Reg.AXIS_MAP_SIGN] = AxisRemap().config, AxisRemap().sign

    def unplug(self) -> None:
        """Off the bus: every transaction fails with EIO until `replug`."""
        self.unplugged = True

    def replug(self, power_cycled: bool = True) -> None:
        """Back on the bus; `power_cycled`: it lost power meanwhile and starts as at power-on."""
        self.unplugged = False
        if power_cycled:
            self._power_on()

    @property
    def mode(self) -> int:
        return self.regs[Reg.OPR_MODE] & 0x0F

    def _nack(self, op: str, address: int, register: int, value: int | None) -> None:
        if self.unplugged:  # no chip: the adapter reports the transfer failed
            self.history.append(Access(op, address, register, value, False))
            raise OSError(errno.EIO, "Input/output error")
        nack = address != self.address  # nobody answers at another address
        if self.nack_next > 0:
            self.nack_next -= 1
            nack = True
        elif self.nack_rate > 0 and self._rng.random() < self.nack_rate:
            nack = True
        self.history.append(Access(op, address, register, value, not nack))
        if nack:
            raise OSError(errno.EREMOTEIO, "Remote I/O error")

    def _refresh_euler(self) -> None:
        if self.mode not in FUSION_MODES:
            return  # fusion stopped: registers keep their last (initially zero) values
        o = self._reported(self.source())
        values = (o.heading % 360.0, o.roll, o.pitch)
        per_degree = 900.0 * math.pi / 180.0 if self.regs[Reg.UNIT_SEL] & EULER_RADIANS else 16.0
        for i, deg in enumerate(values):
            deg += self._rng.gauss(0.0, self.noise_deg) if self.noise_deg > 0 else 0.0
            raw = max(-32768, min(32767, round(deg * per_degree))) & 0xFFFF
            self.regs[Reg.EULER_H_LSB + 2 * i] = raw & 0xFF
            self.regs[Reg.EULER_H_LSB + 2 * i + 1] = raw >> 8

    def _reported(self, camera: Orientation) -> Orientation:
        """What the fusion reports for the camera's orientation, through the mount and the remap."""
        remap = AxisRemap(self.regs[Reg.AXIS_MAP_CONFIG] & 0x3F, self.regs[Reg.AXIS_MAP_SIGN] & 0x07)
        if self.mount is None and remap == AxisRemap():
            return camera
        mount = np.eye(3) if self.mount is None else self.mount
        return euler_angles(euler_matrix(camera) @ mount @ remap.matrix.T)

    def read_byte_data(self, i2c_addr: int, register: int) -> int:
        self._nack("read", i2c_addr, register, None)
        self._refresh_euler()
        return self.regs[register & 0x7F]

    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int) -> list[int]:
        self._nack("block", i2c_addr, register, length)
        self._refresh_euler()
        return list(self.regs[register:register + length])

    def write_byte_data(self, i2c_addr: int, register: int, value: int) -> None:
        self._nack("write", i2c_addr, register, value)
        if register == Reg.CHIP_ID or (register not in ANY_MODE_WRITABLE and self.mode != Mode.CONFIG):
            return  # read-only, or a config register outside CONFIG mode: ignored like the chip does
        if register == Reg.OPR_MODE and self.mode in FUSION_MODES and (value & 0x0F) != Mode.CONFIG:
            return  # fusion modes change only through CONFIG
        self.regs[register] = value & 0xFF

    def close(self) -> None:
        self.closed = True
