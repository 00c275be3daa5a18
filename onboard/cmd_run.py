"""`btf-robot run`: the robot's runtime, autonomous sweeps and remote control over the link."""
from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import signal
import sqlite3
import sys
import tempfile
import time
from pathlib import Path

from onboard import config as config_mod
from onboard.cli_runner import CliError
from onboard.config import ConfigError


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:
    p = sub.add_parser("run", help="run the robot: sweeps, commands, outbox, failsafe")
    p.add_argument("--config", required=True, help="robot TOML config (see examples/robot.toml)")
    p.add_argument("--hal", choices=("fake", "emulated", "real"), help="override hal.body")
    p.add_argument("--port", help="override link.url (a device, pty path, loop://, socket://, btfsim://?port=...)")
    p.add_argument("--exit-when-idle", action="store_true",
                   help="exit 0 once no sweep is running and every packet is acknowledged")
    p.add_argument("--max-seconds", type=float, default=0.0, help="stop after this long (0: never)")
    p.add_argument("--new-sweep", action="store_true",
                   help="start a new sweep of the config's plan even if its last sweep finished "
                        "(by default an interrupted sweep resumes and a finished one is not repeated)")
    return p


def _setup(args: argparse.Namespace):
    try:
        cfg = config_mod.load(args.config)
        if args.hal:
            cfg = dataclasses.replace(cfg, hal=dataclasses.replace(cfg.hal, body=args.hal))
        if args.port:
            cfg = dataclasses.replace(cfg, link=dataclasses.replace(cfg.link, url=args.port))
        config_mod.check(cfg)
        config_mod.check_key_file(cfg)
        _check_state_dir(cfg.state_dir)
        from radio.keys import KeyFileError, load_key

        try:
            key = load_key(cfg.link.key_file)
        except KeyFileError as exc:
            raise ConfigError(f"link.key_file: {exc}") from None
    except ConfigError as exc:
        raise CliError(str(exc)) from None
    return cfg, key


def _calibrated_exposure(cfg):
    """`cfg` with the exposure `btf-robot calibrate exposure` stored, when there is one."""
    from onboard.config import CameraValue
    from onboard.exposure_calibration import EXPOSURE_FILE, load_exposure

    try:
        stored = load_exposure(cfg.state_dir)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    if stored is None:
        return cfg
    print(f"btf-robot: camera exposure {stored:g} us from {cfg.state_dir / EXPOSURE_FILE} "
          "(btf-robot calibrate exposure)", file=sys.stderr)
    return dataclasses.replace(cfg, camera=dataclasses.replace(cfg.camera, exposure=CameraValue(repr(stored))))


def _check_state_dir(path: Path) -> None:
    """The state directory exists (or is made) and takes a durable write: else one ConfigError."""
    try:
        path.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise ConfigError(f"state_dir {path}: exists and is not a directory") from None
    except OSError as exc:
        raise ConfigError(f"state_dir {path}: cannot create it: {exc.strerror or exc}") from None
    try:
        with tempfile.TemporaryFile(dir=path) as probe:
            probe.write(b"x")
            probe.flush()
            os.fsync(probe.fileno())
    except OSError as exc:
        raise ConfigError(f"state_dir {path}: cannot write in it: {exc.strerror or exc}") from None


def _open_port(url: str, baud: int):
    from radio.ports import open_url

    return open_url(url, baud, timeout=0.005)


def console_log() -> None:
    """One short line per pose, command and link change on stderr: plain text for journald,
    which stamps each line; a terminal gets the time in front."""
    log = logging.getLogger("btf.robot")
    for old in list(log.handlers):
        log.removeHandler(old)
    handler = logging.StreamHandler(sys.stderr)
    tty = hasattr(sys.stderr, "isatty") and sys.stderr.isatty()
    handler.setFormatter(logging.Formatter("%(asctime)s %(message)s" if tty else "%(message)s", "%H:%M:%S"))
    log.addHandler(handler)
    log.setLevel(logging.INFO)
    log.propagate = False


def run(args: argparse.Namespace) -> int:
    cfg, key = _setup(args)
    console_log()
    from hal.factory import build_hal
    from hal.interfaces import HalError
    from onboard.outbox import OutboxError
    from onboard.runtime import Runtime
    from onboard.segmentation import Segmentation
    from onboard.watchdog import Notifier
    from radio.auth import FileCounterStore
    from radio.link import Link
    from radio.pump import LinkPump

    cfg = _calibrated_exposure(cfg)
    try:
        hal = build_hal(cfg.hal, state_dir=cfg.state_dir)  # with the arm calibration stored there
    except HalError as exc:
        raise CliError(f"hal: {exc}") from None
    try:
        port = _open_port(cfg.link.url, cfg.link.baud)
    except Exception as exc:
        hal.close()
        raise CliError(f"link.url {cfg.link.url}: cannot open: {exc}") from None
    try:
        segment = Segmentation(cfg, hal)
        link = Link(cfg.link.node_id, cfg.link.peer_id, cfg.link.link_id, key,
                    FileCounterStore(cfg.state_dir / "counters.json"), mtu=cfg.link.mtu,
                    heartbeat=cfg.link.heartbeat_s, link_timeout=cfg.link.failsafe_s)
        h, w = cfg.hal.size
        hal.camera.open(w, h)
        rt = Runtime(cfg, hal, LinkPump(link, port), segment, notifier=Notifier(),
                     new_sweep=args.new_sweep)
    except (ConfigError, ValueError, HalError, OutboxError) as exc:
        hal.close()
        raise CliError(str(exc)) from None
    stopping = []
    signal.signal(signal.SIGTERM, lambda *_: stopping.append(1))
    t0 = time.monotonic()

    def stop(r: Runtime) -> bool:
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
