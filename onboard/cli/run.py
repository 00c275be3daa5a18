"""`btf-robot run`: the robot's runtime, autonomous sweeps and remote control over the link.

Exit status 2: the configuration is wrong (restarting cannot mend it); 1: the environment is
(a full disk, a device or port not there yet: systemd restarts it, see examples/btf-robot.service).
Everything the configuration decides is checked before anything is created on disk: the state
directory is made only once the configuration, the key, the HAL and the segmentation stand.
"""
from __future__ import annotations

import argparse
import dataclasses
import errno
import json
import logging
import os
import signal
import sqlite3
import sys
import tempfile
import time
from pathlib import Path

from serial import SerialException

from hal.factory import HalConfigError, build_hal, choose_body
from hal.interfaces import Body, HalError, NotGranted
from onboard import config as config_mod
from onboard.capture.exposure import EXPOSURE_FILE, load_exposure
from onboard.capture.segmentation import Segmentation
from onboard.cli.runner import CliError, RetryLater, bounded
from onboard.config import CameraValue, ConfigError
from onboard.link.outbox import OutboxError
from onboard.runtime import Runtime, open_state
from onboard.watchdog import Notifier
from radio.auth import CounterFileLost, FileCounterStore, write_fresh
from radio.channel_port import parse_url
from radio.keys import KeyFileError, load_key
from radio.link import Link
from radio.packets.base import iso_time
from radio.ports import open_url
from radio.pump import LinkPump


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", required=True, help="robot TOML config (see examples/robot.toml)")
    p.add_argument("--hal", choices=("fake", "emulated", "real"), help="override hal.body")
    p.add_argument("--port", help="override link.url (a device, pty path, loop://, socket://, btfsim://?port=...)")
    p.add_argument("--exit-when-idle", action="store_true",
                   help="exit 0 once no sweep is running and every packet is acknowledged")
    p.add_argument("--max-seconds", type=bounded(float, 0, None, "seconds"), default=0.0,
                   help="stop after this many seconds (0: never)")
    p.add_argument("--new-sweep", action="store_true",
                   help="start a new sweep of the config's plan even if its last sweep finished "
                        "(by default an interrupted sweep resumes and a finished one is not repeated)")
    p.add_argument("--log-json", action="store_true",
                   help="log one JSON object per line (time, message and the line's fields, e.g. each "
                        "pose's compute by step) instead of plain text")
    p.add_argument("--new-key", action="store_true",
                   help="link.key_file holds a key never used before (just made by 'btf-host keygen'): "
                        "start its link counters afresh; only needed with [link] clock = \"none\"")


def _setup(args: argparse.Namespace):
    try:
        cfg = config_mod.load(args.config)
        if args.hal:
            cfg = dataclasses.replace(cfg, hal=dataclasses.replace(cfg.hal, body=args.hal))
        if args.port:
            cfg = dataclasses.replace(cfg, link=dataclasses.replace(cfg.link, url=args.port))
        config_mod.check(cfg)
        _check_devices(cfg)
        config_mod.check_key_file(cfg)
        try:
            key = load_key(cfg.link.key_file)
        except KeyFileError as exc:
            raise ConfigError(f"link.key_file: {exc}") from None
    except ConfigError as exc:
        raise CliError(str(exc)) from None
    return cfg, key


def _check_devices(cfg) -> None:
    """What the HAL and the link need of the configuration, said before anything opens: a body
    chosen (hal.body or BTF_HAL), a servo port for the real one, a simulated radio's options."""
    try:
        body = choose_body({"body": cfg.hal.body}, os.environ)
    except HalConfigError as exc:
        raise ConfigError(f"hal: {exc}") from None
    if body is Body.REAL and not cfg.hal.servo_port:
        raise ConfigError("hal.servo_port is required for the real body (e.g. /dev/ttyUSB0)")
    if cfg.link.url.lower().startswith("btfsim:"):
        try:
            parse_url(cfg.link.url)
        except SerialException as exc:
            raise ConfigError(f"link.url: {exc}") from None


def _calibrated_exposure(cfg):
    """`cfg` with the exposure `btf-robot calibrate exposure` stored, when there is one."""
    try:
        stored = load_exposure(cfg.state_dir)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    if stored is None:
        return cfg
    print(f"btf-robot: camera exposure {stored:g} us from {cfg.state_dir / EXPOSURE_FILE} "
          "(btf-robot calibrate exposure)", file=sys.stderr)
    return dataclasses.replace(cfg, camera=dataclasses.replace(cfg.camera, exposure=CameraValue(repr(stored))))


# A state_dir refusing writes for these reasons needs a person (exit 2: a wrong path or mode, a
# filesystem gone read-only); a full disk is the robot's to live with (it starts paused and says
# so); any other failure is the environment's (exit 1, retried).
_CONFIG_ERRNOS = (errno.EACCES, errno.EPERM, errno.ENOTDIR, errno.EEXIST, errno.ENOENT, errno.ENAMETOOLONG,
                  errno.ELOOP, errno.EROFS)
_NO_ROOM_ERRNOS = (errno.ENOSPC, errno.EDQUOT)


def _check_state_dir(path: Path) -> None:
    """The state directory exists (or is made) and takes a durable write: else one line, a
    ConfigError when the setup is wrong, RetryLater when the disk or device is."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise ConfigError(f"state_dir {path}: exists and is not a directory") from None
    except OSError as exc:
        _state_dir_failed(path, "cannot create it", exc)
    try:
        with tempfile.TemporaryFile(dir=path) as probe:
            probe.write(b"x")
            probe.flush()
            os.fsync(probe.fileno())
    except OSError as exc:
        if exc.errno not in _NO_ROOM_ERRNOS:  # a full disk: the runtime releases its reserve
            _state_dir_failed(path, "cannot write in it", exc)


def _state_dir_failed(path: Path, what: str, exc: OSError) -> None:
    text = f"state_dir {path}: {what}: {exc.strerror or exc}"
    if exc.errno in _CONFIG_ERRNOS:
        raise ConfigError(text) from None
    raise RetryLater(text) from None


def _open_port(url: str, baud: int):
    return open_url(url, baud, timeout=0.005)


def _counters(cfg, new_key: bool):
    """The robot's link counters (state_dir/counters.json); CliError when only a new key helps."""
    path = cfg.state_dir / "counters.json"
    try:
        if new_key:
            write_fresh(path)
        return FileCounterStore(path, clock=cfg.link.clock == "rtc")
    except CounterFileLost as exc:
        raise CliError(str(exc)) from None
    except OSError as exc:
        raise RetryLater(f"state_dir {cfg.state_dir}: counters: {exc}") from None


def _build(cfg, key: bytes, args: argparse.Namespace, hal, port, segment: Segmentation):
    """The runtime on its link; what opening its state had to say is in its notes."""
    counters = _counters(cfg, args.new_key)
    try:
        outbox, disk, note = open_state(cfg)
    except (OutboxError, OSError) as exc:
        raise RetryLater(f"state_dir {cfg.state_dir}: {exc}") from None
    link = Link(cfg.link.node_id, cfg.link.peer_id, cfg.link.link_id, key, counters,
                mtu=cfg.link.mtu, heartbeat=cfg.link.heartbeat_s, link_timeout=cfg.link.failsafe_s,
                incarnation=bytes.fromhex(outbox.incarnation))
    rt = Runtime(cfg, hal, LinkPump(link, port), segment, outbox=outbox, disk=disk, notifier=Notifier(),
                 new_sweep=args.new_sweep)
    # A missing counters file beside a new outbox is a first start (or a whole state lost, which
    # the new incarnation tells the host): said only when the rest of the state is there.
    for line in (note, "" if outbox.new else counters.note):
        if line:
            rt.note(line)
    return rt


class JsonLines(logging.Formatter):
    """A log record as one JSON object: its UTC time, level, message and the fields it carries
    (`extra={"fields": {...}}`, e.g. a pose's compute by step)."""

    def format(self, record: logging.LogRecord) -> str:
        line = {"time": iso_time(record.created), "level": record.levelname.lower(), "message": record.getMessage()}
        line.update(getattr(record, "fields", {}))
        return json.dumps(line, separators=(",", ":"))


def console_log(as_json: bool = False) -> None:
    """One short line per pose, command and link change on stderr: plain text for journald,
    which stamps each line; a terminal gets the time in front; `as_json`: JSON lines."""
    log = logging.getLogger("btf.robot")
    for old in list(log.handlers):
        log.removeHandler(old)
    handler = logging.StreamHandler(sys.stderr)
    tty = hasattr(sys.stderr, "isatty") and sys.stderr.isatty()
    handler.setFormatter(JsonLines() if as_json else
                         logging.Formatter("%(asctime)s %(message)s" if tty else "%(message)s", "%H:%M:%S"))
    log.addHandler(handler)
    log.setLevel(logging.INFO)
    log.propagate = False


def run(args: argparse.Namespace) -> int:
    cfg, key = _setup(args)
    console_log(getattr(args, "log_json", False))

    cfg = _calibrated_exposure(cfg)
    try:
        hal = build_hal(cfg.hal, state_dir=cfg.state_dir)  # with the arm calibration stored there
    except HalConfigError as exc:  # no body chosen, an unknown option: restarting cannot mend it
        raise CliError(f"hal: {exc}") from None
    except HalError as exc:  # a device not there yet
        raise RetryLater(f"hal: {exc}") from None
    try:
        hal.open_camera()
        segment = Segmentation(cfg, hal)  # reads the palette kept in state_dir, writes nothing
        _check_state_dir(cfg.state_dir)  # the first thing made on disk
    except BaseException as exc:
        hal.close()
        # no device to wait for, or one that will never give what the configuration asks
        if isinstance(exc, (ConfigError, NotGranted)) or (isinstance(exc, HalError) and hal.body is not Body.REAL):
            raise CliError(f"hal: {exc}" if isinstance(exc, HalError) else str(exc)) from None
        if isinstance(exc, HalError):
            raise RetryLater(f"hal: camera: {exc}") from None
        raise
    try:
        port = _open_port(cfg.link.url, cfg.link.baud)
    except ValueError as exc:  # a URL no handler reads: the config's mistake, which no restart mends
        hal.close()
        raise CliError(f"link.url {cfg.link.url}: {exc}; give a device such as /dev/ttyUSB0, or loop://, "
                       "socket://HOST:PORT or btfsim://") from None
    except Exception as exc:
        hal.close()
        raise RetryLater(f"link.url {cfg.link.url}: cannot open: {exc}") from None
    try:
        rt = _build(cfg, key, args, hal, port, segment)
    except (CliError, RetryLater):
        hal.close()
        port.close()
        raise
    except (ConfigError, ValueError) as exc:
        hal.close()
        port.close()
        raise CliError(str(exc)) from None
    except HalError as exc:
        hal.close()
        port.close()
        raise RetryLater(f"hal: {exc}") from None
    stopping = []
    signal.signal(signal.SIGTERM, lambda *_: stopping.append(1))
    t0 = time.monotonic()

    def stop(r) -> bool:
        if stopping or (args.max_seconds and time.monotonic() - t0 > args.max_seconds):
            return True
        return bool(args.exit_when_idle and r.idle())

    try:
        return rt.run(stop)
    except (OutboxError, OSError, sqlite3.Error) as exc:
        # The disk under the outbox failed (boot writes, or beneath step()'s own guard): one
        # line and status 1, which systemd restarts, unlike a configuration error's 2.
        print(f"btf-robot: error: state_dir {cfg.state_dir}: {exc}", file=sys.stderr)
        return 1
    finally:
        rt.outbox.close()
        hal.close()
        port.close()
