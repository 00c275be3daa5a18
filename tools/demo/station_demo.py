"""`btf-host station --demo [DIR]`: the operator's page on a fake robot, in one command.

A fake robot (`btf-robot run --hal fake`, the mixed sand plate with its grey card) runs on one
end of a pty cable (`tools.demo.pty_cable`), the station on the other, with the page; the robot
sweeps 90..30° by 10° at azimuths 0 and 90 and then waits for commands. Its key, config, state
and the database live in DIR (kept between runs: the sweep resumes, the captures stay). The
page shows the robot's renders as the measured frames. Ctrl-C stops both.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from onboard.cli.runner import CliError
from radio.keys import write_key
from tools.demo.pty_cable import PtyCable
from tools.page.data import end_with_parent
from tools.report.capture_views import Frames
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
    with open(log, "ab") as err:
        return subprocess.Popen([sys.executable, "-c", "import sys; from onboard.cli import main; sys.exit(main())",
                                 "run", "--config", str(config), "--port", port], cwd=config.parent,
                                stdout=subprocess.DEVNULL, stderr=err, preexec_fn=end_with_parent)


def stop_robot(robot: subprocess.Popen) -> None:
    if robot.poll() is None:
        robot.terminate()
        try:
            robot.wait(timeout=10)
        except subprocess.TimeoutExpired:
            robot.kill()
            robot.wait()


def run_demo(where: Path, page, status_every: float) -> int:
    """The fake robot and the station with its page, until Ctrl-C or SIGTERM."""
    key, config, db = prepare(where)
    page.fake = Frames.from_robot_config(config).fake
    cable = PtyCable()
    robot = start_robot(config, cable.paths[0], where / "robot.log")
    try:
        print(f"demo: a fake robot on {cable.paths[0]} (its log: {where / 'robot.log'}), the station on "
              f"{cable.paths[1]}, database {db}", file=sys.stderr, flush=True)
        parts = open_station(cable.paths[1], str(key), str(db), status_every=status_every)
        return serve_to_exit(parts, page)
    finally:
        stop_robot(robot)
        cable.close()
