"""A real small disk for test processes: a size-limited tmpfs in a private mount namespace.

Full-disk behaviour is the kernel's and SQLite's (ENOSPC, SQLITE_FULL, a WAL that cannot grow),
so the tests run the robot or the host on a real filesystem that fills, rather than on writes
made to fail. `unshare -Urm` (an unprivileged user may do it where user namespaces are allowed)
starts a holder process with its own mount namespace, in which a tmpfs of a few MiB is mounted
over an empty directory; processes started with `SmallDisk.argv` join that namespace (nsenter),
so the disk outlives each of them, as a robot's SD card outlives a restart. The test fills and
frees it through `/proc/<holder>/root`. Where namespaces are not available these tests are
skipped with the reason.
"""
from __future__ import annotations

import functools
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.support import ROOT


@functools.cache
def unavailable() -> str:
    """Why a small disk cannot be made here ("" when it can)."""
    if shutil.which("unshare") is None or shutil.which("nsenter") is None:
        return "no unshare(1) or nsenter(1)"
    probe = subprocess.run(["unshare", "-Urm", "sh", "-c", 'd=$(mktemp -d) && mount -t tmpfs -o size=1m tmpfs "$d"'],
                           capture_output=True, text=True, timeout=30)
    return "" if probe.returncode == 0 else f"cannot mount a tmpfs in a mount namespace: {probe.stderr.strip()}"


class SmallDisk:
    """A tmpfs of `size` bytes at `mountpoint` (an existing, empty directory), seen by the
    processes run through `argv` and, from here, at `path`."""

    def __init__(self, mountpoint: Path, size: int) -> None:
        why = unavailable()
        if why:
            pytest.skip(why)
        self.mountpoint = Path(mountpoint)
        self._holder = subprocess.Popen(
            ["unshare", "-Urm", "sh", "-c", 'mount -t tmpfs -o "size=$1" tmpfs "$0" && echo up && exec sleep 3600',
             str(self.mountpoint), str(size)], stdout=subprocess.PIPE, text=True)
        if self._holder.stdout.readline().strip() != "up":
            self.close()
            pytest.skip("the small disk did not mount")
        self.path = Path(f"/proc/{self._holder.pid}/root") / self.mountpoint.relative_to("/")

    def argv(self, argv: list[str]) -> list[str]:
        """`argv` run inside the small disk's namespace, in the project's directory (entering a
        mount namespace resets the working directory; `python -c` imports from it)."""
        return ["nsenter", "-t", str(self._holder.pid), "-U", "-m", "--preserve-credentials", f"--wd={ROOT}", *argv]

    def free(self) -> int:
        st = os.statvfs(self.path)
        return st.f_bavail * st.f_frsize

    def fill(self, name: str = "filler") -> int:
        """Write zeros into the disk until it is full; the bytes written."""
        written = 0
        with open(self.path / name, "wb", buffering=0) as f:
            for size in (1 << 16, 4096, 512, 1):  # the last partial blocks too: nothing is left
                while True:
                    try:
                        n = f.write(bytes(size))
                    except OSError:
                        break
                    if not n:
                        break
                    written += n
        return written

    def close(self) -> None:
        if self._holder.poll() is None:
            self._holder.kill()
        self._holder.wait(timeout=10)


def python(*code_then_args: str) -> list[str]:
    """`python -c CODE ARGS...` with the project importable."""
    return [sys.executable, "-c", *code_then_args]


def robot_argv(*args: str) -> list[str]:
    return python("import sys; from onboard.cli import main; sys.exit(main())", *args)


def wait_for(predicate, limit_s: float) -> bool:
    end = time.monotonic() + limit_s
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(0.02)
    return predicate()
