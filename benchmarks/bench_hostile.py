"""The operator's page under hostile clients, the station at the common limit of 1024 file
descriptors: `cmd ping`'s time (a PING through the station's control socket to a fake robot
and back) and the station's memory, idle and while a flood is held open: 1,120 connections
each with half a request's headers (slowloris), and 2,000 event streams asked for from 20
addresses. The figures are the station's own against its idle ones, measured in one run.
"""
from __future__ import annotations

import resource
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from urllib.parse import urlsplit

from benchmarks.browser import page_address
from benchmarks.common import Context, Section
from benchmarks.hostile_clients import (
    event_streams, half_requests, limit_fds, pings_s, room_for_sockets, rss_kb, until)

ROOT = Path(__file__).resolve().parents[1]
ROBOT = ('[hal]\nbody = "fake"\nscene = "mixed"\nsize = [40, 60]\n[link]\nkey_file = "robot.key"\n'
         'heartbeat_s = 0.2\nfailsafe_s = 30\n[segment]\nmethod = "scene"\n[sweep]\nautostart = false\n')


def _python(module: str) -> list[str]:
    return [sys.executable, "-c", f"import sys; from {module} import main; sys.exit(main())"]


def measure(where: Path, slow: int, streams: int, pings: int) -> list[tuple[str, str, list[float], int]]:
    """(flood, what the clients met, ping times s, station's memory KiB) idle, then per flood."""
    from radio.keys import write_key
    from tools.demo.pty_cable import PtyCable
    from tools.station.control import socket_path

    cable, key, db = PtyCable(), write_key(where / "robot.key"), where / "host.db"
    (where / "robot.toml").write_text(ROBOT)
    quiet = dict(cwd=ROOT, stdout=subprocess.DEVNULL)
    robot = subprocess.Popen([*_python("onboard.cli"), "run", "--config", str(where / "robot.toml"), "--port",
                              cable.paths[0], "--max-seconds", "600"], stderr=subprocess.DEVNULL, **quiet)
    station = subprocess.Popen([*_python("tools.cli"), "station", "--port", cable.paths[1], "--db", str(db), "--key",
                                str(key), "--http", "127.0.0.1:0"], stderr=open(where / "station.err", "wb"),
                               preexec_fn=limit_fds, **quiet)
    rows = []
    try:
        url = urlsplit(page_address(where / "station.err"))
        address, sock = (url.hostname, url.port), socket_path(db)
        assert until(lambda: _answers(sock), 60), "the robot never answered a PING"
        time.sleep(1.0)  # the page's first snapshots out
        rows.append(("none (idle)", "", pings_s(sock, pings), rss_kb(station.pid)))
        floods = ((f"{slow:,} half-sent requests", lambda: half_requests(address, url.netloc, slow)),
                  (f"{streams:,} event streams from 20 addresses",
                   lambda: event_streams(address, url.netloc, url.query.removeprefix("token="), streams, 20)))
        for i, (name, open_flood) in enumerate(floods):
            flood = open_flood()
            until(lambda: sum(c.state() == "open" for c in flood) <= 256, 60)  # the refusals are in
            met = Counter(c.state() for c in flood)
            said = ", ".join(f"{n} {'streaming' if k == '200' else 'held open' if k == 'open' else k}"
                             for k, n in sorted(met.items()))
            rows.append((name, said, pings_s(sock, pings), rss_kb(station.pid)))
            for c in flood:
                c.close()
            if i < len(floods) - 1:  # the next flood meets a station that has seen this one go
                time.sleep(2.0)
        assert station.poll() is None, (where / "station.err").read_text()[-2000:]
    finally:
        for p in (station, robot):
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
                p.wait(timeout=30)
        cable.close()
    return rows


def _answers(sock: Path) -> bool:
    from benchmarks.hostile_clients import ping_s

    try:
        return ping_s(sock) < 30
    except (OSError, RuntimeError, TimeoutError):
        return False


def run(ctx: Context | None = None) -> Section:
    ctx = ctx or Context()
    slow, streams, pings = ctx.pick((1120, 2000, 15), (300, 300, 3))
    before = room_for_sockets(max(slow, streams))
    if before is None:
        return Section("Operator page under hostile clients", ["Not run: this process may not open enough sockets."])
    try:
        with tempfile.TemporaryDirectory(prefix="bench-hostile-") as tmp:
            rows = measure(Path(tmp), slow, streams, pings)
    finally:
        resource.setrlimit(resource.RLIMIT_NOFILE, before)
    idle_rss = rows[0][3]
    lines = ["The station a separate process at 1024 file descriptors, its page on 127.0.0.1, a fake robot "
             f"on a pty cable; {pings} PINGs through the station's socket per row, the flood held open meanwhile.",
             "", "| flood | what its clients met | ping median ms | ping worst ms | station's memory MB | vs idle |",
             "|---|---|---:|---:|---:|---:|"]
    for name, met, times, rss in rows:
        lines.append(f"| {name} | {met or '-'} | {statistics.median(times) * 1e3:.0f} | {max(times) * 1e3:.0f} | "
                     f"{rss / 1024:.0f} | {rss / idle_rss:.2f}x |")
    return Section("Operator page under hostile clients", lines + [""])
