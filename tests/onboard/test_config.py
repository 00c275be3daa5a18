"""The robot's config: good files load into frozen records; every bad one is one clear line."""
import subprocess
import sys
from dataclasses import FrozenInstanceError
from pathlib import Path

import pytest

from onboard import config
from onboard.config import ConfigError
from tests.support import ROOT
from tests.support.robots import SMALL, robot_toml

GOOD = """
robot_id = 7
[hal]
body = "fake"
scene = "mixed"
size = [60, 80]
fault_rate = 0.1
[link]
url = "loop://"
key_file = "robot.key"
[sweep]
start = 90
stop = 30
step = 10
azimuths = [0, 45.5]
[features]
space = "hsv"
bands = ["V"]
[skip]
min_pixels = 10
"""


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "robot.toml"
    p.write_text(text)
    return p


def test_good_file_loads_into_frozen_records_with_paths_relative_to_the_file(tmp_path):
    cfg = config.load(write(tmp_path, GOOD))
    assert cfg.robot_id == 7
    assert cfg.hal.size == (60, 80) and cfg.hal.fault_rate == 0.1
    assert cfg.sweep.azimuths == (0.0, 45.5) and cfg.sweep.start == 90.0
    assert cfg.features.bands == ("V",)
    assert cfg.link.key_file == tmp_path.resolve() / "robot.key"
    assert cfg.state_dir == tmp_path.resolve() / "state"
    with pytest.raises(FrozenInstanceError):
        cfg.robot_id = 3  # type: ignore[misc]


@pytest.mark.parametrize(
    "text, words",
    [
        ("robot_id = [", "bad TOML"),
        ("colour = 3", "unknown key colour"),
        ("[sweep]\nspeed = 3", "unknown key sweep.speed"),
        ("[sweep]\nstep = 'ten'", "sweep.step must be a number"),
        ("robot_id = 1.5", "robot_id must be an integer"),
        ("[sweep]\nautostart = 1", "sweep.autostart must be true or false"),
        ("[hal]\nsize = [10]", "hal.size must have 2 items"),
        ("[hal]\nbody = 'magic'", "hal.body must be one of \"\" (unset), 'fake', 'emulated', 'real', got 'magic'"),
        ("[sweep]\nstep = -5", "sweep.step must lie in 0.01..180, got -5"),
        ("[sweep]\nstart = 120", "sweep.start must lie in 0..90, got 120"),
        ("[sweep]\nstart = nan", "must be finite"),
        ("[segment]\nmethod = 'mask'\nmask = 'nowhere.png'", "no such file"),
        ("hal = 3", "[hal] must be a table"),
        ("[sweep]\nstop = 0\nstep = 0.02", "exceeds 4096"),
        ("[features]\nband_names = ['nir']", "with features.space = 'rgb' leave it empty"),
        ("[features]\nspace = 'raw'\nband_names = ['nir', 'nir']", "a name repeats"),
        ("[features]\nspace = 'raw'\nband_names = ['near infrared 842nm']", "1..16 printable"),
        ("[features]\nspace = 'raw'\nband_names = ['red', 'nir']\nbands = ['green']",
         "features.bands ['green'] not among features.band_names"),
        ("", "the file sets nothing (empty, or comments only); copy examples/robot.toml"),
        ("# robot 3, the north rig\n\n", "the file sets nothing"),
    ],
)
def test_each_bad_config_raises_one_line_naming_the_problem(tmp_path, text, words):
    with pytest.raises(ConfigError) as info:
        config.load(write(tmp_path, text))
    msg = str(info.value)
    assert words in msg and "\n" not in msg
    assert str(tmp_path / "robot.toml") in msg


def test_missing_file_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="config file not found"):
        config.load(tmp_path / "absent.toml")


def test_missing_key_file_is_reported(tmp_path):
    cfg = config.load(write(tmp_path, GOOD))
    with pytest.raises(ConfigError, match="link.key_file: no such file"):
        config.check_key_file(cfg)
    (tmp_path / "robot.key").write_text("00" * 32)
    config.check_key_file(cfg)


@pytest.mark.parametrize(
    "text, words",
    [
        (None, "config file not found"),
        ("robot_id = [", "bad TOML"),
        ("colour = 3", "unknown key"),
        ("[sweep]\nstep = 'ten'", "must be a number"),
        ("[link]\nkey_file = 'none.key'", "link.key_file: no such file"),
    ],
)
def test_btf_robot_run_stops_at_start_with_one_line_and_exit_2(tmp_path, text, words):
    path = tmp_path / "robot.toml"
    if text is not None:
        path.write_text(text + "\n")
    out = subprocess.run(
        [sys.executable, "-c", "import sys; from onboard.cli import main; sys.exit(main())",
         "run", "--config", str(path), "--hal", "fake"],
        capture_output=True, text=True, timeout=60, cwd=ROOT,
    )
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0] and "Traceback" not in out.stderr


def test_a_link_url_no_handler_reads_is_a_configuration_error_not_restarted(tmp_path):
    """Exit 1 means "retry later" to the systemd unit: a URL of an unknown scheme was retried forever."""
    (tmp_path / "robot.key").write_text("00" * 32)
    (tmp_path / "robot.key").chmod(0o600)
    (tmp_path / "robot.toml").write_text("[link]\nurl = 'bogus://x'\n")
    out = subprocess.run(
        [sys.executable, "-c", "import sys; from onboard.cli import main; sys.exit(main())",
         "run", "--config", str(tmp_path / "robot.toml"), "--hal", "fake"],
        capture_output=True, text=True, timeout=60, cwd=ROOT,
    )
    (line,) = out.stderr.strip().splitlines()
    assert out.returncode == 2 and "link.url bogus://x" in line and "give a device such as /dev/ttyUSB0" in line


def test_btf_robot_run_without_a_hal_body_is_a_configuration_error_not_restarted(tmp_path, monkeypatch, capsys):
    """No hal.body and no BTF_HAL: exit 2, which the shipped systemd unit does not restart."""
    from onboard.cli import main

    monkeypatch.delenv("BTF_HAL", raising=False)
    (tmp_path / "robot.key").write_text("00" * 32)
    (tmp_path / "robot.key").chmod(0o600)
    path = tmp_path / "robot.toml"
    path.write_text('state_dir = "state"\n[link]\nkey_file = "robot.key"\n')
    assert main(["run", "--config", str(path), "--port", "loop://", "--max-seconds", "1"]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "hal.body" in err and "Traceback" not in err
    unit = (ROOT / "examples" / "btf-robot.service").read_text()
    assert "RestartPreventExitStatus=2" in unit


@pytest.mark.parametrize("value", ["-5", "nan", "inf", "soon"])
def test_btf_robot_run_refuses_a_max_seconds_that_is_negative_or_not_finite(value, capsys):
    from onboard.cli import main

    assert main(["run", "--config", "robot.toml", "--max-seconds", value]) == 2
    err = capsys.readouterr().err
    assert err.splitlines() == [err.strip()] and err.startswith(f"btf-robot run: error: --max-seconds {value}: ")
    assert "at least 0 seconds" in err


def test_a_failing_state_disk_after_start_is_one_line_and_exit_1(tmp_path, monkeypatch, capsys):
    """Not a configuration error (exit 2, not restarted): systemd restarts status 1."""
    import sqlite3

    from onboard.cli import main
    from onboard.runtime import Runtime

    (tmp_path / "robot.key").write_text("00" * 32)
    (tmp_path / "robot.key").chmod(0o600)
    path = tmp_path / "robot.toml"
    path.write_text(robot_toml(SMALL, {"link": {"key_file": "robot.key"}}, state_dir="state"))

    def broken_boot(self):
        raise sqlite3.OperationalError("disk I/O error")

    monkeypatch.setattr(Runtime, "boot", broken_boot)
    assert main(["run", "--config", str(path), "--max-seconds", "5"]) == 1
    err = [line for line in capsys.readouterr().err.splitlines() if ": error: " in line]
    assert len(err) == 1 and "disk I/O error" in err[0] and "state_dir" in err[0]


def test_default_paths_resolve_against_the_config_file_even_without_their_section(tmp_path):
    cfg = config.load(write(tmp_path, robot_toml()))
    assert cfg.link.key_file == tmp_path.resolve() / "robot.key"
    assert cfg.state_dir == tmp_path.resolve() / "state"


def test_config_types_are_read_from_the_dataclasses():
    assert config.field_types(config.HalConfig)["size"] == (int, 2)
    assert config.field_types(config.SweepConfig)["azimuths"] == (float, None)
    assert config.field_types(config.SegmentConfig)["mask"] is Path
    assert config.field_types(config.Config)["outbox_quota_bytes"] is int


def test_a_value_set_at_run_time_is_read_as_the_file_would_read_it(tmp_path):
    cfg = config.load(write(tmp_path, robot_toml()))
    assert config.with_value(cfg, "sweep.azimuths", [0, 90]).sweep.azimuths == (0.0, 90.0)
    assert config.with_value(cfg, "skip.min_pixels", 5).skip.min_pixels == 5
    with pytest.raises(config.ConfigError, match="skip.min_pixels must be an integer"):
        config.with_value(cfg, "skip.min_pixels", 2.5)
    with pytest.raises(config.ConfigError, match="unknown key skip.nope"):
        config.with_value(cfg, "skip.nope", 1)
