"""A fake robot, a station and `cmd` clients as separate processes on a real pty cable, for the
station's tests (tests/test_station*.py)."""
from __future__ import annotations

import http.client
import json
import os
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path
from urllib.parse import urlsplit

from radio.keys import write_key
from tests.support import ROOT
from tests.support.browser import page_address
from tests.support.robots import EVERY_POSE, IDLE, LINKED, robot_toml
from tools.demo.pty_cable import PtyCable
from tools.station.control import StationClient, socket_path
from tools.store.database import Store

# The rig's robot: on a real link, measuring every pose.
ROBOT = (LINKED, EVERY_POSE)
# The robot's own sweep of the 60 poses, at boot (the others wait for a SWEEP command).
AUTONOMOUS = {"sweep": {"start": 90, "stop": 32, "step": 2, "azimuths": [0, 90]}}

# 60 poses: 30 elevations at two azimuths
PLAN = ["--start", "90", "--stop", "32", "--step", "2", "--azimuths", "0,90"]
POSES = sorted((90.0 - 2.0 * i, a) for a in (0.0, 90.0) for i in range(30))


def python(module: str) -> list[str]:
    return [sys.executable, "-c", f"import sys; from {module} import main; sys.exit(main())"]


class Rig:
    def __init__(self, where: Path, *changes: dict, **top: object) -> None:
        """A rig in `where`: the robot is ROBOT with `changes` (IDLE when none are given) and
        the top-level keys `top`."""
        self.where = where
        self.cable = PtyCable()
        self.key = write_key(where / "robot.key")
        self.db = where / "host.db"
        (where / "robot.toml").write_text(robot_toml(*ROBOT, *(changes or (IDLE,)), **top))
        self.procs: list[subprocess.Popen] = []
        self.stations = 0

    # -- processes -------------------------------------------------------------------------
    def robot(self, *argv: str) -> subprocess.Popen:
        err = open(self.where / "robot.err", "ab")
        p = subprocess.Popen([*python("onboard.cli"), "run", "--config", str(self.where / "robot.toml"),
                              "--port", self.cable.paths[0], "--max-seconds", "300", *argv],
                             cwd=ROOT, stdout=subprocess.DEVNULL, stderr=err)
        self.procs.append(p)
        return p

    def station(self, *argv: str, key: Path | None = None, env: dict[str, str] | None = None,
                preexec_fn=None) -> subprocess.Popen:
        """`btf-host station` on the cable (`env`: added to this process's environment)."""
        self.stations += 1
        err = open(self.where / f"station-{self.stations}.err", "wb")
        p = subprocess.Popen([*python("tools.cli"), "station", "--port", self.cable.paths[1], "--db", str(self.db),
                              "--key", str(key or self.key), "--status-every", "1", *argv],
                             cwd=ROOT, stdout=subprocess.DEVNULL, stderr=err,
                             env=None if env is None else {**os.environ, **env}, preexec_fn=preexec_fn)
        self.procs.append(p)
        return p

    def wait_up(self, station: subprocess.Popen, limit_s: float = 60.0) -> None:
        """Until `station` answers on its socket (a killed one's stale socket refuses)."""
        end = time.monotonic() + limit_s
        while time.monotonic() < end:
            assert station.poll() is None, (self.where / f"station-{self.stations}.err").read_text()
            client = StationClient.connect(socket_path(self.db), timeout=5)
            if client is not None:
                client.close()
                return
            time.sleep(0.02)
        raise AssertionError("the station never served its socket")

    def cmd(self, *argv: str, timeout: float = 60.0) -> tuple[int, list[dict], str]:
        """`btf-host cmd --db DB --json ...`: (exit status, the JSON lines it printed, stderr)."""
        out = subprocess.run([*python("tools.cli"), "cmd", "--db", str(self.db), "--timeout", str(timeout),
                              "--json", *argv], cwd=ROOT, capture_output=True, text=True, timeout=timeout + 60)
        return out.returncode, [json.loads(line) for line in out.stdout.splitlines()], out.stderr

    def snapshot(self) -> dict:
        client = StationClient.connect(socket_path(self.db), timeout=10)
        assert client is not None
        try:
            client.send({"op": "snapshot"})
            return client.receive(timeout=10)["snapshot"]
        finally:
            client.close()

    def stop(self, p: subprocess.Popen) -> int:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
        return p.wait(timeout=30)

    def close(self) -> None:
        for p in self.procs:
            if p.poll() is None:
                p.kill()
                p.wait()
        self.cable.close()

    # -- what the host holds -----------------------------------------------------------------
    def captures(self) -> list:
        with Store.open(self.db) as store:
            return store.captures()

    def wait_for_poses(self, poses: list, limit_s: float = 180.0, robot: subprocess.Popen | None = None) -> None:
        end = time.monotonic() + limit_s
        while time.monotonic() < end:
            if robot is not None and robot.poll() is not None:
                break
            if self.db.exists() and set(poses) <= set(self.commanded()):
                return
            time.sleep(0.2)
        assert set(poses) <= set(self.commanded()), sorted(set(poses) - set(self.commanded()))

    def commanded(self) -> Counter:
        return Counter((c.commanded[0], c.commanded[1]) for c in self.captures())

    def log(self) -> list[dict]:
        path = Path(str(self.db) + ".log")
        return [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []


def robot_log(where: Path) -> list[str]:
    return (where / "robot.err").read_text(encoding="utf-8").splitlines()


def kill9(p: subprocess.Popen) -> None:
    os.kill(p.pid, signal.SIGKILL)
    p.wait(timeout=30)

def served(rig, *argv):
    """A station serving the page on a free port: (process, host, port, token)."""
    station = rig.station("--http", "127.0.0.1:0", *argv)
    url = urlsplit(page_address(rig.where / f"station-{rig.stations}.err"))
    token = url.query.removeprefix("token=")
    return station, url.hostname, url.port, token


def request(host, port, method, path, body=None, headers=None):
    """One HTTP request: (status, headers, body)."""
    conn = http.client.HTTPConnection(host, port, timeout=30)
    try:
        conn.request(method, path, body=body, headers=headers or {})
        resp = conn.getresponse()
        return resp.status, dict(resp.getheaders()), resp.read()
    finally:
        conn.close()
