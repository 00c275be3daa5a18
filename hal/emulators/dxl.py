"""A Dynamixel Protocol 2.0 servo chain on a pseudo-terminal, for the real driver to talk to.

The emulator owns the master side of a pty; `port` is a stable link to its slave (as udev's
/dev/serial/by-id names an adapter) that pyserial, and so dynamixel-sdk, opens. It answers
PING, READ, WRITE, SYNC_READ, SYNC_WRITE and REBOOT with status packets, moves present
positions toward goals at the profile velocity, and on request drops replies, corrupts
bytes or raises the alert bit with a hardware error code. `unplug()` pulls the adapter: the
pty closes (an open port reads and writes EIO) and `port` vanishes; `replug()` brings a new
pty under the same name, the servos as they were (they keep their power).
"""
from __future__ import annotations

import os
import select
import shutil
import tempfile
import threading
import time
import tty
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Callable

from hal.dynamixel_table import ALERT, CENTER_TICKS, READ_ONLY, SIZE, TABLE_SIZE, TICKS_PER_TURN, VELOCITY_UNIT_RPM, Reg
from hal.fakes import Call, Faults

HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
VELOCITY_UNIT_TICKS_S = VELOCITY_UNIT_RPM * TICKS_PER_TURN / 60.0
MAX_SPEED_TICKS_S = 1023 * VELOCITY_UNIT_TICKS_S


class Inst(IntEnum):
    PING = 0x01
    READ = 0x02
    WRITE = 0x03
    REBOOT = 0x08
    STATUS = 0x55
    SYNC_READ = 0x82
    SYNC_WRITE = 0x83


class PacketError(IntEnum):
    """The low seven bits of a status packet's error byte."""

    NONE = 0
    RESULT_FAIL = 1
    INSTRUCTION = 2
    CRC = 3
    DATA_RANGE = 4
    DATA_LENGTH = 5
    DATA_LIMIT = 6
    ACCESS = 7


XL430_MODEL = 1060
MIN_PACKET = 10  # header 4, id, length 2, instruction, CRC 2
MAX_PACKET = 1024


def _crc_table() -> list[int]:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return table


_CRC_TABLE = _crc_table()


def crc16(data: bytes) -> int:
    """Dynamixel Protocol 2.0 CRC-16 (polynomial 0x8005, initial 0, unreflected)."""
    crc = 0
    for byte in data:
        crc = ((crc << 8) ^ _CRC_TABLE[((crc >> 8) ^ byte) & 0xFF]) & 0xFFFF
    return crc


def stuff(body: bytes) -> bytes:
    """Byte stuffing: every FF FF FD inside the body becomes FF FF FD FD."""
    out = bytearray()
    for byte in body:
        out.append(byte)
        if out[-3:] == b"\xff\xff\xfd":
            out.append(0xFD)
    return bytes(out)


def unstuff(body: bytes) -> bytes:
    out = bytearray()
    i = 0
    while i < len(body):
        out.append(body[i])
        if out[-3:] == b"\xff\xff\xfd" and i + 1 < len(body) and body[i + 1] == 0xFD:
            i += 1
        i += 1
    return bytes(out)


def status_packet(servo_id: int, error: int, params: bytes = b"") -> bytes:
    body = stuff(bytes([Inst.STATUS, error]) + params)
    head = HEADER + bytes([servo_id]) + (len(body) + 2).to_bytes(2, "little")
    packet = head + body
    return packet + crc16(packet).to_bytes(2, "little")


def instruction_packet(servo_id: int, inst: int, params: bytes = b"") -> bytes:
    """An instruction packet as a controller sends it (used by tests and tools)."""
    body = stuff(bytes([inst]) + params)
    packet = HEADER + bytes([servo_id]) + (len(body) + 2).to_bytes(2, "little") + body
    return packet + crc16(packet).to_bytes(2, "little")


@dataclass
class EmulatedServo:
    """One servo's control table and motion state."""

    servo_id: int
    table: bytearray = field(default_factory=lambda: bytearray(TABLE_SIZE))
    position: float = float(CENTER_TICKS)
    offline_until: float = 0.0

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self.table[:] = bytes(TABLE_SIZE)
        self.set(Reg.MODEL_NUMBER, XL430_MODEL)
        self.set(Reg.ID, self.servo_id)
        self.set(Reg.GOAL_POSITION, round(self.position))
        self.set(Reg.PRESENT_POSITION, round(self.position))

    def get(self, reg: Reg) -> int:
        size = SIZE[reg]
        return int.from_bytes(self.table[reg:reg + size], "little", signed=size == 4)

    def set(self, reg: Reg, value: int) -> None:
        size = SIZE[reg]
        self.table[reg:reg + size] = value.to_bytes(size, "little", signed=size == 4)

    def advance(self, dt: float) -> None:
        """Move toward the goal for `dt` seconds (only while torque is on)."""
        goal = self.get(Reg.GOAL_POSITION)
        torque = self.table[Reg.TORQUE_ENABLE] == 1
        if torque and dt > 0.0:
            velocity = self.get(Reg.PROFILE_VELOCITY)
            speed = velocity * VELOCITY_UNIT_TICKS_S if velocity > 0 else MAX_SPEED_TICKS_S
            step = speed * dt
            delta = goal - self.position
            self.position = float(goal) if abs(delta) <= step else self.position + step * (1 if delta > 0 else -1)
        self.set(Reg.PRESENT_POSITION, round(self.position))
        self.table[Reg.MOVING] = int(torque and round(self.position) != goal)


class DxlEmulator:
    """A chain of X-series servos answering Protocol 2.0 on a pty, served by a thread.

    Fault knobs: `drop_next(n)` and `corrupt_next(n)` act on the next n status packets,
    `raise_alert(id, code)` sets a hardware error (torque drops, the alert bit appears in
    every status until REBOOT), and `faults` draws "drop"/"corrupt" at random per reply.
    `history` records every instruction received as `Call(instruction, (id, ...), outcome)`.
    """

    def __init__(
        self,
        servo_ids: tuple[int, ...] = (1, 2),
        clock: Callable[[], float] = time.monotonic,
        faults: Faults | None = None,
        reboot_s: float = 0.02,
    ) -> None:
        if not servo_ids or any(not 0 <= i < BROADCAST_ID for i in servo_ids):
            raise ValueError(f"servo ids must be in 0..252, got {servo_ids}")
        self.servos = {i: EmulatedServo(i) for i in servo_ids}
        self.clock = clock
        self.faults = faults or Faults()
        self.reboot_s = reboot_s
        self.history: list[Call] = []
        self._drop = 0
        self._corrupt = 0
        self._last = clock()
        self._lock = threading.Lock()
        self._io = threading.Lock()  # held while the pty is used, so `unplug` never closes it under a read
        self._stop = threading.Event()
        self._dir = tempfile.mkdtemp(prefix="btf-dxl-")
        self.port = os.path.join(self._dir, "ttyDXL")
        self._master: int | None = None
        self._slave: int | None = None
        self._plug()
        self._thread = threading.Thread(target=self._serve, name="dxl-emulator", daemon=True)
        self._thread.start()

    # -- fault knobs ----------------------------------------------------------------
    def drop_next(self, n: int = 1) -> None:
        with self._lock:
            self._drop += n

    def corrupt_next(self, n: int = 1) -> None:
        with self._lock:
            self._corrupt += n

    def clear_faults(self) -> None:
        """Forget pending drops and corruptions (hardware errors stay until REBOOT)."""
        with self._lock:
            self._drop = self._corrupt = 0

    def raise_alert(self, servo_id: int, code: int = 0x20) -> None:
        """Hardware error `code` (bits of register 70, e.g. 0x20 overload) on a servo."""
        with self._lock:
            servo = self.servos[servo_id]
            servo.table[Reg.HARDWARE_ERROR_STATUS] = code
            servo.table[Reg.TORQUE_ENABLE] = 0

    def unplug(self) -> None:
        """The adapter is pulled: the pty closes and `port` no longer names anything."""
        with self._io:
            if self._master is None:
                return
            os.unlink(self.port)
            for fd in (self._master, self._slave):
                os.close(fd)
            self._master = self._slave = None
            self.history.append(Call("unplug", (), "ok"))

    def replug(self) -> None:
        """A new pty under `port`; the servos as they were."""
        with self._io:
            if self._master is None:
                self._plug()
                self.history.append(Call("replug", (), "ok"))

    def _plug(self) -> None:
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)  # bytes pass unchanged: no echo, no CR/LF mapping
        os.symlink(os.ttyname(self._slave), self.port)

    @property
    def plugged(self) -> bool:
        return self._master is not None

    def position_deg(self, servo_id: int) -> float:
        with self._lock:
            self._advance()
            return (self.servos[servo_id].position - CENTER_TICKS) * 360.0 / TICKS_PER_TURN

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        with self._io:
            for fd in (self._master, self._slave):
                try:
                    if fd is not None:
                        os.close(fd)
                except OSError:
                    pass
            self._master = self._slave = None
        shutil.rmtree(self._dir, ignore_errors=True)

    def __enter__(self) -> DxlEmulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- serving --------------------------------------------------------------------
    def _serve(self) -> None:
        buf = bytearray()
        while not self._stop.is_set():
            with self._io:
                plugged = self._master is not None
                if plugged:
                    self._serve_once(self._master, buf)
                else:  # unplugged: what was half-read is lost with the port
                    buf.clear()
            time.sleep(0 if plugged else 0.01)  # `unplug` and `replug` take the pty between turns

    def _serve_once(self, master: int, buf: bytearray) -> None:
        ready, _, _ = select.select([master], [], [], 0.02)
        if not ready:
            return
        try:
            buf += os.read(master, 4096)
            for packet in self._packets(buf):
                reply = self._handle(packet)
                if reply:
                    os.write(master, reply)
        except OSError:
            pass

    def _packets(self, buf: bytearray) -> list[bytes]:
        """Cut complete instruction packets off the front of `buf`, skipping garbage."""
        out = []
        while True:
            start = buf.find(HEADER)
            if start < 0:
                del buf[:max(0, len(buf) - 3)]
                return out
            del buf[:start]
            if len(buf) < 7:
                return out
            total = 7 + int.from_bytes(buf[5:7], "little")
            # A false header in garbage: skip it (shorter than instruction + CRC, or too long).
            if not MIN_PACKET <= total <= MAX_PACKET:
                del buf[:1]
                continue
            if len(buf) < total:
                return out
            out.append(bytes(buf[:total]))
            del buf[:total]

    def _advance(self) -> None:
        now = self.clock()
        for servo in self.servos.values():
            servo.advance(now - self._last)
        self._last = now

    def _handle(self, packet: bytes) -> bytes:
        with self._lock:
            self._advance()
            servo_id, inst = packet[4], packet[7]
            if crc16(packet[:-2]) != int.from_bytes(packet[-2:], "little"):
                self.history.append(Call("bad_crc", (servo_id,), "ignored"))
                return b""
            params = unstuff(packet[8:-2])
            now = self.clock()
            replies = self._dispatch(servo_id, inst, params, now)
            return b"".join(self._deliver(r) for r in replies)

    def _deliver(self, reply: bytes) -> bytes:
        if self._drop > 0 or self.faults.hit("drop"):
            self._drop = max(0, self._drop - 1)
            self.history.append(Call("reply", (reply[4],), "dropped"))
            return b""
        if self._corrupt > 0 or self.faults.hit("corrupt"):
            self._corrupt = max(0, self._corrupt - 1)
            bad = bytearray(reply)
            bad[-3] ^= 0x5A  # a payload byte near the CRC: the CRC check must catch it
            self.history.append(Call("reply", (reply[4],), "corrupted"))
            return bytes(bad)
        return reply

    def _online(self, servo_id: int, now: float) -> EmulatedServo | None:
        servo = self.servos.get(servo_id)
        return servo if servo is not None and now >= servo.offline_until else None

    def _status(self, servo: EmulatedServo, error: int, params: bytes = b"") -> bytes:
        if servo.table[Reg.HARDWARE_ERROR_STATUS]:
            error |= ALERT
        return status_packet(servo.servo_id, error, params)

    def _dispatch(self, servo_id: int, inst: int, p: bytes, now: float) -> list[bytes]:
        name = Inst(inst).name if inst in Inst._value2member_map_ else f"0x{inst:02x}"
        self.history.append(Call(name, (servo_id, p), "ok"))
        if inst == Inst.SYNC_WRITE and len(p) >= 4:
            addr, size = int.from_bytes(p[0:2], "little"), int.from_bytes(p[2:4], "little")
            for i in range(4, len(p) - size, size + 1):
                servo = self._online(p[i], now)
                if servo is not None:
                    self._write(servo, addr, p[i + 1:i + 1 + size])
            return []
        if inst == Inst.SYNC_READ and len(p) >= 4:
            addr, size = int.from_bytes(p[0:2], "little"), int.from_bytes(p[2:4], "little")
            out = []
            for sid in p[4:]:
                servo = self._online(sid, now)
                if servo is not None:
                    out.append(self._status(servo, 0, bytes(servo.table[addr:addr + size])))
            return out
        servo = self._online(servo_id, now)
        if servo is None:
            return []
        if inst == Inst.PING:
            return [self._status(servo, 0, servo.table[0:2] + bytes([servo.table[6]]))]
        if inst == Inst.READ and len(p) == 4:
            addr, size = int.from_bytes(p[0:2], "little"), int.from_bytes(p[2:4], "little")
            if addr + size > TABLE_SIZE:
                return [self._status(servo, PacketError.DATA_RANGE)]
            return [self._status(servo, 0, bytes(servo.table[addr:addr + size]))]
        if inst == Inst.WRITE and len(p) > 2:
            return [self._status(servo, self._write(servo, int.from_bytes(p[0:2], "little"), p[2:]))]
        if inst == Inst.REBOOT:
            reply = self._status(servo, 0)
            servo.reset()
            servo.offline_until = now + self.reboot_s
            return [reply]
        return [self._status(servo, PacketError.INSTRUCTION)]

    @staticmethod
    def _write(servo: EmulatedServo, addr: int, data: bytes) -> int:
        if addr + len(data) > TABLE_SIZE:
            return PacketError.DATA_RANGE
        if any(a in READ_ONLY for a in range(addr, addr + len(data))):
            return PacketError.ACCESS
        if addr == Reg.GOAL_POSITION and len(data) == SIZE[Reg.GOAL_POSITION]:
            if not 0 <= int.from_bytes(data, "little", signed=True) < TICKS_PER_TURN:
                return PacketError.DATA_LIMIT
        if addr == Reg.TORQUE_ENABLE and data[:1] == b"\x01" and servo.table[Reg.HARDWARE_ERROR_STATUS]:
            return PacketError.RESULT_FAIL  # torque stays off until a reboot clears the error
        servo.table[addr:addr + len(data)] = data
        if addr <= Reg.TORQUE_ENABLE < addr + len(data) and servo.table[Reg.TORQUE_ENABLE] == 0:
            servo.set(Reg.GOAL_POSITION, round(servo.position))
        return PacketError.NONE
