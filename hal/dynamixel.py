"""Dynamixel X-series servos over Protocol 2.0, through dynamixel-sdk.

Degrees at the interface, ticks (4096 per turn, 2048 = 0°) inside. A value is used only
when the SDK reports COMM_SUCCESS, no packet error and the expected payload length; a
timeout or corrupt reply is retried a bounded number of times, then raises an error naming
the servo and the port. A status with the alert bit (0x80) makes the driver read the
hardware error status, reboot the servo, restore torque and goal, and redo the request.
A port that fails under a request (its USB adapter unplugged: EIO, then the device node gone)
raises `DeviceGone`; the next request opens it again and, once it opens, restores torque and
goals as after a reboot, then goes on.
"""
from __future__ import annotations

import math
import os
import termios
import threading
import time

import dynamixel_sdk as sdk

from hal.dynamixel_table import ALERT, CENTER_TICKS, SIZE, TICKS_PER_TURN, Reg
from hal.interfaces import DeviceGone, DeviceTimeout, HalError, LimitError, ServoRecovery


def deg_to_ticks(deg: float) -> int:
    if not math.isfinite(deg):
        raise LimitError(f"goal {deg}° is not a finite angle")
    ticks = round(CENTER_TICKS + deg * TICKS_PER_TURN / 360.0)
    if not 0 <= ticks < TICKS_PER_TURN:
        raise LimitError(f"goal {deg:.2f}° is outside the servo's range [-180°, 180°)")
    return ticks


def ticks_to_deg(ticks: int) -> float:
    return (ticks - CENTER_TICKS) * 360.0 / TICKS_PER_TURN


class _Port(sdk.PortHandler):
    """PortHandler with a configurable USB latency (the SDK hard-codes 16 ms)."""

    def __init__(self, port_name: str, latency_ms: float) -> None:
        super().__init__(port_name)
        self.latency_ms = latency_ms

    def setPacketTimeout(self, packet_length: int) -> None:  # noqa: N802 (SDK name)
        self.packet_start_time = self.getCurrentTime()
        self.packet_timeout = self.tx_time_per_byte * packet_length + self.latency_ms * 2.0 + 2.0


class _Failed(Exception):
    """One attempt failed on the wire (timeout, corrupt or short reply): worth a retry."""

    def __init__(self, reason: str, timeout: bool = False) -> None:
        super().__init__(reason)
        self.timeout = timeout


def _comm_failure(ph: sdk.PacketHandler, sid: int, result: int) -> _Failed:
    reason = ph.getTxRxResult(result).removeprefix("[TxRxResult] ").rstrip("!")
    return _Failed(f"servo {sid}: {reason}", timeout=result == sdk.COMM_RX_TIMEOUT)


def _packet_error(ph: sdk.PacketHandler, sid: int, port: str, what: str, error: int) -> HalError:
    """The servo understood and refused: retrying would not help."""
    reason = ph.getRxPacketError(error & ~ALERT).removeprefix("[RxPacketError] ").rstrip("!")
    return HalError(f"servo {sid} on {port}: {what} refused ({reason})")


class _Alert(Exception):
    def __init__(self, servo_id: int) -> None:
        super().__init__(servo_id)
        self.servo_id = servo_id


class DynamixelServoBus:
    """The `ServoBus` for a chain of X-series servos on one serial port."""

    def __init__(
        self,
        port: str,
        baudrate: int = 1_000_000,
        *,
        retries: int = 3,
        latency_ms: float = 16.0,
        profile_velocity: int = 0,
        reboot_timeout_s: float = 2.0,
        max_recoveries: int = 2,
    ) -> None:
        if retries < 1:
            raise ValueError("retries must be at least 1")
        self.port_name = port
        self.retries = retries
        self.profile_velocity = profile_velocity
        self.reboot_timeout_s = reboot_timeout_s
        self.max_recoveries = max_recoveries
        self.recoveries: list[ServoRecovery] = []
        self._lock = threading.RLock()
        self._goals: dict[int, int] = {}
        self._torque: dict[int, bool] = {}
        self._lost = False  # the port failed under a request: open it again before the next
        self._closed = False
        self._port = _Port(port, latency_ms)
        self._ph = sdk.PacketHandler(2.0)
        try:
            opened = self._port.setBaudRate(baudrate)  # opens the port at that rate
        except Exception as exc:  # pyserial raises SerialException/OSError/ValueError
            raise HalError(f"cannot open servo port {port}: {exc}") from exc
        if not opened:
            raise HalError(f"cannot open servo port {port} at {baudrate} baud (unsupported rate)")

    # -- ServoBus -------------------------------------------------------------------
    def ping(self, servo_id: int) -> bool:
        with self._lock:
            try:
                self._call(servo_id, "ping", lambda: self._ph.ping(self._port, servo_id)[1:], alerts=False)
            except HalError:
                return False
            return True

    def set_torque(self, servo_ids: list[int], enabled: bool) -> None:
        with self._lock:
            for sid in servo_ids:
                self._torque[sid] = enabled
                if enabled and self.profile_velocity:
                    self._write(sid, Reg.PROFILE_VELOCITY, self.profile_velocity)
                self._write(sid, Reg.TORQUE_ENABLE, int(enabled))
                if not enabled:
                    self._goals.pop(sid, None)

    def move(self, goals_deg: dict[int, float]) -> None:
        ticks = {sid: deg_to_ticks(deg) for sid, deg in goals_deg.items()}  # all checked first
        if not ticks:
            return
        with self._lock:
            size = SIZE[Reg.GOAL_POSITION]
            group = sdk.GroupSyncWrite(self._port, self._ph, Reg.GOAL_POSITION, size)
            for sid, t in ticks.items():
                group.addParam(sid, list(t.to_bytes(size, "little")))
            # Broadcast: no status comes back, so only a transmit failure is visible.
            self._call(min(ticks), "sync write goal", lambda: (group.txPacket(), 0), alerts=False)
            self._goals.update(ticks)  # sent: what a reboot or a reopened port restores

    def positions(self, servo_ids: list[int]) -> dict[int, float]:
        raw = self._sync_read(servo_ids, Reg.PRESENT_POSITION)
        return {sid: ticks_to_deg(v) for sid, v in raw.items()}

    def is_moving(self, servo_ids: list[int]) -> bool:
        return any(self._sync_read(servo_ids, Reg.MOVING).values())

    def hardware_error(self, servo_id: int) -> int:
        with self._lock:
            return self._read(servo_id, Reg.HARDWARE_ERROR_STATUS, alerts=False)

    def reboot(self, servo_id: int) -> None:
        """Reboot a servo, wait until it answers again, and restore its torque and goal."""
        with self._lock:
            self._call(servo_id, "reboot", lambda: self._ph.reboot(self._port, servo_id), alerts=False)
            deadline = time.monotonic() + self.reboot_timeout_s
            while not self.ping(servo_id):
                if time.monotonic() > deadline:
                    raise DeviceTimeout(f"servo {servo_id} on {self.port_name} did not come back after reboot")
                time.sleep(0.005)
            if self._torque.get(servo_id):
                if self.profile_velocity:
                    self._write(servo_id, Reg.PROFILE_VELOCITY, self.profile_velocity, alerts=False)
                self._write(servo_id, Reg.TORQUE_ENABLE, 1, alerts=False)
            if servo_id in self._goals:
                self._write(servo_id, Reg.GOAL_POSITION, self._goals[servo_id], alerts=False)

    def close(self) -> None:
        with self._lock:
            self._closed = True
            if self._port.is_open:
                self._port.closePort()

    # -- transactions ---------------------------------------------------------------
    def _write(self, sid: int, reg: Reg, value: int, alerts: bool = True) -> None:
        fn = {1: self._ph.write1ByteTxRx, 4: self._ph.write4ByteTxRx}[SIZE[reg]]
        self._call(sid, f"write {reg.name.lower()}", lambda: fn(self._port, sid, reg, value), alerts)

    def _read(self, sid: int, reg: Reg, alerts: bool = True) -> int:
        size = SIZE[reg]

        def attempt() -> tuple[int, int]:
            data, result, error = self._ph.readTxRx(self._port, sid, reg, size)
            if result == sdk.COMM_SUCCESS and len(data) != size:
                raise _Failed(f"servo {sid}: reply of {len(data)} bytes, expected {size}")
            return (_unpack(data, size) if result == sdk.COMM_SUCCESS else 0), result, error

        return self._call(sid, f"read {reg.name.lower()}", attempt, alerts)

    def _sync_read(self, servo_ids: list[int], reg: Reg) -> dict[int, int]:
        """Read one register of several servos in one SYNC_READ, retried as a whole."""
        size = SIZE[reg]
        ids = list(dict.fromkeys(servo_ids))
        if not ids:
            return {}
        with self._lock:
            for _ in range(self.max_recoveries + 1):
                try:
                    return self._retry(ids[0], f"sync read {reg.name.lower()}", lambda: self._sync_once(ids, reg, size))
                except _Alert as alert:
                    self._recover(alert.servo_id)
            raise HalError(f"servo alert persists after {self.max_recoveries} reboots on {self.port_name}")

    def _sync_once(self, ids: list[int], reg: Reg, size: int) -> dict[int, int]:
        result = self._ph.syncReadTx(self._port, reg, size, ids, len(ids), False)
        if result != sdk.COMM_SUCCESS:
            raise _comm_failure(self._ph, ids[0], result)
        out, alerted = {}, None
        for sid in ids:
            data, result, error = self._ph.readRx(self._port, sid, size)
            if result != sdk.COMM_SUCCESS:
                raise _comm_failure(self._ph, sid, result)
            if error & ALERT:
                alerted = sid if alerted is None else alerted
            elif error:
                raise _packet_error(self._ph, sid, self.port_name, f"sync read {reg.name.lower()}", error)
            elif len(data) != size:
                raise _Failed(f"servo {sid}: reply of {len(data)} bytes, expected {size}")
            else:
                out[sid] = _unpack(data, size)
        if alerted is not None:
            raise _Alert(alerted)
        return out

    def _call(self, sid: int, what: str, attempt, alerts: bool = True):
        """Run an SDK call returning (value..., result, error) with retries and alert handling."""

        def checked():
            *value, result, error = attempt()
            if result != sdk.COMM_SUCCESS:
                raise _comm_failure(self._ph, sid, result)
            # An alerted servo refuses some requests (torque on): recover first, then redo.
            if error & ALERT and alerts:
                raise _Alert(sid)
            if error & ~ALERT:
                raise _packet_error(self._ph, sid, self.port_name, what, error)
            return value[0] if value else None

        with self._lock:
            for _ in range(self.max_recoveries + 1):
                try:
                    return self._retry(sid, what, checked)
                except _Alert:
                    self._recover(sid)
            raise HalError(f"servo {sid} on {self.port_name}: alert persists after {self.max_recoveries} reboots")

    def _retry(self, sid: int, what: str, attempt):
        if self._lost and not self._closed:
            self._reopen(sid, what)
        failure = _Failed("not attempted")
        try:
            for _ in range(self.retries):
                try:
                    return attempt()
                except _Failed as exc:
                    failure = exc
                    # A late reply must not be taken for the next request's answer.
                    time.sleep(self._port.latency_ms / 1000.0)
                    self._port.clearPort()
        except (OSError, termios.error) as exc:  # the port itself failed: unplugged or closed
            self._port.is_using = False  # the SDK leaves its busy flag set when a write raises
            if self._closed:
                raise HalError(f"servo {sid} on {self.port_name}: {what}: port failed ({exc})") from exc
            self._lost = True
            try:
                self._port.closePort()
            except (OSError, termios.error):
                pass
            raise DeviceGone(f"servo {sid} on {self.port_name}: {what}: port failed ({_why(exc)}); unplugged?") from exc
        error = DeviceTimeout if failure.timeout else HalError
        raise error(f"servo {sid} on {self.port_name}: {what} failed {self.retries} times (last: {failure})")

    def _reopen(self, sid: int, what: str) -> None:
        """Open the port that failed; once it is back, torque and goals as they were. DeviceGone
        while it is not there."""
        try:
            opened = self._port.openPort()
        except Exception as exc:  # pyserial: SerialException (an OSError) naming the missing node
            opened, why = False, _why(exc)
        else:
            why = "it would not open"
        if not opened:
            raise DeviceGone(f"servo {sid} on {self.port_name}: {what}: port not there ({why}); unplugged?")
        self._lost = False
        for servo, on in self._torque.items():
            if on:
                if self.profile_velocity:
                    self._write(servo, Reg.PROFILE_VELOCITY, self.profile_velocity, alerts=False)
                self._write(servo, Reg.TORQUE_ENABLE, 1, alerts=False)
        for servo, goal in self._goals.items():
            self._write(servo, Reg.GOAL_POSITION, goal, alerts=False)

    def _recover(self, sid: int) -> None:
        code = self.hardware_error(sid)
        self.recoveries.append(ServoRecovery(sid, code))
        self.reboot(sid)


def _why(exc: Exception) -> str:
    """An OS error as a person reads it: "Input/output error" rather than (5, '...') or a path twice."""
    number = getattr(exc, "errno", None)
    if not isinstance(number, int) and exc.args and isinstance(exc.args[0], int):  # termios.error
        number = exc.args[0]
    return os.strerror(number) if isinstance(number, int) else str(exc)


def _unpack(data: list[int], size: int) -> int:
    return int.from_bytes(bytes(data[:size]), "little", signed=size == 4)
