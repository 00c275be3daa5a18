"""Room on the disk under the robot's state directory, and a reserve for the writes that free it.

On a full disk SQLite cannot even delete an acknowledged row (the delete goes through the WAL),
so a robot whose disk filled would keep its outbox and its paused acquisition for ever, and say
nothing. The robot therefore holds `disk_reserve_bytes` in a file beside the outbox, released
when a write that frees room or says why finds the disk full (`Outbox(on_full=...)`), and made
again once the disk has room. Acquisition pauses while fewer than `disk_min_free_bytes` are
free (it never fills the disk itself), and while a write failed for lack of room: until
`disk_min_free_bytes` plus the reserve are free again.
"""
from __future__ import annotations

import enum
import errno
import os
from pathlib import Path
from typing import Callable

RESERVE_NAME = "disk.reserve"


class Pressure(enum.StrEnum):
    OK = "ok"  # room enough: acquisition runs
    LOW = "low"  # fewer than min_free bytes free: acquisition paused before the disk fills
    FULL = "full"  # a write failed for lack of room: paused until min_free + reserve are free


class Disk:
    def __init__(self, state_dir: Path, min_free: int, reserve: int,
                 statvfs: Callable[[Path], os.statvfs_result] = os.statvfs) -> None:
        self.state_dir, self.min_free, self.reserve = Path(state_dir), min_free, reserve
        self.reserve_path = self.state_dir / RESERVE_NAME
        self._statvfs = statvfs
        self.failed = ""  # why the last write failed for lack of room, until room is back
        self.unheld = ""  # why the reserve cannot be held here at all

    def free(self) -> int | None:
        """Bytes an unprivileged writer may still use under the state directory (None: unknown)."""
        try:
            st = self._statvfs(self.state_dir)
        except OSError:
            return None
        return int(st.f_bavail) * int(st.f_frsize)

    def held(self) -> bool:
        try:
            return self.reserve_path.stat().st_size >= self.reserve
        except OSError:
            return False

    def hold(self) -> bool:
        """Make the reserve file (allocated, not sparse); whether it is held. Best effort: a
        filesystem that cannot hold it leaves the robot without it, said once in `unheld`."""
        if self.reserve <= 0 or self.held():
            return True
        if self.unheld:
            return False
        try:
            fd = os.open(self.reserve_path, os.O_WRONLY | os.O_CREAT, 0o600)
            try:
                try:
                    os.posix_fallocate(fd, 0, self.reserve)
                except OSError as exc:
                    if exc.errno not in (errno.EOPNOTSUPP, errno.EINVAL):
                        raise
                    for start in range(0, self.reserve, 1 << 16):  # no fallocate here: zeros
                        os.pwrite(fd, bytes(min(1 << 16, self.reserve - start)), start)
                os.fsync(fd)
            finally:
                os.close(fd)
            return True
        except OSError as exc:
            self.reserve_path.unlink(missing_ok=True)
            if exc.errno not in (errno.ENOSPC, errno.EDQUOT, errno.EFBIG):
                self.unheld = f"cannot hold {self.reserve_path}: {exc.strerror or exc}"
            return False

    def release(self) -> bool:
        """Free the reserve for the writes that must still happen; whether it freed any."""
        try:
            self.reserve_path.unlink()
            return True
        except FileNotFoundError:
            return False

    def write_failed(self, why: str) -> None:
        """A write found the disk full: release the reserve and pause until there is room."""
        self.failed = why
        self.release()

    def pressure(self) -> Pressure:
        """The disk's state now; makes the reserve again once there is room for it."""
        free = self.free()
        if free is None:
            return Pressure.FULL if self.failed else Pressure.OK
        if self.failed and free >= self.min_free + self.reserve:
            self.failed = ""
        if self.failed:
            return Pressure.FULL
        if free < self.min_free:
            return Pressure.LOW
        if free >= self.min_free + self.reserve and not self.held():
            self.hold()
        return Pressure.OK
