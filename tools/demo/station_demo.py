"""`btf-host station --demo [DIR]`: the operator's page on a fake robot, in one command.

A fake robot (`btf-robot run --hal fake`, the mixed sand plate with its grey card) runs on one
end of a pty cable (`tools.demo.pty_cable`), the station on the other, with the page; the robot
sweeps 90..30° by 10° at azimuths 0 and 90 and then waits for commands. Its key, config, state
and the database live in DIR (kept between runs: the sweep resumes, the captures stay). The
page shows the robot's renders as the measured frames. Ctrl-C stops both.
"""
from __future__ import annotations

import asyncio
import subprocess
import sys
from pathlib import Path

from onboard.cli.runner import CliError
from onboard.config import load
from radio.keys import write_key
from tools.demo.pty_cable import PtyCable
from tools.page.data import end_with_parent
from tools.station.events import StationEvent
from tools.station.start import open_station, serve_to_exit

ROBOT_CONFIG = """\
# The fake robot of `btf-host station --demo`.
robot_id = 1
state_dir = "robot-state"
[hal]
body = "fake"
scene = "mixed"
size = [90, 120]
reference = true
[link]
key_file = "robot.key"
heartbeat_s = 0.5
failsafe_s = 3
[features]
dependence = true
[segment]
method = "scene"
[skip]
min_pixels = 20
[sweep]
start = 90
stop = 30
step = 10
azimuths = [0, 90]
"""


def prepare(where: Path) -> tuple[Path, Path, Path]:
    """DIR's key, robot config and database paths, the first two written when absent."""
    try:
        where.mkdir(parents=True, exist_ok=True)
        key, config = where / "robot.key", where / "robot.toml"
        if not key.exists():
            write_key(key)
        if not config.exists():
            config.write_text(ROBOT_CONFIG, encoding="utf-8")
    except OSError as exc:
        raise CliError(f"--demo {where}: {exc.strerror or exc}") from None
    return key, config, where / "scene.db"


def start_robot(config: Path, port: str, log: Path) -> subprocess.Popen:
    """The fake robot, in DIR (its config's paths are the config's own: absolute, whatever DIR was given as)."""
    config = config.resolve()
    with open(log, "ab") as err:
        return subprocess.Popen([sys.executable, "-c", "import sys; from onboard.cli import main; sys.exit(main())",
                                 "run", "--config", str(config), "--port", port], cwd=config.parent,
                                stdout=subprocess.DEVNULL, stderr=err, preexec_fn=end_with_parent,
                                start_new_session=True)  # Ctrl-C stops the station, which then ends the robot


def last_line(log: Path) -> str:
    """The robot log's last line (what a robot that ended said last), '' when there is none."""
    try:
        with open(log, "rb") as f:
            f.seek(max(0, f.seek(0, 2) - 4096))
            lines = f.read().decode(errors="replace").strip().splitlines()
    except OSError:
        return ""
    return lines[-1].strip() if lines else ""


def watch_robot(robot: subprocess.Popen, log: Path, every: float = 0.2):
    """A companion of the station (`serve(beside=...)`): when the robot's process ends, one station
    event says so, with the robot's last words and where its log is; the station and page stay up."""

    async def watch(station) -> None:
        while robot.poll() is None:
            await asyncio.sleep(every)
        said = last_line(log)
        station.emit(StationEvent(station.wall(), f"demo robot failed: its process exited with status "
                                  f"{robot.returncode}" + (f" ({said})" if said else "") + f"; its log: {log}",
                                  failed=True))

    return watch


def stop_robot(robot: subprocess.Popen) -> None:
    if robot.poll() is None:
        robot.terminate()
        try:
            robot.wait(timeout=10)
        except subprocess.TimeoutExpired:
            robot.kill()
            robot.wait()


def run_demo(where: Path, page, status_every: float) -> int:
    """The fake robot and the station with its page, until Ctrl-C or SIGTERM; exit status 1 when
    the robot had ended on its own."""
    key, config, db = prepare(where)
    try:
        page.fake = load(config).fake_hal
    except ValueError as exc:  # onboard.config.ConfigError: a robot.toml edited in DIR
        raise CliError(f"--demo {where}: {exc}; mend it, or delete it for the demo's own") from None
    cable = PtyCable()
    robot = start_robot(config, cable.paths[0], where / "robot.log")
    try:
        print(f"demo: a fake robot on {cable.paths[0]} (its log: {where / 'robot.log'}), the station on "
              f"{cable.paths[1]}, database {db}", file=sys.stderr, flush=True)
        parts = open_station(cable.paths[1], str(key), str(db), status_every=status_every)
        code = serve_to_exit(parts, page, beside=watch_robot(robot, where / "robot.log"))
        return code or (1 if robot.poll() is not None else 0)  # a robot that ended on its own: a failed demo
    finally:
        stop_robot(robot)
        cable.close()
