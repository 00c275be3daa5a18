"""BNO055 orientation tracker over I2C (smbus2), in NDOF fusion mode.

Register addresses from the Bosch BNO055 datasheet (page 0). Euler angles are
little-endian int16 in 1/16 degree; conversion to degrees happens here and nowhere else.
A chip that does not answer at all (EIO after every try, or no device: ENXIO, ENODEV) is
`DeviceGone`: unplugged, or without power. Back on the bus it has started afresh (CONFIG
mode, the default axes, Euler registers at zero), so the next read sets it up again first.
"""
from __future__ import annotations

import errno
import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from enum import IntEnum
from typing import Any, Protocol

import numpy as np

from hal.interfaces import Calibration, DeviceGone, HalError, Orientation

CHIP_ID = 0xA0
DEFAULT_ADDRESS = 0x28


class Reg(IntEnum):
    CHIP_ID = 0x00
    PAGE_ID = 0x07
    EULER_H_LSB = 0x1A  # heading, roll, pitch: 6 bytes
    CALIB_STAT = 0x35
    SYS_STATUS = 0x39
    UNIT_SEL = 0x3B
    OPR_MODE = 0x3D
    PWR_MODE = 0x3E
    SYS_TRIGGER = 0x3F
    AXIS_MAP_CONFIG = 0x41  # which chip axis each reported axis takes (2 bits per axis: X, Y, Z)
    AXIS_MAP_SIGN = 0x42  # bit 2: X negated, bit 1: Y, bit 0: Z


class Mode(IntEnum):
    CONFIG = 0x00
    IMU = 0x08
    NDOF = 0x0C


# Datasheet table 3-6: 19 ms from any mode into CONFIG, 7 ms from CONFIG into a fusion mode.
TO_CONFIG_S = 0.019
FROM_CONFIG_S = 0.007
EULER_RADIANS = 0x04  # UNIT_SEL bit 2: Euler in 1/900 rad instead of 1/16 degree
RETRYABLE = frozenset({errno.EREMOTEIO, errno.EIO, errno.EBUSY})  # 121 NACK, 5, 16
GONE = frozenset({errno.EIO, errno.ENXIO, errno.ENODEV})  # every try: no chip on the bus


# Datasheet section 3.4: the eight placements of the chip, as (AXIS_MAP_CONFIG, AXIS_MAP_SIGN).
PLACEMENTS: dict[str, tuple[int, int]] = {
    "P0": (0x21, 0x04), "P1": (0x24, 0x00), "P2": (0x24, 0x06), "P3": (0x21, 0x02),
    "P4": (0x24, 0x03), "P5": (0x21, 0x01), "P6": (0x21, 0x07), "P7": (0x24, 0x05),
}


@dataclass(frozen=True, slots=True)
class AxisRemap:
    """The BNO055's axis remap registers; the default P1 reports the chip's own axes."""

    config: int = 0x24
    sign: int = 0x00

    def __post_init__(self) -> None:
        sources = sorted((self.config >> (2 * i)) & 3 for i in range(3))
        if not 0 <= self.config <= 0x3F or sources != [0, 1, 2] or not 0 <= self.sign <= 0x07:
            raise ValueError(f"axis remap 0x{self.config:02X}/0x{self.sign:02X} is not a remap: AXIS_MAP_CONFIG "
                             "must give each of X, Y, Z one chip axis, AXIS_MAP_SIGN uses bits 0..2")

    @classmethod
    def parse(cls, text: str) -> AxisRemap:
        """'P0'..'P7' (the datasheet's placements) or 'CONFIG/SIGN' register values, e.g. '0x24/0x03'."""
        t = text.strip().upper()
        if t in PLACEMENTS:
            return cls(*PLACEMENTS[t])
        m = re.fullmatch(r"(0X[0-9A-F]+|\d+)\s*/\s*(0X[0-9A-F]+|\d+)", t)
        if not m:
            raise ValueError(f"axis remap {text!r}: give a placement P0..P7 or registers CONFIG/SIGN like 0x24/0x03")
        return cls(int(m.group(1), 0), int(m.group(2), 0))

    @property
    def matrix(self) -> np.ndarray:
        """P with reported = P · chip: row i has the sign of reported axis i at its chip axis."""
        p = np.zeros((3, 3))
        for axis in range(3):
            negated = (self.sign >> (2 - axis)) & 1
            p[axis, (self.config >> (2 * axis)) & 3] = -1.0 if negated else 1.0
        return p

    @classmethod
    def from_matrix(cls, p: np.ndarray) -> AxisRemap:
        config = sign = 0
        for axis in range(3):
            source = int(np.argmax(np.abs(p[axis])))
            config |= source << (2 * axis)
            sign |= (1 if p[axis, source] < 0 else 0) << (2 - axis)
        return cls(config, sign)

    @property
    def placement(self) -> str | None:
        return next((name for name, regs in PLACEMENTS.items() if regs == (self.config, self.sign)), None)

    def __str__(self) -> str:
        regs = f"AXIS_MAP_CONFIG 0x{self.config:02X}, AXIS_MAP_SIGN 0x{self.sign:02X}"
        return f"{self.placement} ({regs})" if self.placement else regs


class SMBusLike(Protocol):
    def read_byte_data(self, i2c_addr: int, register: int) -> int: ...
    def write_byte_data(self, i2c_addr: int, register: int, value: int) -> None: ...
    def read_i2c_block_data(self, i2c_addr: int, register: int, length: int) -> list[int]: ...


def _int16(lo: int, hi: int) -> int:
    v = lo | (hi << 8)
    return v - 0x10000 if v & 0x8000 else v


class BNO055Tracker:
    """OrientationTracker on a BNO055. The bus is passed in; `open` makes an smbus2.SMBus."""

    def __init__(self, bus: SMBusLike, address: int = DEFAULT_ADDRESS, bus_number: int = 1,
                 retries: int = 3, sleep: Callable[[float], None] = time.sleep,
                 remap: AxisRemap | None = None) -> None:
        if retries < 0:
            raise ValueError(f"retries must be >= 0, got {retries}")
        self._bus = bus
        self.address = address
        self.bus_number = bus_number
        self.retries = retries
        self._sleep = sleep
        self.retried = 0  # transient bus errors absorbed so far
        self._wanted = remap
        self._lost = False  # the chip stopped answering: set it up again before the next read
        self._setup()

    def _setup(self) -> None:
        """Put the chip in fusion mode with degrees and the remap asked for (at start, and when
        it is back on the bus after it was gone)."""
        chip = self._io(self._bus.read_byte_data, self.address, Reg.CHIP_ID)
        if chip != CHIP_ID:
            raise HalError(f"{self._where()}: chip id 0x{chip:02X}, expected 0x{CHIP_ID:02X} (BNO055); "
                           "wrong device or address")
        self._set_mode(Mode.CONFIG)
        self._io(self._bus.write_byte_data, self.address, Reg.PAGE_ID, 0)
        self._use_degrees()
        self.remap = self._axis_remap(self._wanted)
        self._set_mode(Mode.NDOF)
        self._lost = False

    def _back(self) -> None:
        """Set a chip that was gone up again before it is read (it lost its settings)."""
        if self._lost:
            self._setup()

    @classmethod
    def open(cls, bus_number: int = 1, address: int = DEFAULT_ADDRESS, **kwargs: Any) -> BNO055Tracker:
        import smbus2  # only the real robot needs the bus module

        try:
            bus = smbus2.SMBus(bus_number)
        except OSError as exc:
            raise HalError(f"BNO055 on I2C bus {bus_number}: cannot open bus: {exc}") from exc
        try:
            return cls(bus, address=address, bus_number=bus_number, **kwargs)
        except Exception:
            bus.close()
            raise

    def _where(self) -> str:
        return f"BNO055 on I2C bus {self.bus_number} address 0x{self.address:02X}"

    def _io(self, op: Callable[..., Any], *args: Any) -> Any:
        for attempt in range(self.retries + 1):
            try:
                return op(*args)
            except OSError as exc:
                gone = exc.errno in GONE and (attempt == self.retries or exc.errno not in RETRYABLE)
                if gone:
                    self._lost = True
                    raise DeviceGone(f"{self._where()}: no answer ({errno.errorcode.get(exc.errno, exc.errno)}, "
                                     f"{attempt + 1} tries): unplugged or without power?") from exc
                if exc.errno not in RETRYABLE:
                    raise HalError(f"{self._where()}: {exc}") from exc
                if attempt == self.retries:
                    raise HalError(f"{self._where()}: no answer after {self.retries + 1} tries "
                                   f"({errno.errorcode.get(exc.errno, exc.errno)})") from exc
                self.retried += 1
                self._sleep(0.001 * (attempt + 1))
        raise AssertionError("unreachable")

    def _use_degrees(self) -> None:
        """Euler registers in 1/16 degree: an earlier program may have left the chip in radians."""
        units = self._io(self._bus.read_byte_data, self.address, Reg.UNIT_SEL)
        if units & EULER_RADIANS:
            self._io(self._bus.write_byte_data, self.address, Reg.UNIT_SEL, units & ~EULER_RADIANS)
            if self._io(self._bus.read_byte_data, self.address, Reg.UNIT_SEL) & EULER_RADIANS:
                raise HalError(f"{self._where()}: Euler unit stays radians (UNIT_SEL 0x{units:02X})")

    def _axis_remap(self, wanted: AxisRemap | None) -> AxisRemap:
        """Write `wanted` (in CONFIG mode; the chip forgets it at power-off) and return what the chip holds."""
        if wanted is not None:
            self._io(self._bus.write_byte_data, self.address, Reg.AXIS_MAP_CONFIG, wanted.config)
            self._io(self._bus.write_byte_data, self.address, Reg.AXIS_MAP_SIGN, wanted.sign)
        config = self._io(self._bus.read_byte_data, self.address, Reg.AXIS_MAP_CONFIG) & 0x3F
        sign = self._io(self._bus.read_byte_data, self.address, Reg.AXIS_MAP_SIGN) & 0x07
        try:
            held = AxisRemap(config, sign)
        except ValueError as exc:
            raise HalError(f"{self._where()}: {exc}") from None
        if wanted is not None and held != wanted:
            raise HalError(f"{self._where()}: asked for axis remap {wanted}, chip holds {held}")
        return held

    def _set_mode(self, mode: Mode) -> None:
        self._io(self._bus.write_byte_data, self.address, Reg.OPR_MODE, int(mode))
        self._sleep(TO_CONFIG_S if mode is Mode.CONFIG else FROM_CONFIG_S)
        got = self._io(self._bus.read_byte_data, self.address, Reg.OPR_MODE) & 0x0F
        if got != mode:
            raise HalError(f"{self._where()}: asked for mode {mode.name}, chip reports 0x{got:02X}")

    def orientation(self) -> Orientation:
        self._back()
        raw = self._io(self._bus.read_i2c_block_data, self.address, Reg.EULER_H_LSB, 6)
        if len(raw) != 6:
            raise HalError(f"{self._where()}: short Euler read ({len(raw)} of 6 bytes)")
        heading, roll, pitch = (_int16(raw[i], raw[i + 1]) / 16.0 for i in (0, 2, 4))
        return Orientation(heading=heading, roll=roll, pitch=pitch)

    def calibration(self) -> Calibration:
        self._back()
        v = self._io(self._bus.read_byte_data, self.address, Reg.CALIB_STAT)
        return Calibration(system=(v >> 6) & 3, gyro=(v >> 4) & 3, accel=(v >> 2) & 3, mag=v & 3)

    def close(self) -> None:
        close = getattr(self._bus, "close", None)
        if close is not None:
            close()
